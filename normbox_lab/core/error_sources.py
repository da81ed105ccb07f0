"""Error sources of the Normbox (the Normbox paper's error path, its §5 and Fig. 4): their
names, specs and distributions, shared by the simulator and the analysis.

Each source is a switch with a magnitude.  The virtual Normbox (`normbox_lab.sim.world`)
applies the switched-on sources where they arise in the lab, so the rest of the pipeline meets
them exactly as it would meet the real ones; `normbox-lab budget` (`normbox_lab.analyze`)
propagates the same distributions through the pipeline.  Neither imports the other: both
import this module.

A *spec* is a comma-separated list of ``name=value`` (``demo --errors SPEC``, or the lab
config's ``[render] errors = "SPEC"`` / a ``[render.errors]`` table of the same names):

    angle=1.0,angle-offset=65:+0.7;80:-0.7,cs1000=0.02,lamp=+0.01

A plain number ``x`` is a uniform distribution U(−x, +x) (a "±x" figure of a data sheet); a
signed number ``+x`` / ``-x`` is that fixed value (a known realisation, e.g. for validation);
``0`` or ``off`` switches the source off.  ``paper`` as the whole spec (or ``all=paper``) is the
paper's set, `PAPER_SPEC`.  Unknown names and bad values raise `ConfigError` naming the field.

| name | unit | what | paper (§5) | where it acts |
|---|---|---|---|---|
| angle | deg | sample angle per reading (hand placement) | — | world: the rendered angle |
| angle-sweep | deg | one misadjustment per sweep angle, shared by all patches | ±1° | world |
| angle-offset | deg | fixed per-angle offsets ``A:±x;B:±y`` | NSE 65° high, 80° low (§6.3.5) | world |
| geometry | mm | each length of the box (sample height, aperture x/y, box size), per campaign | ±1 mm | world geometry |
| cs1000 | fraction | CS-1000A radiometric gain per reading | ±2 % | world radiance |
| cs1000-wl | nm | CS-1000A wavelength shift per reading | ±0.3 nm (data sheet) | world radiance |
| qepro-snr | ratio | gonio spectrometer noise, σ = √(f·f_fs)/SNR | 1000 | world BRDF |
| qepro-nonlin | fraction | residual non-linearity f·(1 − x·f/f_fs) | 0.5 % | world BRDF |
| gonio-cal | fraction | gonio calibration gain, shared by all materials | 0.7 % | world BRDF |
| homogeneity | fraction | panel map deviates from the assumed one (same pattern) | ±3 % | world panel map |
| diffusivity | fraction | light reaching the sample vs the light map's view, per campaign | ±2.6 % | world radiance |
| lamp | fraction | lamp output, sweep vs light-map session | < 1 % | world radiance |
| render | rel. SE | the world's Monte-Carlo error per band (its renders are independent of the prediction's; this sets their target) | — | world renders |

The fitting error is not a switch here: it is the truth materials' departure from the fit
family (`--truth default|model|paper`, `predict.materials`).  f_fs is the reading's full scale
(the largest value over λ at that geometry: the integration time is set for it).
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, field, fields, replace
from typing import Any

import numpy as np

from normbox_lab.core.errors import ConfigError


@dataclass(frozen=True)
class Magnitude:
    """U(−value, +value) when not `fixed`, else exactly `value` (signed)."""

    value: float = 0.0
    fixed: bool = False

    @property
    def on(self) -> bool:
        return self.value != 0.0

    @property
    def rms(self) -> float:
        """Root mean square of the distribution."""
        return abs(self.value) if self.fixed else abs(self.value) / math.sqrt(3.0)

    def draw(self, rng: np.random.Generator, size: Any = None) -> Any:
        if self.fixed:
            return self.value if size is None else np.full(size, self.value)
        return rng.uniform(-abs(self.value), abs(self.value), size)

    def text(self) -> str:
        if not self.on:
            return "off"
        return f"{self.value:+g}" if self.fixed else f"{self.value:g}"


#: spec name → attribute name (the order of the documentation and of `budget`)
SOURCE_FIELDS: dict[str, str] = {
    "angle": "angle_deg",
    "angle-sweep": "angle_sweep_deg",
    "angle-offset": "angle_offset_deg",
    "geometry": "geometry_mm",
    "cs1000": "cs1000_gain",
    "cs1000-wl": "cs1000_shift_nm",
    "qepro-snr": "qepro_snr",
    "qepro-nonlin": "qepro_nonlinearity",
    "gonio-cal": "gonio_calibration",
    "homogeneity": "homogeneity",
    "diffusivity": "diffusivity",
    "lamp": "lamp_repeatability",
    "render": "render_rel_se",
}

#: geometry lengths perturbed by `geometry` (GeometryConfig fields, mm)
GEOMETRY_FIELDS = ("sample_height_mm", "aperture_x_mm", "aperture_y_mm", "box_inner_mm")


@dataclass(frozen=True)
class ErrorSources:
    """The switched-on error sources and their magnitudes; all off by default."""

    angle_deg: Magnitude = Magnitude()
    angle_sweep_deg: Magnitude = Magnitude()
    angle_offset_deg: dict[float, float] = field(default_factory=dict)
    geometry_mm: Magnitude = Magnitude()
    cs1000_gain: Magnitude = Magnitude()
    cs1000_shift_nm: Magnitude = Magnitude()
    qepro_snr: float = 0.0                       # 0 = off
    qepro_nonlinearity: float = 0.0
    gonio_calibration: Magnitude = Magnitude()
    homogeneity: Magnitude = Magnitude()
    diffusivity: Magnitude = Magnitude()
    lamp_repeatability: Magnitude = Magnitude()
    render_rel_se: float = 0.0                   # 0 = the world renders at its quality's target
    seed: int = 1

    # --- queries ----------------------------------------------------------------------------
    def is_on(self, name: str) -> bool:
        v = getattr(self, SOURCE_FIELDS[name])
        if isinstance(v, Magnitude):
            return v.on
        if isinstance(v, dict):
            return any(x != 0.0 for x in v.values())
        return float(v) != 0.0

    @property
    def any_on(self) -> bool:
        return any(self.is_on(n) for n in SOURCE_FIELDS)

    def on_names(self) -> list[str]:
        return [n for n in SOURCE_FIELDS if self.is_on(n)]

    def only(self, *names: str) -> ErrorSources:
        """A copy with every source but `names` off."""
        keep = {SOURCE_FIELDS[n] for n in names}
        off = ErrorSources(seed=self.seed)
        return replace(self, **{f.name: getattr(off, f.name) for f in fields(self)
                                if f.name not in keep and f.name != "seed"})

    def spec(self) -> str:
        """The spec text (round-trips through `parse_error_spec`)."""
        parts = []
        for name, attr in SOURCE_FIELDS.items():
            if not self.is_on(name):
                continue
            v = getattr(self, attr)
            if isinstance(v, Magnitude):
                parts.append(f"{name}={v.text()}")
            elif isinstance(v, dict):
                parts.append(f"{name}=" + ";".join(f"{a:g}:{x:+g}" for a, x in sorted(v.items())))
            else:
                parts.append(f"{name}={float(v):g}")
        return ",".join(parts) or "off"

    # --- draws (deterministic: seeded by the source and what it acts on) --------------------
    def rng(self, source: str, *key: Any) -> np.random.Generator:
        words = [int(self.seed), zlib.crc32(source.encode())]
        words += [zlib.crc32(repr(k).encode()) for k in key]
        return np.random.default_rng(words)

    def angle_error_deg(self, commanded_deg: float, patch: int | None, reading: int) -> float:
        """Sample-angle error of one reading: fixed offset + sweep misadjustment + random."""
        a = round(float(commanded_deg), 1)
        err = 0.0
        for angle, off in self.angle_offset_deg.items():
            if abs(a - angle) < 0.05:
                err += off
        if self.angle_sweep_deg.on:
            err += float(self.angle_sweep_deg.draw(self.rng("angle-sweep", a)))
        if self.angle_deg.on:
            err += float(self.angle_deg.draw(self.rng("angle", a, patch, reading)))
        return err

    def perturbed_geometry(self, geometry: Any) -> Any:
        """The truth geometry: lengths moved by `geometry`, the panel map by `homogeneity`."""
        changes: dict[str, float] = {}
        if self.geometry_mm.on:
            rng = self.rng("geometry")
            for name in GEOMETRY_FIELDS:
                changes[name] = getattr(geometry, name) + float(self.geometry_mm.draw(rng))
        if self.homogeneity.on:
            d = float(self.homogeneity.draw(self.rng("homogeneity")))
            changes["panel_homogeneity_percent"] = geometry.panel_homogeneity_percent + 100 * d
        return replace(geometry, **changes) if changes else geometry

    def box_light_gain(self) -> float:
        """Light on the sample relative to the light map's view: diffusivity × lamp session."""
        g = 1.0
        if self.diffusivity.on:
            g *= 1.0 + float(self.diffusivity.draw(self.rng("diffusivity")))
        if self.lamp_repeatability.on:
            g *= 1.0 + float(self.lamp_repeatability.draw(self.rng("lamp")))
        return g

    def radiometer(self, wavelength_nm: np.ndarray, radiance: np.ndarray, key: Any
                   ) -> np.ndarray:
        """The CS-1000A's gain and wavelength errors on one reading."""
        out = np.asarray(radiance, dtype=float)
        if self.cs1000_shift_nm.on:
            shift = float(self.cs1000_shift_nm.draw(self.rng("cs1000-wl", *key)))
            out = np.interp(wavelength_nm + shift, wavelength_nm, out)
        if self.cs1000_gain.on:
            out = out * (1.0 + float(self.cs1000_gain.draw(self.rng("cs1000", *key))))
        return out

    def gonio(self, brdf: np.ndarray, key: Any) -> np.ndarray:
        """The gonioreflectometer's calibration, non-linearity and noise on one reading."""
        f = np.asarray(brdf, dtype=float)
        if self.gonio_calibration.on:
            f = f * (1.0 + float(self.gonio_calibration.draw(self.rng("gonio-cal"))))
        full_scale = float(np.max(np.abs(f))) if f.size else 0.0
        if full_scale <= 0.0:
            return f
        if self.qepro_nonlinearity:
            f = f * (1.0 - self.qepro_nonlinearity * f / full_scale)
        if self.qepro_snr:
            sigma = np.sqrt(np.maximum(f, 0.0) * full_scale) / self.qepro_snr
            f = f + self.rng("qepro-snr", *key).normal(0.0, 1.0, f.shape) * sigma
        return f


