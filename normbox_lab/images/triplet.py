"""MIST wavelength-triplet rendering: the spectral Normbox view from an RGB renderer.

Hao & Funt (MIST, 2020) render spectral images with Blender Cycles, an RGB renderer, by putting
the scene's spectra at three wavelengths into the R, G and B channels and repeating the render
for the next three wavelengths until the range is covered.  Here the same trick runs in
Mitsuba's RGB variant (`llvm_ad_rgb`; `cuda_ad_rgb` where the project's spectral variant is CUDA;
`scalar_rgb` where LLVM does not work) as an independent cross-check of the project's spectral
renderers (`normbox_lab.predict.render`, stock Mitsuba with the Python `NormboxBSDF`, and
`normbox_lab.predict.fastrender`): different variant, different BSDF code, different wavelength
sampling, different emitter set-up — same expected radiance.

    r = render_triplets(patch, wall, angle_deg=30.0, spp=64, batches=16, seed=1)
    r.wavelength_nm, r.radiance, r.std_error            # W·sr⁻¹·m⁻²·nm⁻¹ per band
    r.z_scores(render.render_view(...))                  # (triplet − spectral) / combined SE

How one render is set up (the Normbox scene of `normbox_lab.predict.scene.scene_dict`, radiometer view,
10 × 10 px, an RGB `hdrfilm` of the same sensor):
- Materials: Mitsuba built-ins that *are* the fit-model family (reference notes §4, verified
  there to 6 digits against the closed form):
      twosided(blendbsdf(weight 0.5, a = diffuse(2·kd), b = roughconductor(ggx, α, η, k = 0,
                                                                            specular_reflectance 2·ks)))
  = kd/π + ks·D·F(η)·G1·G1/(4 cosθi cosθo) on both sides, as the `NormboxBSDF` (two-sided too).
  roughconductor with k = 0 is the exact unpolarised dielectric Fresnel of the family.  Not
  representable by built-ins, hence refused (ValueError): c ≠ 0 (the "− c"), a backscatter lobe
  kb, a dispersive η (dη ≠ 0) — i.e. the cross-check takes `Material.is_model_family`
  materials with c = 0 (`truth_material(..., truth="model")`, fitted materials `.without_c()`).
- Colour values: reflectances go in as `{"type": "srgb", "color": [v_R, v_G, v_B],
  "unbounded": True}`.  In `*_rgb` variants Mitsuba 3.9's `srgb` texture stores the colour
  as-is (no spectral upsampling, no gamut mapping, no clamping); the plain
  `{"type": "rgb", "value": ...}` shorthand refuses reflectances outside [0, 1] (and 2·kd can
  exceed 1).  Emitter radiance goes in as `{"type": "rgb", "value": [...]}`, which emitters
  accept unbounded and, in RGB variants, use as-is (no D65 multiplication: that is only done in
  spectral variants).  Checked by `test_triplet.py::test_rgb_values_are_used_as_is`
  (ρ = (1.2, 0.5, 2.0) under L = (3, 0.2, 7.5): the render gives the products).
- The lamp: the 25 emitting panel cells of `scene_dict` (each lamp(λ) × its homogeneity factor)
  instead of the stock renderer's single textured emitter: the same radiance field, a different
  emitter sampling.

Point wavelengths vs 5 nm bands ("exact in expectation"): a spectral band is the average of the
radiance under a unit triangular hat of half-width 5 nm (`render.band_film`).  Each batch draws,
per band, one wavelength from that triangular distribution, λ = centre + δ, δ ~ Tri(−5, 0, 5) nm,
and evaluates every spectrum exactly as the spectral renderer does at λ (materials: linear on
the `NormboxBSDF`'s 5 nm grid; lamp: linear on `render.LAMP_GRID_NM`).  The batch value is then
an unbiased estimate of the band average, and batch-to-batch spread (independent δ, independent
seeds) gives the standard error, jitter included.  `band_width_nm=0` renders point wavelengths.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from normbox_lab.core.spectral import BAND_WAVELENGTHS_NM
from normbox_lab.predict.kernel_safety import jit_table, require_finite

#: default bands: those of the stock spectral renderer (380…780 nm step 5, 5 nm hats)
DEFAULT_WAVELENGTHS_NM = BAND_WAVELENGTHS_NM
DEFAULT_BAND_WIDTH_NM = 5.0


@dataclass
class TripletResult:
    """Per-band radiance (W·sr⁻¹·m⁻²·nm⁻¹) from wavelength-triplet renders, mean over batches."""

    wavelength_nm: np.ndarray       # band centres (B,)
    radiance: np.ndarray            # (B,)
    std_error: np.ndarray           # standard error of the mean over batches (B,)
    batches: np.ndarray             # (n_batches, B)
    render_time_s: float
    variant: str
    renders: int                    # RGB renders done (triplets × batches)
    spp: int                        # samples per pixel per render
    info: dict[str, Any] = field(default_factory=dict)

    @property
    def relative_std_error(self) -> np.ndarray:
        return self.std_error / np.maximum(np.abs(self.radiance), 1e-300)

    def z_scores(self, other: Any) -> np.ndarray:
        """(self − other) / √(SE² + SE_other²) per band; `other` has .wavelength_nm, .radiance
        and .std_error on the same bands (a `render.RenderResult` or another TripletResult)."""
        wl = np.asarray(other.wavelength_nm, dtype=np.float64)
        if wl.shape != self.wavelength_nm.shape or not np.allclose(wl, self.wavelength_nm):
            raise ValueError("z_scores: the two results are on different bands")
        se = np.hypot(self.std_error, np.asarray(other.std_error, dtype=np.float64))
        return (self.radiance - np.asarray(other.radiance, dtype=np.float64)) / \
            np.maximum(se, 1e-300)


# --- materials and emitters as RGB triples --------------------------------------------------------
def check_representable(material: Any) -> None:
    """Raise ValueError unless Mitsuba's built-ins represent `material` exactly (see module doc)."""
    if float(material.c) != 0.0:
        raise ValueError(f"material {material.name}: c = {material.c} ≠ 0 has no built-in "
                         "Mitsuba equivalent; use material.without_c()")
    if not material.is_model_family:
        raise ValueError(f"material {material.name}: backscatter lobe or dispersive η "
                         "(truth='default') has no built-in Mitsuba equivalent; use the "
                         "fit-model family (truth='model')")


