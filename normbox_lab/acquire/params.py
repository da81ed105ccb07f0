"""One parser and validator for every number and list a person or a script gives: `run
--param K=V`, every numeric option of every subcommand, the console's parameter form and its
dialogs, the protocol parameters from the lab config (``[protocols.NAME]``) and from protocol
files.

A *kind* says what a value may hold and its limits (`Angles`, `Patches`, `Count`,
`Positive`, `Number`, `Role`).  `read(text, kind, field)` takes the text as typed and answers
the value or raises `ParameterError`: one line naming the field and what it expects (the
command line exits 2).  `check_parameters(LIMITS, params, lab)` checks values that are already
Python objects (TOML, a script) against the same kinds.

The grammar is one for every entry point:

- a number is ASCII decimal: ``30``, ``-2.5``, ``1e-3``; its length is checked before it is
  converted (at most `MAX_NUMBER_CHARS`), so no text makes an `OverflowError` or hits Python's
  4300-digit limit; ``NaN``, ``Infinity`` and anything that overflows to infinity are refused;
- digits of other scripts (Arabic-Indic ``٤٥``, fullwidth ``４５``) are refused everywhere
  with the same line ("use the digits 0-9"), never read as numbers in one place and refused in
  another;
- a list is ``[30, 60]`` or ``30, 60`` (the same items either way); an empty item
  (``30,,60``, ``[30,]``), an unbalanced or nested bracket is refused;
- a list whose items name readings (angles, patches, materials) refuses a repeated item: two
  readings with one key would only fail later, at planning.

    LIMITS = {"angles_deg": Angles(role_param="rotator"), "patches": Patches(),
              "repeats": Count(), "lamp_timeout_s": Positive("s")}
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from normbox_lab.core.errors import NormboxError, PlanError

#: ColorChecker Classic patches 1…24 (`normbox_lab.core.spectral.PATCH_NAMES`; not imported
#: here: the command line parses its options without numpy)
PATCH_COUNT = 24

#: the longest text read as one number (a 309-digit integer is refused by length, unconverted)
MAX_NUMBER_CHARS = 40
#: the longest text read as one value (a list included)
MAX_TEXT_CHARS = 4000
#: the most items in one list
MAX_ITEMS = 1000

_NUMBER = re.compile(r"[+-]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][+-]?[0-9]+)?")
_NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_-]{0,31}")
_NON_FINITE = {"nan", "inf", "infinity", "+nan", "-nan", "+inf", "-inf", "+infinity",
               "-infinity"}


class ParameterError(PlanError):
    """A value outside its declared kind or limits, or text that is no value of its kind
    (one line: the field and what it expects)."""

    exit_code = 2


# --- showing values in one short line -----------------------------------------------------------

def show(value: Any) -> str:
    """A value as the messages quote it: at most 24 characters, NaN and ∞ by name."""
    if isinstance(value, float):
        if math.isnan(value):
            return "NaN"
        if math.isinf(value):
            return "Infinity" if value > 0 else "-Infinity"
        return f"{value:.6g}"
    if isinstance(value, int) and not isinstance(value, bool):
        if abs(value) >= 10 ** 24:
            return f"a {len(str(abs(value))) if abs(value) < 10 ** 4000 else 'huge'}-digit number"
        return str(value)
    text = repr(value) if isinstance(value, str) else str(value)
    return text if len(text) <= 24 else text[:23] + "…"


def _quoted(text: str) -> str:
    """Text as typed, quoted, cut to 24 characters, one line."""
    flat = text.replace("\n", "\\n").replace("\r", "\\r")
    return repr(flat if len(flat) <= 24 else flat[:23] + "…")


# --- text → number, text → items -------------------------------------------------------------

def _foreign_digits(text: str) -> bool:
    return any(ch.isdigit() and not ch.isascii() for ch in text)


def parse_number(text: str, field: str, *, whole: bool = False) -> int | float:
    """One number from its text: ASCII decimal, length checked before conversion, finite;
    an `int` when written without a point or exponent (as JSON reads it); `whole`: always an
    integer (``7``, ``7.0`` and ``1e3`` are whole).  Raises `ParameterError`."""
    s = text.strip()
    what = "a whole number" if whole else "a number"
    if not s:
        raise ParameterError(f"{field}: empty; give {what}")
    if len(s) > MAX_NUMBER_CHARS:
        raise ParameterError(f"{field}: a {len(s)}-character number is too long (at most "
                             f"{MAX_NUMBER_CHARS} characters)")
    if _foreign_digits(s):
        raise ParameterError(f"{field}: {_quoted(s)} has digits of another script; use the "
                             "digits 0-9")
    if s.lower() in _NON_FINITE:
        name = "NaN" if "nan" in s.lower() else ("-Infinity" if s.startswith("-")
                                                  else "Infinity")
        raise ParameterError(f"{field}: {name} is not a finite number")
    if not _NUMBER.fullmatch(s):
        raise ParameterError(f"{field}: {_quoted(s)} is not {what}")
    if not any(c in s for c in ".eE"):
        return int(s)                      # at most 40 digits: no conversion limit applies
    x = float(s)
    if not math.isfinite(x):
        raise ParameterError(f"{field}: {s} is not a finite number (beyond the float range)")
    if whole:
        if not x.is_integer():
            raise ParameterError(f"{field}: {s} is not a whole number")
        return int(x)
    return x


def parse_items(text: str, field: str) -> list[str]:
    """The items of a list as typed: ``[30, 60]`` or ``30, 60``; ``[]`` is the empty list.
    Refuses an empty item, an unbalanced or nested bracket, and more than `MAX_ITEMS`."""
    s = text.strip()
    if len(s) > MAX_TEXT_CHARS:
        raise ParameterError(f"{field}: {len(s)} characters is too long for a list (at most "
                             f"{MAX_TEXT_CHARS})")
    if s.startswith("[") != s.endswith("]") or (s.startswith("[") and len(s) == 1):
        raise ParameterError(f"{field}: {_quoted(s)} has an unbalanced bracket")
    if s.startswith("["):
        s = s[1:-1]
    if any(c in s for c in "[]{}"):
        raise ParameterError(f"{field}: {_quoted(text.strip())} is not a flat list (write "
                             "[30, 60] or 30, 60)")
    if not s.strip():
        return []
    parts = s.split(",")
    if len(parts) > MAX_ITEMS:
        raise ParameterError(f"{field}: {len(parts)} items is too many (at most {MAX_ITEMS})")
    if any(not p.strip() for p in parts):
        raise ParameterError(f"{field}: {_quoted(text.strip())} has an empty item (two "
                             "commas, or a comma at an end)")
    return [p.strip() for p in parts]


def _parse_item(item: str, field: str, *, whole: bool, names: bool) -> Any:
    """One list item: a number, or with `names` a material name (bare or in double quotes)."""
    if names:
        if len(item) >= 2 and item[0] == item[-1] == '"':
            try:
                name = json.loads(item)
            except json.JSONDecodeError:
                raise ParameterError(f"{field}: {_quoted(item)} is not a quoted name"
                                     ) from None
            if not isinstance(name, str) or not _NAME.fullmatch(name):
                raise ParameterError(f"{field}: {_quoted(item)} is not a name (letters, "
                                     "digits, _ and -, starting with a letter)")
            return name
        if _NAME.fullmatch(item) and item.lower() not in _NON_FINITE:
            return item
    return parse_number(item, field, whole=whole)


# --- kinds and their limits --------------------------------------------------------------------

def _number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def _finite(field: str, value: Any, what: str = "a number") -> float:
    """A Python value as a finite float (an integer beyond the float range is refused, not
    converted with an `OverflowError`)."""
    if not _number(value):
        raise ParameterError(f"{field}: {show(value)} is not {what}")
    if isinstance(value, int) and abs(value) >= 10 ** 300:
        raise ParameterError(f"{field}: {show(value)} is not a finite number (beyond the "
                             "float range)")
    if not math.isfinite(float(value)):
        raise ParameterError(f"{field}: {show(value)} is not a finite number")
    return float(value)


def _items(field: str, value: Any, many: bool) -> list[Any]:
    if not many:
        return [value]
    if not isinstance(value, list):
        raise ParameterError(f"{field}: expected a list, got {show(value)}")
    if not value:
        raise ParameterError(f"{field}: the list is empty; give at least one value")
    if len(value) > MAX_ITEMS:
        raise ParameterError(f"{field}: {len(value)} items is too many (at most {MAX_ITEMS})")
    return value


def _unique(field: str, values: list[Any], key: Callable[[Any], str]) -> None:
    """Refuse two items that name the same readings (the plan needs each key once)."""
    def full(v: Any) -> str:
        return f"{v:.12g}" if isinstance(v, float) and math.isfinite(v) else show(v)

    seen: dict[str, Any] = {}
    for v in values:
        k = key(v)
        if k in seen:
            same = "twice" if full(seen[k]) == full(v) else \
                f"next to {full(seen[k])} (both are reading key {k})"
            raise ParameterError(f"{field}: {full(v)} is given {same}; each value once "
                                 "(it names its readings)")
        seen[k] = v


def angle_key(angle_deg: float) -> str:
    """30 → "a30", 32.5 → "a32.5", -10 → "a-10"."""
    a = float(angle_deg)
    return f"a{int(a)}" if a.is_integer() else f"a{a:g}"


def signed_key(prefix: str, angle_deg: float) -> str:
    """("i", -80) → "i-80", ("o", 40) → "o+40", ("o", 0) → "o+0"."""
    a = float(angle_deg)
    text = f"{int(a):+d}" if a.is_integer() else f"{a:+g}"
    return prefix + text


def _is_patch_number_text(v: Any) -> bool:
    return isinstance(v, str) and v.strip().isascii() and v.strip().isdigit()


def material_key(m: Any) -> str:
    """The reading-key part of a material: patch 7 (or "7") → "p07", "wall" → "wall"."""
    if _number(m) or _is_patch_number_text(m):
        return f"p{int(m):02d}"
    return str(m)


def _lab_config(lab: Any) -> Any:
    """The `LabConfig` of a lab (or the config itself); None for a lab without one.  By
    shape, not by class: the lab config checks its protocol defaults with these kinds, so
    this module imports neither `acquire.config` nor `acquire.lab`."""
    for candidate in (lab, getattr(lab, "config", None)):
        if isinstance(getattr(candidate, "instruments", None), dict) \
                and hasattr(candidate, "protocols"):
            return candidate
    return None


def angle_limits_deg(lab: Any, role: str) -> tuple[float, float, str] | None:
    """(min, max, source) of the instrument of `role`: the lab config's
    ``min_angle_deg`` / ``max_angle_deg``, else its driver's default; None when the lab (or
    its config) is not known or has no such instrument."""
    import inspect

    from normbox_lab.acquire.registry import driver_class

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
    role named by the parameter `role_param`, or the fixed `role`.  `many`: a non-empty list,
    each angle once (`unique`: two angles with one reading key are refused)."""

    role_param: str = ""
    role: str = ""
    many: bool = True
    unique: bool = True

    whole = False
    names = False

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        role = str(params.get(self.role_param, "")) if self.role_param else self.role
        limits = angle_limits_deg(lab, role) if role else None
        values = _items(field, value, self.many)
        for v in values:
            a = _finite(field, v, "an angle in degrees")
            if limits is not None and not limits[0] <= a <= limits[1]:
                raise ParameterError(f"{field}: {show(v)}° is outside {limits[0]:g}…"
                                     f"{limits[1]:g}° (the {role}'s range, {limits[2]})")
        if self.many and self.unique:
            _unique(field, values, angle_key)