#: the paper's campaign (`--truth paper`): its magnitudes (§5), with the sample-angle error as
#: the misadjustment it observed (§6.3.5: the angle is set once for all patches; its NSE,
#: reference − prediction, "slightly higher" at 65° and "slightly lower" at 80°: the sample
#: stood at a smaller angle than set at 65° (more light than predicted) and at a larger one at
#: 80°; the size 0.3° is ours, the paper gives none)
PAPER_SPEC = ("angle-offset=65:-0.3;80:+0.3,geometry=1,cs1000=0.02,cs1000-wl=0.3,"
              "qepro-snr=1000,qepro-nonlin=0.005,gonio-cal=0.007,homogeneity=0.03,"
              "diffusivity=0.026,lamp=0.01")
#: the paper's figures as distributions (what `budget` assumes for a run without a spec): the
#: ±1° of the angle setting as one draw per sweep angle
PAPER_FIGURES = ("angle-sweep=1,geometry=1,cs1000=0.02,cs1000-wl=0.3,qepro-snr=1000,"
                 "qepro-nonlin=0.005,gonio-cal=0.007,homogeneity=0.03,diffusivity=0.026,"
                 "lamp=0.01")


def _fail(field_name: str, message: str, source: str) -> ConfigError:
    return ConfigError(source, 0, f"errors.{field_name}", message)


