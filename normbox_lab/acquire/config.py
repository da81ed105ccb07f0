"""The lab config (TOML): instruments, Normbox geometry, protocol defaults.

Every error names the file, the line and the field (`ConfigError`).  `tomllib` gives no line
numbers for values, so `_Locator` finds the line of a key inside its table in the source text.

    [lab]
    name = "Normbox (simulated)"
    simulated = true
    time_scale = 0.0        # simulated labs: virtual clock, 0 = instant, 1 = real time
    seed = 1

    [instruments.radiometer]
    driver = "cs1000a"      # cs1000a | cs2000a
    port = "sim://cs1000a"  # /dev/ttyUSB0, COM3, socket://host:port or sim://DEVICE?options
    baud = 9600
    serial_number = "…"     # optional: the instrument `lab discover` found (lab check compares)

    [instruments.radiometer.calibration]      # optional: the certificate in force
    certificate = "DAkkS-12345"
    date = 2026-03-02
    due = 2027-03-02
    laboratory = "…"
    uncertainty_percent = 2.0                 # stated expanded uncertainty (k = 2)
    responsivity_file = "cal/cs1000a.csv"     # radiometer: spectral responsivity correction

    [geometry]              # DESIGN §1; every field has the Normbox default
    box_inner_mm = 600.0
    ...

    [protocols.reference-sweep]
    angles_deg = [30, 35, ..., 90]
"""

from __future__ import annotations

import datetime
import hashlib
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from normbox_lab.acquire.quality import QualityLimits, parse_limits
from normbox_lab.acquire.registry import (
    REQUIRED_ROLES,
    ROLES,
    driver_options,
    drivers_for,
    entry,
)
from normbox_lab.core.errors import ConfigError
from normbox_lab.core.geometry import NormboxGeometry

#: the roles and drivers a config may name, and each driver's options, come from the one
#: driver registry (`normbox_lab.acquire.registry`; options derived from the drivers' signatures)
BAUD_RATES = (4800, 9600, 19200, 38400, 57600, 115200)


@dataclass(frozen=True)
class Calibration:
    """An instrument's calibration certificate, as the lab config states it.

    `uncertainty_percent` is the certificate's stated expanded uncertainty (with `coverage_k`);
    `responsivity_file` (radiometer) a spectral responsivity correction, CSV of wavelength_nm
    and factor, path relative to the config, recorded with its SHA-256 so a run names the
    exact file it rests on."""

    certificate: str
    date: datetime.date
    due: datetime.date
    laboratory: str
    uncertainty_percent: float
    coverage_k: float = 2.0
    responsivity_file: str = ""
    responsivity_sha256: str = ""

    def expired(self, on: datetime.date) -> bool:
        return on > self.due

    def as_dict(self) -> dict[str, Any]:
        """The record stored with each run (ISO dates)."""
        d = {"certificate": self.certificate, "date": self.date.isoformat(),
             "due": self.due.isoformat(), "laboratory": self.laboratory,
             "uncertainty_percent": self.uncertainty_percent, "coverage_k": self.coverage_k}
        if self.responsivity_file:
            d.update(responsivity_file=self.responsivity_file,
                     responsivity_sha256=self.responsivity_sha256)
        return d


#: the fields of an [instruments.ROLE.calibration] table: name → (required, TOML type)
CALIBRATION_FIELDS: dict[str, tuple[bool, type | tuple[type, ...]]] = {
    "certificate": (True, str), "date": (True, datetime.date), "due": (True, datetime.date),
    "laboratory": (True, str), "uncertainty_percent": (True, (int, float)),
    "coverage_k": (False, (int, float)), "responsivity_file": (False, str)}
#: instrument-table keys that are the config's, not the driver's options
INSTRUMENT_KEYS = ("driver", "port", "serial_number", "calibration")


@dataclass(frozen=True)
class InstrumentConfig:
    role: str
    driver: str
    port: str
    options: dict[str, Any] = field(default_factory=dict)
    #: the serial number the instrument must report (`lab check`); "" = not checked
    serial_number: str = ""
    calibration: Calibration | None = None

    @property
    def simulated(self) -> bool:
        return self.port.startswith("sim://")


