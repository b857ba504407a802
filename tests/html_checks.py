"""What a Meshcat replay page must hold: the robot, the traces, the phase label, and no
external fetches (an empty ``StaticHtml`` page is 2.2 MB and mentions "ws://" and "embedded",
so size and those words prove nothing)."""

import re

from drake_estop.systems.visualization import html_mentions

ROBOT_LINKS = ("pelvis", "torso", "l_thigh", "r_thigh", "l_shank", "r_shank", "l_foot", "r_foot")
TRACES = ("estop/nominal/cog", "estop/plan/zmp", "estop/markers/cog", "estop/support", "estop/one_step")
PHASE_LABEL = "estop/phase/stopped"
ANIMATION = "set_animation"

_FETCH = [
    re.compile(r"<(?:script|link|img|iframe|source|video|audio)\b[^>]*\b(?:src|href)\s*=\s*[\"']?(?:https?:)?//",
               re.I),
    re.compile(r"\bimport\b[^;\n]*\bfrom\s*[\"'](?:https?:)?//", re.I),
    re.compile(r"@import\s+(?:url\()?[\"']?(?:https?:)?//", re.I),
    re.compile(r"\bimport\(\s*[\"'](?:https?:)?//", re.I),
]


def external_fetches(html):
    """Resource loads from other hosts (tags, ES-module / CSS imports) in the page."""
    return [m.group(0)[:80] for pattern in _FETCH for m in pattern.finditer(html)]


def missing_from_replay(html):
    """Names of the robot links, traces, phase label and animation the page lacks."""
    wanted = ROBOT_LINKS + TRACES + (PHASE_LABEL, ANIMATION)
    return sorted(set(wanted) - html_mentions(html, wanted))