def _magnitude(name: str, text: str, source: str) -> Magnitude:
    t = text.strip()
    if t.lower() in ("off", "0", "+0", "-0", ""):
        return Magnitude()
    try:
        value = float(t)
    except ValueError:
        raise _fail(name, f"not a number: {text!r} (x = ±x uniform, +x/-x fixed, off)",
                    source) from None
    if not math.isfinite(value):
        raise _fail(name, f"not finite: {text!r}", source)
    fixed = t[0] in "+-"
    if not fixed and value < 0:
        raise _fail(name, f"must be ≥ 0: {text!r}", source)
    return Magnitude(value, fixed)


def _offsets(text: str, source: str) -> dict[float, float]:
    if text.strip().lower() in ("off", "0", ""):
        return {}
    out: dict[float, float] = {}
    for item in text.split(";"):
        angle, sep, value = item.partition(":")
        try:
            if not sep:
                raise ValueError
            out[round(float(angle), 1)] = float(value)
        except ValueError:
            raise _fail("angle-offset", f"expected ANGLE:±DEG;..., got {item!r}",
                        source) from None
    return out


def _plain(name: str, text: str, source: str) -> float:
    t = text.strip().lower()
    if t in ("off", "0", ""):
        return 0.0
    try:
        value = float(t)
    except ValueError:
        raise _fail(name, f"not a number: {text!r}", source) from None
    if value < 0 or not math.isfinite(value):
        raise _fail(name, f"must be a finite number ≥ 0: {text!r}", source)
    return value