@dataclass(frozen=True)
class LabConfig:
    path: str
    name: str
    simulated: bool
    time_scale: float | None        # None: real clock
    seed: int
    instruments: dict[str, InstrumentConfig]
    geometry: NormboxGeometry
    protocols: dict[str, dict[str, Any]]
    render: dict[str, Any]
    text: str = ""                  # the source, snapshotted into every run
    quality: QualityLimits = field(default_factory=QualityLimits)   # [quality] gate limits
    #: a run (other than lab-check) needs a passing `lab check` younger than this; None: not
    require_check_h: float | None = None

    def calibrations(self) -> dict[str, Calibration]:
        """Role → the calibration in the config (roles without one are left out)."""
        return {r: i.calibration for r, i in self.instruments.items() if i.calibration}

    def protocol_defaults(self, name: str) -> dict[str, Any]:
        return dict(self.protocols.get(name, {}))


class _Locator:
    """Line numbers of tables and keys in a TOML source (1-based; 0 when not found)."""

    def __init__(self, text: str) -> None:
        self.lines = text.splitlines()

    def line_of(self, table: str, key: str | None = None) -> int:
        header = None
        for i, raw in enumerate(self.lines, 1):
            s = raw.strip()
            if s.startswith("[") and not s.startswith("[["):
                end = s.find("]")
                name = s[1:end if end > 0 else None].replace('"', "").replace(" ", "")
                header = name
                if key is None and name == table:
                    return i
                continue
            if key is not None and header == table:
                k = s.split("=", 1)[0].strip().strip('"') if "=" in s else None
                if k == key:
                    return i
        if key is not None and table:
            found = self.line_of(table)
            if found:
                return found
        # not a [header] of its own (an inline or dotted table): the first line naming it
        last = (key or table).rsplit(".", 1)[-1]
        for i, raw in enumerate(self.lines, 1):
            if last and last in raw:
                return i
        if "." in table:
            return self.line_of(table.rsplit(".", 1)[0])
        return 1 if self.lines else 0


#: protocol parameters that name ColorChecker patches (1–24; brdf-inplane also "wall")
_PATCH_PARAMETERS = ("patch", "patches", "materials")
_COUNT_PARAMETERS = ("repeats", "rows", "columns")


def _shipped_parameters(name: str) -> dict[str, Any] | None:
    """The PARAMETERS of a shipped protocol, None for any other name (a user's .py file)."""
    import importlib
    import importlib.util

    module_name = "normbox_lab.protocols." + name.replace("-", "_")
    if not name.replace("-", "_").isidentifier() or name.startswith("_") \
            or importlib.util.find_spec(module_name) is None:
        return None
    return dict(getattr(importlib.import_module(module_name), "PARAMETERS", {}))


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) < 1e300 \
        and math.isfinite(v)


def _parameter_problem(shipped: dict[str, Any] | None, key: str, value: Any) -> str:
    """Why `value` cannot be the default of protocol parameter `key` ("" when it can)."""
    if shipped is None:
        return ""
    if key not in shipped:
        return f"unknown parameter; known: {', '.join(sorted(shipped))}"
    default = shipped[key]
    items = value if isinstance(value, list) else [value]
    if isinstance(default, list):
        if not isinstance(value, list) or not value or len(value) > 10_000:
            return f"must be a non-empty list like {default[:3]!r}…, got {value!r}"[:200]
        kinds = {type(d) for d in default}
    else:
        if isinstance(value, list):
            return f"must be a single value like {default!r}, not a list"
        kinds = {type(default)}
    for v in items:
        if str in kinds and isinstance(v, str):
            continue
        if bool in kinds:
            if not isinstance(v, bool):
                return f"must be true or false, got {v!r}"
            continue
        if int in kinds and float not in kinds and key in _PATCH_PARAMETERS + _COUNT_PARAMETERS:
            if not isinstance(v, int) or isinstance(v, bool):
                return f"must be an integer, got {v!r}"
        elif (int in kinds or float in kinds) and not _is_number(v):
            return f"must be a finite number, got {v!r}"
        elif kinds == {str} and not isinstance(v, str):
            return f"must be a string, got {v!r}"
        if key in _PATCH_PARAMETERS and isinstance(v, int) and not 1 <= v <= 24:
            return f"patches are numbered 1–24, got {v}"
        if key in _COUNT_PARAMETERS and isinstance(v, int) and not 1 <= v <= 10_000:
            return f"must be 1–10000, got {v}"
        if _is_number(v) and abs(v) > 1e9:
            return f"must be of sensible size, got {v!r}"
    return ""


