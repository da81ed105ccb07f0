"""Helpers the shipped protocols share: reading-key formatting.  (Patch names and numbers,
ColorChecker Classic order, are `normbox_lab.core.spectral`'s.)"""

from __future__ import annotations


def angle_key(angle_deg: float) -> str:
    """30 → "a30", 32.5 → "a32.5", -10 → "a-10"."""
    a = float(angle_deg)
    return f"a{int(a)}" if a.is_integer() else f"a{a:g}"


def signed_key(prefix: str, angle_deg: float) -> str:
    """("i", -80) → "i-80", ("o", 40) → "o+40", ("o", 0) → "o+0"."""
    a = float(angle_deg)
    text = f"{int(a):+d}" if a.is_integer() else f"{a:+g}"
    return prefix + text