def parse_error_spec(spec: str | dict[str, Any] | None, *, source: str = "--errors",
                     seed: int = 1) -> ErrorSources:
    """`ErrorSources` from a spec string or a table (see the module doc)."""
    if spec is None:
        return ErrorSources(seed=seed)
    if isinstance(spec, dict):
        items = [(str(k), str(v)) for k, v in spec.items()]
    else:
        text = spec.strip()
        if text.lower() in ("", "off", "none"):
            return ErrorSources(seed=seed)
        items = []
        for part in text.split(","):
            if not part.strip():
                continue
            name, sep, value = part.partition("=")
            if not sep and name.strip().lower() == "paper":
                name, value = "all", "paper"
            elif not sep:
                raise _fail(name.strip(), f"expected NAME=VALUE, got {part.strip()!r}", source)
            items.append((name.strip(), value.strip()))
    values: dict[str, Any] = {}
    for name, value in items:
        key = name.lower()
        if key == "all" or (key == "paper" and not value):
            if value.lower() not in ("paper", ""):
                raise _fail("all", f"only 'all=paper' is known, got {value!r}", source)
            base = parse_error_spec(PAPER_SPEC, source=source, seed=seed)
            values.update({f.name: getattr(base, f.name) for f in fields(base)})
            continue
        if key == "seed":
            try:
                values["seed"] = int(value)
            except ValueError:
                raise _fail("seed", f"not an integer: {value!r}", source) from None
            continue
        if key not in SOURCE_FIELDS:
            raise _fail(name, f"unknown error source; known: {', '.join(SOURCE_FIELDS)}",
                        source)
        attr = SOURCE_FIELDS[key]
        if key == "angle-offset":
            values[attr] = _offsets(value, source)
        elif key in ("qepro-snr", "qepro-nonlin", "render"):
            values[attr] = _plain(key, value, source)
        else:
            values[attr] = _magnitude(key, value, source)
    values.setdefault("seed", seed)
    return ErrorSources(**values)


def error_sources_from_config(config: Any, override: str | None = None) -> ErrorSources:
    """The lab config's ``[render] errors`` (string or table), then `override` on top."""
    render_cfg = dict(getattr(config, "render", None) or {})
    seed = int(getattr(config, "seed", 1) or 1)
    where = f"{getattr(config, 'path', 'lab config')}: [render] errors"
    base = parse_error_spec(render_cfg.get("errors"), source=where, seed=seed)
    if override is None:
        return base
    extra = parse_error_spec(override, source="--errors", seed=base.seed)
    given = _given_fields(override)
    return replace(base, **{a: getattr(extra, a) for a in given})


def _given_fields(spec: str) -> list[str]:
    text = spec.strip()
    if text.lower() in ("paper", "all=paper"):
        return [f.name for f in fields(ErrorSources) if f.name != "seed"]
    out = []
    for part in text.split(","):
        name = part.partition("=")[0].strip().lower()
        if name in ("all", "paper"):
            out += [f.name for f in fields(ErrorSources) if f.name != "seed"]
        elif name in SOURCE_FIELDS:
            out.append(SOURCE_FIELDS[name])
        elif name == "seed":
            out.append("seed")
    return out
