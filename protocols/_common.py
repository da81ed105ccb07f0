"""Helpers the shipped protocols share: ColorChecker patch names and key formatting.

Patch numbers follow the ColorChecker Classic order (1 = dark skin … 24 = black), row by row.
"""

from __future__ import annotations

from normbox_lab.core.spectral import PATCH_NAMES, WHITE_PATCH, patch_name  # noqa: F401


def angle_key(angle_deg: float) -> str:
    """30 → "a30", 32.5 → "a32.5", -10 → "a-10"."""
    a = float(angle_deg)
    return f"a{int(a)}" if a.is_integer() else f"a{a:g}"


def signed_key(prefix: str, angle_deg: float) -> str:
    """("i", -80) → "i-80", ("o", 40) → "o+40", ("o", 0) → "o+0"."""
    a = float(angle_deg)
    text = f"{int(a):+d}" if a.is_integer() else f"{a:+g}"
    return prefix + text
