"""The replay renderer survives a Chromium that hangs (seen once on a fresh CI machine).

A stand-in "chromium" script hangs on its first call and writes the screenshot
on its second; ``screenshot`` must kill the hung run and retry. No Chromium needed.
"""

import stat

import pytest
from scripts import load_script

RENDER = load_script("diagrams/render_replay.py")


def _fake_chromium(tmp_path, body):
    script = tmp_path / "fake_chromium.sh"
    script.write_text("#!/bin/sh\n" + body)
    script.chmod(script.stat().st_mode | stat.S_IEXEC)
    return str(script)


def _screenshot_arg():
    # the --screenshot=PATH argument, in POSIX sh
    return 'for a in "$@"; do case "$a" in --screenshot=*) out="${a#--screenshot=}";; esac; done\n'


def test_hung_chromium_is_killed_and_retried(tmp_path):
    marker = tmp_path / "called_once"
    fake = _fake_chromium(tmp_path, _screenshot_arg() + (
        f'if [ ! -e {marker} ]; then touch {marker}; sleep 600; fi\n'
        'printf PNG > "$out"\n'))
    png = RENDER.screenshot(tmp_path / "x.html", tmp_path / "x.png", chromium=fake,
                            timeout=2, attempts=2)
    assert marker.exists()
    assert png.read_text() == "PNG"


def test_chromium_that_never_writes_raises_after_the_attempts(tmp_path):
    fake = _fake_chromium(tmp_path, 'echo broken >&2\nexit 3\n')
    with pytest.raises(RuntimeError, match=r"2 attempts.*exit 3.*broken"):
        RENDER.screenshot(tmp_path / "x.html", tmp_path / "x.png", chromium=fake,
                          timeout=2, attempts=2)