@dataclass(frozen=True)
class Patches:
    """ColorChecker patch numbers 1–24 (whole numbers); `names`: also material names such as
    "wall"; `many`: a non-empty list, each patch or material once."""

    many: bool = True
    names: bool = False

    whole = True

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        count = PATCH_COUNT
        values = _items(field, value, self.many)
        for v in values:
            if self.names and isinstance(v, str) and not _is_patch_number_text(v):
                if not _NAME.fullmatch(v):
                    raise ParameterError(f"{field}: {show(v)} is not a material name "
                                         "(letters, digits, _ and -, starting with a letter)")
                continue
            n: Any = int(v.strip()) if _is_patch_number_text(v) else v
            bad = ParameterError(f"{field}: {show(v)} is not a patch number (1–{count}"
                                 + (", or a material name" if self.names else "") + ")")
            if not _number(n):
                raise bad
            x = _finite(field, n, "a patch number")
            if x != int(x) or not 1 <= int(x) <= count:
                raise bad
        if self.many:
            _unique(field, values, material_key)


@dataclass(frozen=True)
class Count:
    """A whole number ≥ `minimum` (default 1: a positive count), at most `maximum`."""

    minimum: int = 1
    maximum: int = 100_000

    many = False
    whole = True
    names = False

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        n = _finite(field, value, "a whole number")
        if n != int(n):
            raise ParameterError(f"{field}: {show(value)} is not a whole number")
        if self.minimum == 1 and n < 1:
            raise ParameterError(f"{field}: {show(value)} is not a positive count (≥ 1)")
        if not self.minimum <= n <= self.maximum:
            raise ParameterError(f"{field}: {show(value)} is outside {self.minimum}…"
                                 f"{self.maximum}")