def _check_protocol_limits(name: str, shipped: dict[str, Any] | None,
                           values: dict[str, Any], err: Any) -> None:
    """The defaults of a shipped protocol through its declared kinds and limits (`LIMITS`,
    `normbox_lab.acquire.params`: the one validator of --param, the console and the
    protocols; angle ranges are checked when the plan is built, with the lab)."""
    import importlib

    from normbox_lab.acquire.params import ParameterError, check_parameters

    if shipped is None:
        return
    module = importlib.import_module("normbox_lab.protocols." + name.replace("-", "_"))
    limits = getattr(module, "LIMITS", None) or {}
    merged = {**shipped, **values}
    for key in values:
        try:
            check_parameters(limits, merged, None, only=key)
        except ParameterError as exc:
            raise err(f"protocols.{name}", key, str(exc).removeprefix(f"{key}: ")) from None


#: the largest lab config read (a generated one with every calibration is a few kB)
MAX_CONFIG_BYTES = 1 << 20


def load_config(path: str | Path) -> LabConfig:
    """The lab config of a file: a regular file of at most `MAX_CONFIG_BYTES` (a device such
    as /dev/zero, a FIFO or a huge file is refused with one line, never read without end)."""
    import stat

    if not str(path).strip():
        raise ConfigError(repr(str(path)), 0, "(file)", "an empty path names no file")
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode):
            raise ConfigError(str(path), 0, "(file)", "not a regular file")
        with open(path, "rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)
        if len(data) > MAX_CONFIG_BYTES:
            raise ConfigError(str(path), 0, "(file)", f"larger than {MAX_CONFIG_BYTES >> 20} "
                              "MiB: not a lab config")
        text = data.decode("utf-8")
    except FileNotFoundError:
        raise ConfigError(str(path), 0, "(file)", "no such file; create one with "
                          "`normbox-lab init LAB.toml --sim`") from None
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ConfigError(str(path), 0, "(file)", f"cannot read: {exc}") from None
    return parse_config(text, str(path))


def parse_config(text: str, path: str = "<config>") -> LabConfig:
    data = _load_toml(text, path)
    r = _Reader(text, path)
    known_top = {"lab", "instruments", "geometry", "protocols", "render", "quality"}
    for k in data:
        if k not in known_top:
            raise r.err(k, None, f"unknown table; expected one of {', '.join(sorted(known_top))}")
    name, simulated, time_scale, seed, require_check_h = _parse_lab(r, data.get("lab"))
    instruments = _parse_instruments(r, data.get("instruments"))
    geometry = _parse_geometry(r, data.get("geometry"))
    protocols = _parse_protocols(r, data.get("protocols"))
    render = dict(r.table(data.get("render"), "render"))
    if "quality" in render and render["quality"] not in ("quick", "default", "high"):
        raise r.err("render", "quality", "must be quick, default or high")
    quality = parse_limits(data.get("quality"), r.err)
    return LabConfig(path, name, simulated, time_scale, seed, instruments, geometry, protocols,
                     render, text, quality, require_check_h)


def _load_toml(text: str, path: str) -> dict[str, Any]:
    """The TOML document, or a ConfigError with the line of the syntax error."""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        line = getattr(exc, "lineno", None)
        if line is None:
            import re

            m = re.search(r"line (\d+)", str(exc))
            line = int(m.group(1)) if m else 1
        raise ConfigError(path, line, "(syntax)", str(exc)) from None
    except ValueError as exc:          # tomllib: an integer beyond Python's digit limit
        line = next((i for i, raw in enumerate(text.splitlines(), 1) if len(raw) > 4000), 1)
        raise ConfigError(path, line, "(value)", str(exc)) from None


class _Reader:
    """The checks every table of the config shares; each error names file, line and field."""

    def __init__(self, text: str, path: str) -> None:
        self.path = path
        self.loc = _Locator(text)

    def err(self, table: str, key: str | None, message: str) -> ConfigError:
        where = f"{table}.{key}" if key else table
        return ConfigError(self.path, self.loc.line_of(table, key), where, message)

    def table(self, obj: Any, name: str) -> dict[str, Any]:
        if obj is None:
            return {}
        if not isinstance(obj, dict):
            raise self.err(name.rsplit(".", 1)[0] if "." in name else "",
                           name.rsplit(".", 1)[-1], "must be a table")
        return obj

    def number(self, tab: str, d: dict[str, Any], key: str, default: float | None, *,
               minimum: float | None = None, maximum: float | None = None,
               allow_none: bool = False) -> float | None:
        v = d.get(key, default)
        if v is None and allow_none:
            return None
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.err(tab, key, f"must be a number, got {type(v).__name__} {v!r}")
        if not (abs(v) < 1e300 and math.isfinite(v)):      # (an int beyond float range too)
            raise self.err(tab, key, "must be finite")
        if minimum is not None and v < minimum:
            raise self.err(tab, key, f"must be ≥ {minimum}, got {v}")
        if maximum is not None and v > maximum:
            raise self.err(tab, key, f"must be ≤ {maximum}, got {v}")
        return float(v)


def _parse_lab(r: _Reader, obj: Any) -> tuple[str, bool, float | None, int, float | None]:
    """[lab]: name, simulated, time_scale, seed, require_check_h."""
    lab = r.table(obj, "lab")
    for k in lab:
        if k not in ("name", "simulated", "time_scale", "seed", "require_check_h"):
            raise r.err("lab", k, "unknown field")
    name = lab.get("name", "Normbox")
    if not isinstance(name, str):
        raise r.err("lab", "name", "must be a string")
    simulated = lab.get("simulated", False)
    if not isinstance(simulated, bool):
        raise r.err("lab", "simulated", "must be true or false")
    time_scale = r.number("lab", lab, "time_scale", 0.0 if simulated else None, minimum=0.0,
                          allow_none=not simulated) if ("time_scale" in lab or simulated) else None
    seed = lab.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise r.err("lab", "seed", "must be an integer")
    require_check_h = r.number("lab", lab, "require_check_h", None, minimum=0.0,
                               allow_none=True) if "require_check_h" in lab else None
    return name, simulated, time_scale, seed, require_check_h


def _parse_calibration(r: _Reader, tab: str, spec: Any) -> Calibration | None:
    """[instruments.ROLE.calibration]: the certificate in force (None: none stated)."""
    if spec is None:
        return None
    if not isinstance(spec, dict):
        raise r.err(tab.rsplit(".", 1)[0], "calibration", "must be a table")
    for k in spec:
        if k not in CALIBRATION_FIELDS:
            raise r.err(tab, k, f"unknown field; known: {', '.join(CALIBRATION_FIELDS)}")
    for k, (required, want) in CALIBRATION_FIELDS.items():
        if k not in spec:
            if required:
                raise r.err(tab, None, f"{k} missing (a calibration names certificate, "
                                       "date, due, laboratory and uncertainty_percent)")
            continue
        v = spec[k]
        if isinstance(v, bool) or not isinstance(v, want) or (
                want is datetime.date and isinstance(v, datetime.datetime)):
            kind = "a date (2026-03-02)" if want is datetime.date else \
                "a string" if want is str else "a number"
            raise r.err(tab, k, f"must be {kind}, got {v!r}")
        if want is str and not v.strip():
            raise r.err(tab, k, "must not be empty")
    if spec["due"] <= spec["date"]:
        raise r.err(tab, "due", f"must be after the calibration date {spec['date']}")
    u = r.number(tab, spec, "uncertainty_percent", 0.0, minimum=0.0, maximum=100.0)
    k_cov = r.number(tab, spec, "coverage_k", 2.0, minimum=1.0, maximum=10.0)
    digest = ""
    rfile = spec.get("responsivity_file", "")
    if rfile:
        where = Path(r.path).parent / rfile
        try:
            digest = hashlib.sha256(where.read_bytes()).hexdigest()
        except OSError as exc:
            raise r.err(tab, "responsivity_file", f"cannot read {where}: "
                        f"{exc.strerror or exc}") from None
    return Calibration(spec["certificate"].strip(), spec["date"], spec["due"],
                       spec["laboratory"].strip(), float(u or 0.0), float(k_cov or 2.0),
                       rfile, digest)


def _parse_instruments(r: _Reader, obj: Any) -> dict[str, InstrumentConfig]:
    """[instruments.ROLE] for every role; the required roles must all be there."""
    instruments: dict[str, InstrumentConfig] = {}
    for role, spec in r.table(obj, "instruments").items():
        instruments[role] = _parse_instrument(r, role, spec)
    for role in REQUIRED_ROLES:
        if role not in instruments:
            raise ConfigError(r.path, r.loc.line_of("instruments") or 1, f"instruments.{role}",
                              "missing; every lab needs a radiometer, a rotator and a sphere")
    return instruments


def _check_sim_port(port: str) -> str:
    """Why a ``sim://DEVICE?faults=SPEC&seed=N&key=NAME`` port cannot be opened as written
    ("" when it can): its fault spec and seed through the one parser
    (`normbox_lab.acquire.params`), as `sim serve --faults` reads them.  Which fault kinds the
    device has is the emulator's table; the simulated lab checks them when it is built."""
    import urllib.parse

    from normbox_lab.acquire.params import SEED, ParameterError, parse_fault_spec, read

    query = urllib.parse.urlsplit(port).query
    try:
        pairs = urllib.parse.parse_qsl(query, keep_blank_values=True, strict_parsing=bool(query),
                                       max_num_fields=64)
    except ValueError as exc:
        return f"cannot read the query {query[:40]!r}: {exc}"
    names = [k for k, _ in pairs]
    twice = sorted({k for k in names if names.count(k) > 1})
    if twice:
        return f"{', '.join(twice)} given twice in the port's query"
    options = dict(pairs)
    try:
        if "faults" in options:
            parse_fault_spec(options["faults"], "faults")
        if "seed" in options:
            read(options["seed"], SEED, "seed")
    except ParameterError as exc:
        return str(exc)
    key = options.get("key")
    if key is not None and not key.replace("-", "").replace("_", "").isalnum():
        return f"key {key[:40]!r} is not a name (letters, digits, - and _)"
    return ""


def _parse_instrument(r: _Reader, role: str, spec: Any) -> InstrumentConfig:
    tab = f"instruments.{role}"
    if role not in ROLES:
        raise r.err(tab, None, f"unknown instrument role; known: {', '.join(ROLES)}")
    if not isinstance(spec, dict):
        raise r.err("instruments", role, "must be a table")
    driver = spec.get("driver")
    choices = drivers_for(role)
    if not isinstance(driver, str) or driver not in choices:
        raise r.err(tab, "driver", f"must be one of {', '.join(choices)}, got {driver!r}")
    port = spec.get("port")
    if not isinstance(port, str) or not port:
        raise r.err(tab, "port", "must be a non-empty string (device path, socket:// or "
                    "sim:// URL)")
    if port.startswith("sim://"):
        problem = _check_sim_port(port)
        if problem:
            raise r.err(tab, "port", problem)
    serial_number = spec.get("serial_number", "")
    if not isinstance(serial_number, str):
        raise r.err(tab, "serial_number", f"must be a string, got {serial_number!r}")
    cal = _parse_calibration(r, f"{tab}.calibration", spec.get("calibration"))
    options = _driver_options(r, tab, driver,
                              {k: v for k, v in spec.items() if k not in INSTRUMENT_KEYS})
    return InstrumentConfig(role, driver, port, options, serial_number, cal)


def _driver_options(r: _Reader, tab: str, driver: str,
                    options: dict[str, Any]) -> dict[str, Any]:
    """The driver's own options of an instrument table, checked against the registry's kinds
    (floats made float)."""
    allowed = driver_options(driver)
    for k, v in options.items():
        if k not in allowed:
            raise r.err(tab, k, f"unknown option for driver {driver!r}; known: "
                        f"{', '.join(sorted(allowed))}")
        want = allowed[k]
        ok = (isinstance(v, bool) if want is bool else isinstance(v, str) if want is str
              else isinstance(v, int) and not isinstance(v, bool) if want is int
              else isinstance(v, (int, float)) and not isinstance(v, bool))
        if not ok:
            raise r.err(tab, k, f"must be {want.__name__}, got {type(v).__name__} {v!r}")
        if want in (int, float) and not (abs(v) < 1e12 and math.isfinite(v)):
            raise r.err(tab, k, f"must be a finite number of sensible size, got {v!r}")
        if want is float:
            options[k] = float(v)
    if "baud" in options:
        b = options["baud"]
        rates = entry(driver).baud_rates or BAUD_RATES     # the driver's, from the registry
        if len(rates) == 1 and b != rates[0]:
            raise r.err(tab, "baud", f"{driver} runs at {rates[0]} baud only; remove the line")
        if isinstance(b, bool) or not isinstance(b, int) or b not in rates:
            raise r.err(tab, "baud", f"must be one of {rates}, got {b!r}")
    if "min_angle_deg" in options and "max_angle_deg" in options \
            and options["min_angle_deg"] >= options["max_angle_deg"]:
        raise r.err(tab, "max_angle_deg", "must be greater than min_angle_deg")
    return options


def _parse_geometry(r: _Reader, obj: Any) -> NormboxGeometry:
    """[geometry]: every field has the Normbox default."""
    geo_tab = r.table(obj, "geometry")
    geo_fields = {f.name: f.default for f in fields(NormboxGeometry)}
    for k in geo_tab:
        if k not in geo_fields:
            raise r.err("geometry", k, f"unknown field; known: {', '.join(geo_fields)}")
    geometry = NormboxGeometry(**{k: r.number("geometry", geo_tab, k, d, minimum=0.0)
                                 for k, d in geo_fields.items()})
    if geometry.aperture_x_mm >= geometry.box_inner_mm or \
            geometry.aperture_y_mm >= geometry.box_inner_mm:
        raise r.err("geometry", "aperture_x_mm", "the aperture must be smaller than the box")
    if not 0 < geometry.radiometer_view_deg <= 10:
        raise r.err("geometry", "radiometer_view_deg", "must be in (0, 10] degrees")
    return geometry


def _parse_protocols(r: _Reader, obj: Any) -> dict[str, dict[str, Any]]:
    """[protocols.NAME]: parameter defaults, checked against a shipped protocol's own."""
    protocols: dict[str, dict[str, Any]] = {}
    for pname, pvals in r.table(obj, "protocols").items():
        if not isinstance(pvals, dict):
            raise r.err("protocols", pname, "must be a table of parameter defaults")
        shipped = _shipped_parameters(pname)
        for key, value in pvals.items():
            problem = _parameter_problem(shipped, key, value)
            if problem:
                raise r.err(f"protocols.{pname}", key, problem)
        _check_protocol_limits(pname, shipped, pvals, r.err)
        protocols[pname] = dict(pvals)
    return protocols


SIM_CONFIG_TEMPLATE = """\
# normbox-lab lab config: a fully simulated Normbox (every instrument is a wire-level emulator).
# For the real lab, replace each `port` by the device path (/dev/ttyUSB0, COM3) or socket://host:port.

[lab]
name = "Normbox (simulated)"
simulated = true
time_scale = 0.0        # virtual clock: 0 = instant, 1 = real time
seed = 1

[instruments.radiometer]
driver = "cs1000a"      # cs1000a | cs2000a
port = "sim://cs1000a"
baud = 9600             # CS-1000A: 4800 | 9600 | 19200 (CS-2000A is fixed at 115200)

[instruments.rotator]   # sample holder rotation; 0° = facing the light, 90° = facing the radiometer
driver = "apt-k10cr1"   # apt-k10cr1 | zaber
port = "sim://rotator-apt"
min_angle_deg = 0.0
max_angle_deg = 95.0

[instruments.sphere]    # integrating-sphere light source (placeholder SCPI-like protocol)
driver = "sphere-scpi"
port = "sim://sphere"

[instruments.gonio_light_arm]
driver = "zaber"
port = "sim://rotator-zaber?key=gonio-light"
min_angle_deg = -90.0
max_angle_deg = 90.0

[instruments.gonio_detector_arm]
driver = "zaber"
port = "sim://rotator-zaber?key=gonio-detector"
min_angle_deg = -90.0
max_angle_deg = 90.0

[instruments.spectrometer]  # Ocean Optics QE Pro on the gonioreflectometer
driver = "qepro"
port = "sim://qepro"     # a real one: "usb:" or "usb:SERIALNUMBER" (seabreeze)

[geometry]              # DESIGN §1, lengths in mm
box_inner_mm = 600.0
wall_thickness_mm = 15.0
ceiling_thickness_mm = 19.0
aperture_x_mm = 220.0
aperture_y_mm = 200.0
patch_size_mm = 50.0
holder_size_mm = 80.0
sample_height_mm = 200.0
radiometer_distance_mm = 1000.0
radiometer_view_deg = 1.0
wall_lightness_L = 65.0
panel_homogeneity_percent = 3.0

[render]
quality = "default"     # quick | default | high

[protocols.reference-sweep]
angles_deg = [30, 35, 40, 45, 50, 55, 60, 65, 70, 75, 80, 85, 90]
patches = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16, 17, 18, 19, 20, 21, 22, 23, 24]

[protocols.brdf-inplane]
tilt_deg = 4.0

[protocols.repeatability]
repeats = 10
threshold_percent = 1.0

[quality]               # limits of the quality gates (defaults and their sources:
                        # docs/quality.md); e.g.
# fit_outlier_factor = 2.5
# tec_tolerance_c = 0.5
lamp_reference_cd_m2 = 2000.0   # the sphere's monitor (MEAS:LUM?) at its calibration, level 100 %
                                # (simulated sphere: 2000); a drift is judged against it
"""


def _toml_value(value: Any) -> str:
    if isinstance(value, datetime.date):
        return value.isoformat()
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} to TOML")