def material_rgb(material: Any, wavelengths_nm: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(kd, ks) at each of the (3,) wavelengths, interpolated exactly as the spectral renderer's
    `NormboxBSDF` does (linear between its 5 nm grid values)."""
    from normbox_lab.predict.mitsuba_bsdf import GRID_NM

    kd_grid, ks_grid, _ = material.spectra_at(GRID_NM)
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    return np.interp(wl, GRID_NM, kd_grid), np.interp(wl, GRID_NM, ks_grid)


def _srgb(values: np.ndarray) -> dict[str, Any]:
    return {"type": "srgb", "color": [float(v) for v in values], "unbounded": True}


def bsdf_dict(material: Any, wavelengths_nm: np.ndarray) -> dict[str, Any]:
    """The built-in Mitsuba BSDF (plugin dict) equal to `material` at the three wavelengths."""
    check_representable(material)
    kd, ks = material_rgb(material, wavelengths_nm)
    return {"type": "twosided",
            "bsdf": {"type": "blendbsdf", "weight": 0.5,
                     "a": {"type": "diffuse", "reflectance": _srgb(2.0 * kd)},
                     "b": {"type": "roughconductor", "distribution": "ggx",
                           "alpha": float(material.alpha), "eta": float(material.eta), "k": 0.0,
                           "specular_reflectance": _srgb(2.0 * ks)}}}


def lamp_rgb(lamp: Any, wavelengths_nm: np.ndarray) -> np.ndarray:
    """Mean panel radiance at the (3,) wavelengths, linear on `render.LAMP_GRID_NM` (as the
    stock renderer's panel texture)."""
    from normbox_lab.predict.render import LAMP_GRID_NM

    return np.interp(np.asarray(wavelengths_nm, dtype=np.float64), LAMP_GRID_NM,
                     lamp.radiance(LAMP_GRID_NM))


# --- the scene ----------------------------------------------------------------------------------
_ROLES = ("patch", "wall", "holder", "post")


class _TripletScene:
    """The Normbox radiometer view in an RGB variant: loaded once, then every triplet only sets
    the BSDF colours and the 25 panel cells' radiance in place (opaque values: the render kernel
    is compiled once)."""

    def __init__(self, geometry: Any, angle_deg: float, materials: dict[str, Any],
                 pixels: int, max_depth: int) -> None:
        import mitsuba as mi

        from normbox_lab.predict.scene import as_geometry, panel_map, scene_dict

        g = as_geometry(geometry)
        wl0 = np.full(3, 550.0)
        self.bsdfs = {role: mi.load_dict(bsdf_dict(materials[role], wl0)) for role in _ROLES}
        film = {"type": "hdrfilm", "width": int(pixels), "height": int(pixels),
                "pixel_format": "rgb", "component_format": "float32", "rfilter": {"type": "box"}}
        # one emitting panel with a 5×5 RGB bitmap (lamp × map, nearest filter): with 25
        # emitting cells, emitter sampling followed the order in which Mitsuba loaded them,
        # which changes from load to load, so a seed did not repeat its numbers
        self.cell_map = panel_map(g.panel_homogeneity_percent)
        d = scene_dict(g, angle_deg=float(angle_deg), patch_bsdf=self.bsdfs["patch"],
                       wall_bsdf=self.bsdfs["wall"], holder_bsdf=self.bsdfs["holder"],
                       post_bsdf=self.bsdfs["post"], lamp_values=np.ones(2),
                       lamp_grid_nm=np.array([360.0, 830.0]), film=film,
                       max_depth=max_depth,
                       panel_radiance={"type": "bitmap", "raw": True, "filter_type": "nearest",
                                       "wrap_mode": "clamp",
                                       "bitmap": mi.Bitmap(self._panel_rgb(np.ones(3)))})
        self.scene = mi.load_dict(d, parallel=False)
        self.params = mi.traverse(self.scene)
        self.bsdf_params = {role: mi.traverse(b) for role, b in self.bsdfs.items()}

    def _panel_rgb(self, lamp_values: np.ndarray) -> np.ndarray:
        """(5, 5, 3) float32 bitmap of the panel: the map's cell j along world y, i along x;
        on the downward-facing rectangle u runs along +x and v along −y (bitmap row 0 at v = 0),
        hence the rows reversed (as `mitsuba_bsdf.NormboxPanelTexture`)."""
        cells = np.asarray(self.cell_map, dtype=np.float64)[::-1]
        return np.ascontiguousarray(cells[:, :, None] * np.asarray(lamp_values)[None, None, :],
                                    dtype=np.float32)

    def set_triplet(self, materials: dict[str, Any], lamp: Any,
                    wavelengths_nm: np.ndarray) -> None:

        for role in _ROLES:
            kd, ks = material_rgb(materials[role], wavelengths_nm)
            p = self.bsdf_params[role]
            for key in p.keys():  # noqa: SIM118 (SceneParameters iterate as pairs)
                if key.endswith(".specular_reflectance.value"):      # the roughconductor
                    p[key] = _color(2.0 * ks)
                elif key.endswith(".reflectance.value"):             # the diffuse
                    p[key] = _color(2.0 * kd)
            p.update()
        import mitsuba as mi

        rgb = self._panel_rgb(lamp_rgb(lamp, wavelengths_nm))
        self.params["panel.emitter.radiance.data"] = mi.TensorXf(jit_table(mi.Float, rgb),
                                                                 shape=rgb.shape)
        self.params.update()


def _color(values: np.ndarray) -> Any:
    """A `mi.Color3f` from three numbers (the active variant's float type)."""
    import mitsuba as mi

    return mi.Color3f(*[float(v) for v in values])


def _mix_seed(seed: int, batch: int, triplet: int) -> int:
    """A 32-bit render seed per (seed, batch, triplet)."""
    return int((int(seed) * 1_000_003 + batch * 7919 + triplet * 104_729 + 17) % (2 ** 32))


def render_triplets(patch: Any, wall: Any, angle_deg: float, *, geometry: Any = None,
                    holder: Any = None, lamp: Any = None,
                    wavelengths_nm: Any = DEFAULT_WAVELENGTHS_NM,
                    band_width_nm: float = DEFAULT_BAND_WIDTH_NM, spp: int = 64,
                    batches: int = 16, seed: int = 0, max_depth: int = 12, pixels: int = 10,
                    antithetic: bool = True, variant: str | None = None) -> TripletResult:
    """Radiance the radiometer sees per band (mean over the pixels), by wavelength triplets.

    `wavelengths_nm`: band centres (padded to a multiple of 3 by repeating the last one);
    `band_width_nm`: half-width of the triangular band hat each batch jitters its wavelengths
    over (0: point wavelengths); `spp` per pixel per render; `batches` independent batches
    (≥ 2: the standard error is their spread); `max_depth` as Mitsuba's path integrator (12,
    as `render.render_view`; 2 = direct light only).  Materials must pass `check_representable`.
    """
    import mitsuba as mi

    from normbox_lab.predict.materials import holder_material
    from normbox_lab.predict.mitsuba_setup import in_variant, jit_variant
    from normbox_lab.predict.render import Lamp

    if int(batches) < 2:
        raise ValueError(f"batches must be ≥ 2 for a standard error, got {batches}")
    if float(band_width_nm) < 0:
        raise ValueError(f"band_width_nm must be ≥ 0, got {band_width_nm}")
    holder = holder if holder is not None else holder_material()
    lamp = lamp if lamp is not None else Lamp()
    materials = {"patch": patch, "wall": wall, "holder": holder, "post": holder}
    for m in materials.values():
        check_representable(m)
    centres = np.atleast_1d(np.asarray(wavelengths_nm, dtype=np.float64))
    n_bands = centres.size
    n_triplets = -(-n_bands // 3)
    padded = np.concatenate([centres, np.full(3 * n_triplets - n_bands, centres[-1])])
    variant = jit_variant("rgb", variant)
    rng = np.random.default_rng([int(seed), 0x7219])
    t0 = time.perf_counter()
    out = np.empty((int(batches), n_bands))
    renders = 0
    with in_variant(variant):
        ts = _TripletScene(geometry, angle_deg, materials, pixels, max_depth)
        for b in range(int(batches)):
            w = float(band_width_nm)
            delta = rng.triangular(-w, 0.0, w, size=padded.size) if w > 0 \
                else np.zeros(padded.size)
            # antithetic pair: +δ and −δ (the hat is symmetric, so both are hat-distributed)
            signs = (1.0, -1.0) if (antithetic and w > 0) else (1.0,)
            row = np.zeros(padded.size)
            for k, sign in enumerate(signs):
                lam = padded + sign * delta
                for t in range(n_triplets):
                    ts.set_triplet(materials, lamp, lam[3 * t:3 * t + 3])
                    img = mi.render(ts.scene, spp=int(spp),
                                    seed=_mix_seed(seed, b * len(signs) + k, t))
                    arr = require_finite(np.asarray(img, dtype=np.float64),  # (px, px, 3)
                                         f"wavelength triplets ({variant})")
                    row[3 * t:3 * t + 3] += arr.reshape(-1, 3).mean(axis=0) / len(signs)
                    renders += 1
            out[b] = row[:n_bands]
    dt = time.perf_counter() - t0
    mean = out.mean(axis=0)
    se = out.std(axis=0, ddof=1) / np.sqrt(out.shape[0])
    info = {"angle_deg": float(angle_deg), "patch": getattr(patch, "name", "?"),
            "wall": getattr(wall, "name", "?"), "batches": int(batches), "spp": int(spp),
            "pixels": int(pixels), "max_depth": int(max_depth), "seed": int(seed),
            "band_width_nm": float(band_width_nm), "triplets_per_batch": n_triplets,
            "antithetic": bool(antithetic)}
    return TripletResult(centres.copy(), mean, se, out, dt, variant,
                         renders=renders, spp=int(spp), info=info)