@dataclass(frozen=True)
class Positive:
    """A finite number > 0 (≥ 0 with `zero`), in `unit`, at most `maximum`."""

    unit: str = ""
    zero: bool = False
    maximum: float = math.inf

    many = False
    whole = False
    names = False

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        x = _finite(field, value)
        unit = f" {self.unit}" if self.unit else ""
        if x < 0 or (x == 0 and not self.zero):
            raise ParameterError(f"{field}: {show(value)}{unit} must be "
                                 + ("≥ 0" if self.zero else "> 0"))
        if x > self.maximum:
            raise ParameterError(f"{field}: {show(value)}{unit} is above {self.maximum:g}"
                                 f"{unit}")


@dataclass(frozen=True)
class Number:
    """A finite number from `minimum` to `maximum` (`above`: strictly above `minimum`);
    `whole`: an integer; `unit` for the messages.  The kind of the commands' numeric
    options (`--time-scale`, `--max-faults` …)."""

    minimum: float = -math.inf
    maximum: float = math.inf
    whole: bool = False
    unit: str = ""
    above: bool = False

    many = False
    names = False

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        x = _finite(field, value, "a whole number" if self.whole else "a number")
        unit = f" {self.unit}" if self.unit else ""
        if self.whole and x != int(x):
            raise ParameterError(f"{field}: {show(value)} is not a whole number")
        if x < self.minimum or (self.above and x == self.minimum):
            raise ParameterError(f"{field}: {show(value)}{unit} must be "
                                 f"{'>' if self.above else '≥'} {self.minimum:g}{unit}")
        if x > self.maximum:
            raise ParameterError(f"{field}: {show(value)}{unit} is above {self.maximum:g}"
                                 f"{unit}")


