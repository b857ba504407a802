"""Checks of constructor settings shared by the systems and configs: a bad value raises ``ValueError``
naming the setting."""

import math


def check_positive(name: str, value) -> None:
    """ValueError naming ``name`` unless ``value`` is a positive, finite number (``True`` and ``False`` are
    refused: a switch given where a quantity belongs)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not (math.isfinite(value) and value > 0):
        raise ValueError(f"{name} must be positive and finite, got {value!r}")