def _toml_table(name: str, values: dict[str, Any]) -> list[str]:
    lines = [f"[{name}]"]
    lines += [f"{key} = {_toml_value(v)}" for key, v in values.items() if v is not None]
    return lines + [""]


def format_config(config: LabConfig) -> str:
    """The TOML text of a `LabConfig` (what `parse_config` reads back to an equal config).

    Programs that need a variant of a config (the demo, tests) change the dataclasses with
    `dataclasses.replace` and write them with this, rather than editing TOML text.
    """
    lab = {"name": config.name, "simulated": config.simulated,
           "time_scale": config.time_scale, "seed": config.seed,
           "require_check_h": config.require_check_h}
    lines = ["# normbox-lab lab config (written by normbox-lab)", ""]
    lines += _toml_table("lab", lab)
    for role, inst in config.instruments.items():
        lines += _toml_table(f"instruments.{role}",
                             {"driver": inst.driver, "port": inst.port,
                              "serial_number": inst.serial_number or None, **inst.options})
        cal = inst.calibration
        if cal is not None:
            lines += _toml_table(f"instruments.{role}.calibration", {
                "certificate": cal.certificate, "date": cal.date, "due": cal.due,
                "laboratory": cal.laboratory, "uncertainty_percent": cal.uncertainty_percent,
                "coverage_k": cal.coverage_k, "responsivity_file": cal.responsivity_file or None})
    lines += _toml_table("geometry", {f.name: getattr(config.geometry, f.name)
                                      for f in fields(config.geometry)})
    lines += _toml_table("render", config.render)
    for name, values in config.protocols.items():
        lines += _toml_table(f"protocols.{name}", values)
    default = QualityLimits()
    limits = {f.name: getattr(config.quality, f.name) for f in fields(config.quality)
              if getattr(config.quality, f.name) != getattr(default, f.name)}
    if limits:
        lines += _toml_table("quality", limits)
    return "\n".join(lines)


def write_sim_config(path: str | Path, *, overwrite: bool = False) -> Path:
    path = Path(path)
    if path.exists() and not overwrite:
        raise ConfigError(str(path), 0, "(file)", "exists already; pass --force to overwrite")
    path.write_text(SIM_CONFIG_TEMPLATE, encoding="utf-8")
    return path