@dataclass(frozen=True)
class Role:
    """The name of an instrument role of the lab (checked when the lab's config is known);
    `needs`: the capabilities (`core.capabilities` names) the protocol asks of it, so that
    ``radiometer=rotator`` is refused as a parameter (one line, exit 2), not later by a step."""

    needs: tuple[str, ...] = ()

    many = False
    whole = False
    names = True

    def check(self, field: str, value: Any, params: Mapping[str, Any], lab: Any) -> None:
        if not isinstance(value, str) or not value.strip():
            raise ParameterError(f"{field}: expected the name of an instrument role")
        config = _lab_config(lab)
        if config is None:
            return
        roles = list(config.instruments)
        if value == "gonio":
            return
        if value not in roles:
            raise ParameterError(f"{field}: {show(value)} is not an instrument of this lab "
                                 f"({', '.join(roles)})")
        if not self.needs:
            return
        from normbox_lab.acquire.registry import driver_class
        from normbox_lab.core.capabilities import capabilities_of

        def has(role: str) -> tuple[str, ...]:
            try:
                return capabilities_of(driver_class(config.instruments[role].driver))
            except (NormboxError, ImportError):
                return ()

        driver = config.instruments[value].driver
        missing = [c for c in self.needs if c not in has(value)]
        if missing:
            fit = [r for r in roles if all(c in has(r) for c in self.needs)]
            hint = f"; this lab's: {', '.join(fit)}" if fit else ""
            raise ParameterError(f"{field}: {show(value)} ({driver}) is not "
                                 f"{' and '.join(missing)}{hint}")


Limit = Angles | Patches | Count | Positive | Number | Role

#: what the shipped protocols ask of a role they are given (`Role(needs)`)
MOVES = ("Movable",)
READS_SPECTRA = ("SpectrumReadable",)
LAMP = ("Settling",)


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


# --- text → value ------------------------------------------------------------------------------

