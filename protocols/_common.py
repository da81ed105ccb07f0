"""Helpers the shipped protocols share: ColorChecker patch names and key formatting.

Patch numbers follow the ColorChecker Classic order (1 = dark skin … 24 = black), row by row.
"""

from __future__ import annotations

#: ColorChecker Classic patch names, patch number N at index N - 1
PATCH_NAMES: tuple[str, ...] = (
    "dark skin", "light skin", "blue sky", "foliage", "blue flower", "bluish green",
    "orange", "purplish blue", "moderate red", "purple", "yellow green", "orange yellow",
    "blue", "green", "red", "yellow", "magenta", "cyan",
    "white 9.5 (.05 D)", "neutral 8 (.23 D)", "neutral 6.5 (.44 D)", "neutral 5 (.70 D)",
    "neutral 3.5 (1.05 D)", "black 2 (1.5 D)",
)
WHITE_PATCH = 19


def patch_name(n: int) -> str:
    if not 1 <= int(n) <= 24:
        raise ValueError(f"ColorChecker patches are numbered 1…24, got {n}")
    return PATCH_NAMES[int(n) - 1]


def angle_key(angle_deg: float) -> str:
    """30 → "a30", 32.5 → "a32.5", -10 → "a-10"."""
    a = float(angle_deg)
    return f"a{int(a)}" if a.is_integer() else f"a{a:g}"


def signed_key(prefix: str, angle_deg: float) -> str:
    """("i", -80) → "i-80", ("o", 40) → "o+40", ("o", 0) → "o+0"."""
    a = float(angle_deg)
    text = f"{int(a):+d}" if a.is_integer() else f"{a:+g}"
    return prefix + text
