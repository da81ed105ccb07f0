"""Helpers the shipped protocols share: reading-key formatting, and the declared kinds and
limits of protocol parameters.  (Patch names and numbers, ColorChecker Classic order, are
`normbox_lab.core.spectral`'s.)

Every protocol declares what each parameter may hold in `LIMITS` and checks its parameters
with `check_parameters(LIMITS, params, lab)` before it builds a step, so the command line, the
console and scripts all go through the same check (they all build the plan).  An angle is
checked against the configured range of the instrument that will move to it (the lab config's
``min_angle_deg`` / ``max_angle_deg``, else the driver's own default range).  A bad value
raises `ParameterError`: one line naming the field and the limit (``normbox-lab run`` exits 2).

    LIMITS = {"angles_deg": Angles(role_param="rotator"), "patches": Patches(),
              "repeats": Count(), "lamp_timeout_s": Positive("s")}
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from normbox_lab.acquire.steps import PlanError
from normbox_lab.core.errors import NormboxError
from normbox_lab.core.spectral import PATCH_NAMES


def angle_key(angle_deg: float) -> str:
    """30 → "a30", 32.5 → "a32.5", -10 → "a-10"."""
    a = float(angle_deg)
    return f"a{int(a)}" if a.is_integer() else f"a{a:g}"


def signed_key(prefix: str, angle_deg: float) -> str:
    """("i", -80) → "i-80", ("o", 40) → "o+40", ("o", 0) → "o+0"."""
    a = float(angle_deg)
    text = f"{int(a):+d}" if a.is_integer() else f"{a:+g}"
    return prefix + text


# --- parameter kinds and limits ----------------------------------------------------------------

class ParameterError(PlanError):
    """A protocol parameter outside its declared kind or limits (one line: field and limit)."""

    exit_code = 2


def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _show(value: Any) -> str:
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Infinity" if value > 0 else "-Infinity"
        return f"{value:.6g}"
    text = repr(value) if isinstance(value, str) else str(value)
    return text if len(text) <= 24 else text[:23] + "…"


def _finite(field: str, value: Any, what: str = "a number") -> float:
    if not _number(value):
        raise ParameterError(f"{field}: {_show(value)} is not {what}")
    if not math.isfinite(float(value)):
        raise ParameterError(f"{field}: {_show(value)} is not a finite number")
    return float(value)


def _items(field: str, value: Any, many: bool) -> list[Any]:
    if not many:
        return [value]
    if not isinstance(value, list):
        raise ParameterError(f"{field}: expected a list, got {_show(value)}")
    if not value:
        raise ParameterError(f"{field}: the list is empty; give at least one value")
    return value


def _lab_config(lab: Any) -> Any:
    """The `LabConfig` of a lab (or the config itself); None for a lab without one."""
    from normbox_lab.acquire.config import LabConfig
    from normbox_lab.acquire.lab import Lab

    if isinstance(lab, LabConfig):
        return lab
    if isinstance(lab, Lab):
        return lab.config
    return None


def angle_limits_deg(lab: Any, role: str) -> tuple[float, float, str] | None:
    """(min, max, source) of the instrument of `role`: the lab config's
    ``min_angle_deg`` / ``max_angle_deg``, else its driver's default; None when the lab (or
    its config) is not known or has no such instrument."""
    import inspect

    from normbox_lab.acquire.lab import driver_class

    config = _lab_config(lab)
    inst = None if config is None else config.instruments.get(role)
    if inst is None:
        return None
    options = inst.options
    if "min_angle_deg" in options and "max_angle_deg" in options:
        return (float(options["min_angle_deg"]), float(options["max_angle_deg"]),
                "lab config")
    try:
        params = inspect.signature(driver_class(inst.driver)).parameters
    except (NormboxError, ImportError, ValueError, TypeError):
        return None
    lo = options.get("min_angle_deg", params["min_angle_deg"].default
                     if "min_angle_deg" in params else -math.inf)
    hi = options.get("max_angle_deg", params["max_angle_deg"].default
                     if "max_angle_deg" in params else math.inf)
    return float(lo), float(hi), f"{inst.driver} default"


@dataclass(frozen=True)
class Angles:
    """Finite angles within the configured range of the instrument that moves to them: the
    role named by the parameter `role_param`, or the fixed `role`.  `many`: a non-empty list."""

    role_param: str = ""
    role: str = ""
    many: bool = True

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        role = str(params.get(self.role_param, "")) if self.role_param else self.role
        limits = angle_limits_deg(lab, role) if role else None
        for v in _items(field, value, self.many):
            a = _finite(field, v, "an angle in degrees")
            if limits is not None and not limits[0] <= a <= limits[1]:
                raise ParameterError(f"{field}: {_show(v)}° is outside {limits[0]:g}…"
                                     f"{limits[1]:g}° (the {role}'s range, {limits[2]})")


@dataclass(frozen=True)
class Patches:
    """ColorChecker patch numbers 1–24 (whole numbers); `names`: also material names such as
    "wall"; `many`: a non-empty list."""

    many: bool = True
    names: bool = False

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        count = len(PATCH_NAMES)
        for v in _items(field, value, self.many):
            if self.names and isinstance(v, str) and not v.strip().isdigit():
                if not v.strip():
                    raise ParameterError(f"{field}: an empty material name")
                continue
            n = int(v.strip()) if isinstance(v, str) else v
            if not _number(n) or not math.isfinite(float(n)) or float(n) != int(n) \
                    or not 1 <= int(n) <= count:
                raise ParameterError(f"{field}: {_show(v)} is not a patch number (1–{count}"
                                     + (", or a material name" if self.names else "") + ")")


@dataclass(frozen=True)
class Count:
    """A whole number ≥ `minimum` (default 1: a positive count), at most `maximum`."""

    minimum: int = 1
    maximum: int = 100_000

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        n = _finite(field, value, "a whole number")
        if n != int(n):
            raise ParameterError(f"{field}: {_show(value)} is not a whole number")
        if self.minimum == 1 and n < 1:
            raise ParameterError(f"{field}: {_show(value)} is not a positive count (≥ 1)")
        if not self.minimum <= n <= self.maximum:
            raise ParameterError(f"{field}: {_show(value)} is outside {self.minimum}…"
                                 f"{self.maximum}")


@dataclass(frozen=True)
class Positive:
    """A finite number > 0 (≥ 0 with `zero`), in `unit`, at most `maximum`."""

    unit: str = ""
    zero: bool = False
    maximum: float = math.inf

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        x = _finite(field, value)
        unit = f" {self.unit}" if self.unit else ""
        if x < 0 or (x == 0 and not self.zero):
            raise ParameterError(f"{field}: {_show(value)}{unit} must be "
                                 + ("≥ 0" if self.zero else "> 0"))
        if x > self.maximum:
            raise ParameterError(f"{field}: {_show(value)}{unit} is above {self.maximum:g}"
                                 f"{unit}")


@dataclass(frozen=True)
class Role:
    """The name of an instrument role of the lab (checked when the lab's config is known)."""

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        if not isinstance(value, str) or not value.strip():
            raise ParameterError(f"{field}: expected the name of an instrument role")
        config = _lab_config(lab)
        if config is None:
            return
        roles = list(config.instruments)
        if value == "gonio" or value in roles:
            return
        raise ParameterError(f"{field}: {value!r} is not an instrument of this lab "
                             f"({', '.join(roles)})")


Limit = Angles | Patches | Count | Positive | Role


def check_parameters(limits: Mapping[str, Limit], params: Mapping[str, Any], lab: Any = None,
                     *, only: str | None = None) -> None:
    """Check every declared parameter (or `only` that one) against its kind and limits;
    `lab`: a built lab or a `LabConfig` (angle ranges, roles), None for the kinds alone.
    Raises `ParameterError` naming the field and its limit."""
    for field, limit in limits.items():
        if only is not None and field != only:
            continue
        if field in params:
            limit.check(field, params[field], params, lab)