def parse_param(default: Any, text: str, field: str = "parameter",
                kind: Limit | None = None) -> Any:
    """`--param K=V` and the console's parameter form: the text parsed as a value of the
    default's shape (a number, a list, true/false, a name) and, with `kind`, its whole-ness
    and names.  Limits are checked by `check_parameters` where the plan is built (they may
    depend on other parameters and on the lab)."""
    if not isinstance(text, str):
        raise ParameterError(f"{field}: expected text, got {show(text)}")
    if len(text) > MAX_TEXT_CHARS:
        raise ParameterError(f"{field}: {len(text)} characters is too long (at most "
                             f"{MAX_TEXT_CHARS})")
    if isinstance(default, str):
        return text
    if isinstance(default, bool):
        word = text.strip().lower()
        if word not in ("true", "false"):
            raise ParameterError(f"{field}: expected true or false, got {_quoted(text)}")
        return word == "true"
    if _number(default):
        whole = isinstance(default, int) or bool(getattr(kind, "whole", False))
        value = parse_number(text, field, whole=whole)
        return float(value) if isinstance(default, float) and not whole else value
    if isinstance(default, list):
        numeric = bool(default) and all(_number(v) for v in default)
        names = bool(getattr(kind, "names", False)) or not numeric
        whole = bool(getattr(kind, "whole", False)) or (
            numeric and all(isinstance(v, int) for v in default) and isinstance(kind, Patches))
        return [_parse_item(item, field, whole=whole, names=names)
                for item in parse_items(text, field)]
    raise ParameterError(f"{field}: a parameter of type {type(default).__name__} cannot be "
                         "given as text")


def read(text: str, kind: Limit, field: str, *, params: Mapping[str, Any] | None = None,
         lab: Any = None) -> Any:
    """The value of `text` as `kind` within its limits, or `ParameterError` (one line).  A
    list kind (`many`) reads a list; a whole kind an `int`."""
    if not isinstance(text, str):
        raise ParameterError(f"{field}: expected text, got {show(text)}")
    if kind.many:
        value: Any = [_parse_item(item, field, whole=kind.whole, names=kind.names)
                      for item in parse_items(text, field)]
    elif isinstance(kind, Role):
        value = text.strip()
    else:
        value = parse_number(text, field, whole=kind.whole)
    kind.check(field, value, params or {}, lab)
    return value


#: the kinds of the numeric options that several commands share
SEED = Number(0, 2 ** 63 - 1, whole=True)
TIME_SCALE = Number(0, 1000)                  # ×0 (instant) … ×1000 of real time
WORKERS = Number(1, 1024, whole=True)
PROBABILITY = Number(0, 1)


#: the numbers of a fault rule (``sim://DEVICE?faults=SPEC``, ``sim serve --faults``, a
#: campaign's replay): KIND=P (a probability per opportunity), KIND@N (once, at the N-th
#: opportunity), :X (the kind's parameter: seconds late, a fraction of full scale …)
FAULT_AT = Number(1, 1_000_000_000, whole=True)
FAULT_PARAMETER = Number(-1e12, 1e12)
_FAULT_KIND = re.compile(r"[a-z][a-z0-9-]{0,31}")


@dataclass(frozen=True)
class FaultRuleText:
    """One rule of a fault spec, read: ``garble=0.01`` → ("garble", "=", 0.01, None)."""

    kind: str
    mode: str                  # "=" a rate per opportunity, "@" once at the n-th
    value: float               # the rate, or n
    param: float | None = None


def parse_fault_spec(spec: str, field: str = "faults") -> list[FaultRuleText]:
    """A fault spec (``KIND``, ``KIND=P``, ``KIND@N``, each with an optional ``:X``, comma
    separated) read with the one parser: every number through its kind (``garble@٣``,
    ``garble=NaN``, a 30-digit count are refused here, not read by ``float()`` or left to
    fire never), each kind named once (a second rule of a kind replaced the first silently).
    Which kinds a device has is the emulator's table (``sim.core.fault_table``)."""
    if not isinstance(spec, str):
        raise ParameterError(f"{field}: expected a fault spec, got {show(spec)}")
    if len(spec) > MAX_TEXT_CHARS:
        raise ParameterError(f"{field}: {len(spec)} characters is too long for a fault spec "
                             f"(at most {MAX_TEXT_CHARS})")
    rules: list[FaultRuleText] = []
    if not spec.strip():
        return rules
    for item in (s.strip() for s in spec.split(",")):
        if not item:
            raise ParameterError(f"{field}: {_quoted(spec)} has an empty rule (two commas, "
                                 "or a comma at an end)")
        where = f"{field} {_quoted(item)}"
        head, colon, param_text = item.partition(":")
        mode = "@" if "@" in head else "=" if "=" in head else ""
        kind, _, value_text = head.partition(mode) if mode else (head, "", "")
        kind = kind.strip()
        if not _FAULT_KIND.fullmatch(kind):
            raise ParameterError(f"{where}: {_quoted(kind)} is not a fault kind (KIND, "
                                 "KIND=P or KIND@N, then :X)")
        value: float = 1.0
        if mode == "@":
            value = read(value_text, FAULT_AT, f"{where}: N")
        elif mode == "=":
            value = read(value_text, PROBABILITY, f"{where}: P")
        param = read(param_text, FAULT_PARAMETER, f"{where}: X") if colon else None
        if any(r.kind == kind for r in rules):
            raise ParameterError(f"{where}: {kind} is given twice; one rule per kind")
        rules.append(FaultRuleText(kind, mode or "=", value, param))
    return rules


def check_fault_values(rule: FaultRuleText, field: str = "faults") -> None:
    """A rule that arrives as Python values (a campaign's replay JSON) through the same kinds
    as its text (`parse_fault_spec`)."""
    if not isinstance(rule.kind, str) or not _FAULT_KIND.fullmatch(rule.kind):
        raise ParameterError(f"{field}: {show(rule.kind)} is not a fault kind")
    if rule.mode not in ("=", "@"):
        raise ParameterError(f"{field} {rule.kind}: mode {show(rule.mode)} is not = or @")
    (FAULT_AT if rule.mode == "@" else PROBABILITY).check(f"{field} {rule.kind}",
                                                         rule.value, {}, None)
    if rule.param is not None:
        FAULT_PARAMETER.check(f"{field} {rule.kind}: X", rule.param, {}, None)


#: the numeric options of the emulators (``sim://DEVICE?K=V``, ``sim serve --option K=V``):
#: the emulators convert the text with float()/int(), which read "٣" as 3 and take NaN,
#: 1e400 or a negative time factor; their text is read here first, as every number typed
EMULATOR_OPTIONS: dict[str, Limit] = {
    "baud": Count(1, 10_000_000),
    "time_factor": Positive(zero=True, maximum=1e6),
    "max_luminance_cd_m2": Positive("cd/m²", maximum=1e12),
}


def check_emulator_options(options: Mapping[str, str], field: str = "option") -> None:
    """Every numeric emulator option's text through its kind (`EMULATOR_OPTIONS`); raises
    `ParameterError` naming it.  Other options are the emulator's to check."""
    for key, text in options.items():
        if key in EMULATOR_OPTIONS:
            read(str(text), EMULATOR_OPTIONS[key], f"{field} {key}")


def option(kind: Limit, field: str = "") -> Callable[[str], Any]:
    """An argparse ``type=`` for a numeric option: the text read as `kind` within its
    limits; a refusal becomes argparse's one-line error (the command exits 2)."""
    import argparse

    def parse(text: str) -> Any:
        try:
            return read(text, kind, field or "value")
        except ParameterError as exc:
            message = str(exc)
            prefix = f"{field or 'value'}: "
            raise argparse.ArgumentTypeError(message.removeprefix(prefix)) from None

    parse.__name__ = "number"
    return parse


__all__ = [
    "EMULATOR_OPTIONS",
    "FAULT_AT",
    "FAULT_PARAMETER",
    "LAMP",
    "MAX_ITEMS",
    "MAX_NUMBER_CHARS",
    "MAX_TEXT_CHARS",
    "MOVES",
    "PROBABILITY",
    "READS_SPECTRA",
    "SEED",
    "TIME_SCALE",
    "WORKERS",
    "Angles",
    "Count",
    "FaultRuleText",
    "Limit",
    "Number",
    "ParameterError",
    "Patches",
    "Positive",
    "Role",
    "angle_key",
    "angle_limits_deg",
    "check_emulator_options",
    "check_fault_values",
    "check_parameters",
    "material_key",
    "option",
    "parse_fault_spec",
    "parse_items",
    "parse_number",
    "parse_param",
    "read",
    "show",
    "signed_key",
]
