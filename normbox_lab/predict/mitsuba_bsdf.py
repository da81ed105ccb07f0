"""The Normbox BRDF family as a Mitsuba 3 BSDF (a Python `mi.BSDF`, registered as "normbox").

Same formula as `normbox_lab.predict.materials.truth_brdf` (and, with the extras off, as the fit model
`normbox_lab.predict.brdf_model.ct_ggx_brdf`):

    f = kd(λ)/π + ks(λ)·D·F(η(λ))·G1(ωi)G1(ωo)/(4 cosθi cosθo) − c + kb(λ)·exp((ωi·ωo−1)/σ²)/π

Spectra are resampled onto a fixed 5 nm grid (360–830 nm) and interpolated linearly at the
path's wavelengths with `dr.gather`; every parameter is an opaque Dr.Jit value, so changing the
material (`set_material`) does not recompile the render kernel.  The BSDF is two-sided (a
surface seen from behind reflects like its front).  Sampling: cosine hemisphere with probability
`p_diffuse`, GGX visible normals otherwise, combined by their mixture pdf.

Mitsuba is imported lazily: call `bsdf_class()` after `mi.set_variant(...)`.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from normbox_lab.predict.kernel_safety import cell_index, jit_table

GRID_MIN_NM = 360.0
GRID_STEP_NM = 5.0
GRID_NM = np.arange(GRID_MIN_NM, 830.0 + 0.5, GRID_STEP_NM)

_CLASSES: dict[str, Any] = {}


def glossy_share(kd: np.ndarray, ks: np.ndarray, alpha: float) -> float:
    """The lobe choice: the share of glossy samples, more for smooth materials with real ks
    (0 without ks, else 0.15–0.5)."""
    ks_mean = float(np.mean(ks))
    kd_mean = float(np.mean(kd))
    return 0.0 if ks_mean <= 0 else min(0.5, max(0.15, 0.25 / max(alpha, 0.1)
                                                 * ks_mean / (ks_mean + kd_mean)))


def _gather_spectrum(dr: Any, mi: Any, jit: bool, values: Any, wavelengths: Any,
                     active: Any) -> Any:
    """The spectrum on `GRID_NM` interpolated linearly at the path's wavelengths."""
    if not jit:          # scalar variants: one path at a time, plain numpy
        return mi.UnpolarizedSpectrum(*[float(np.interp(float(w), GRID_NM, values))
                                        for w in wavelengths])
    n = len(GRID_NM)
    out = []
    for k in range(len(wavelengths)):
        t = dr.clip((wavelengths[k] - GRID_MIN_NM) / GRID_STEP_NM, 0.0, n - 1.0)
        i0 = cell_index(dr, mi, t, n - 1.0, active)
        w = dr.select(dr.isfinite(t), t - mi.Float(i0), 0.0)
        v0 = dr.gather(mi.Float, values, i0, active)
        v1 = dr.gather(mi.Float, values, i0 + 1, active)
        out.append(dr.fma(w, v1 - v0, v0))
    return mi.UnpolarizedSpectrum(*out)


def bsdf_class() -> Any:
    """The `NormboxBSDF` class for the current Mitsuba variant (registered as "normbox")."""
    import drjit as dr
    import mitsuba as mi

    variant = mi.variant()
    if variant in _CLASSES:
        return _CLASSES[variant]

    jit = dr.is_jit_v(mi.Float)

    def array(values: Any) -> Any:
        return jit_table(mi.Float, values) if jit \
            else np.asarray(values, dtype=np.float64)

    def opaque(value: float) -> Any:
        return dr.opaque(mi.Float, float(value)) if jit else float(value)

    def gather_spectrum(values: Any, wavelengths: Any, active: Any) -> Any:
        return _gather_spectrum(dr, mi, jit, values, wavelengths, active)

    from normbox_lab.predict.standalone_bsdf import two_lobe_base

    class NormboxBSDF(two_lobe_base()):
        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            self._two_sided_lobes()
            self.p_diffuse = 0.5
            flat = np.full(GRID_NM.shape, 0.5)
            self.set_values(kd=flat, ks=np.zeros_like(flat), kb=np.zeros_like(flat),
                            alpha=0.5, eta=1.5, c=0.0, deta_per_100nm=0.0, sigma=0.3)

        # -- parameters --------------------------------------------------------------------
        def set_values(self, *, kd: np.ndarray, ks: np.ndarray, kb: np.ndarray, alpha: float,
                       eta: float, c: float, deta_per_100nm: float, sigma: float) -> None:
            self.kd = array(kd)
            self.ks = array(ks)
            self.kb = array(kb)
            self.alpha = opaque(alpha)
            self.eta = opaque(eta)
            self.c = opaque(c)
            self.deta = opaque(float(deta_per_100nm) / 100.0)
            self.inv_sigma2 = opaque(1.0 / float(sigma) ** 2)
            self.p_diffuse = opaque(1.0 - glossy_share(kd, ks, alpha))

        def set_material(self, material: Any) -> None:
            """From a `normbox_lab.predict.materials.Material`."""
            kd, ks, kb = material.spectra_at(GRID_NM)
            self.set_values(kd=kd, ks=ks, kb=kb, alpha=material.alpha, eta=material.eta,
                            c=material.c, deta_per_100nm=material.deta_per_100nm,
                            sigma=material.backscatter_sigma)

        # -- the model ---------------------------------------------------------------------
        def _f(self, si: Any, wi: Any, wo: Any, active: Any) -> Any:
            """f (sr⁻¹) for local directions with wi.z > 0 (no cosine): the shared GGX and
            Fresnel lobes with η(λ), spectral kd, ks, and the backscatter lobe."""
            wl = si.wavelengths
            eta = self.eta + self.deta * (wl - 550.0)
            valid, fres, geo = self._lobes(wi, wo, active, eta)
            kd = gather_spectrum(self.kd, wl, active)
            ks = gather_spectrum(self.ks, wl, active)
            kb = gather_spectrum(self.kb, wl, active)
            back = kb * (dr.exp((dr.dot(wi, wo) - 1.0) * self.inv_sigma2) * dr.inv_pi)
            f = kd * dr.inv_pi + ks * fres * geo + back - self.c
            return dr.select(valid, f, 0.0)

        def to_string(self) -> str:
            return "NormboxBSDF[]"

    mi.register_bsdf("normbox", lambda props: NormboxBSDF(props))
    _CLASSES[variant] = NormboxBSDF
    return NormboxBSDF


def make_bsdf(material: Any) -> Any:
    """A `NormboxBSDF` instance carrying `material` (current Mitsuba variant)."""
    import mitsuba as mi

    cls = bsdf_class()
    bsdf = cls(mi.Properties("normbox"))
    bsdf.set_material(material)
    return bsdf


# --- the opal panel's emission: one emitter, lamp spectrum × 5×5 map ---------------------------
_TEXTURES: dict[str, Any] = {}


def panel_texture_class() -> Any:
    """`NormboxPanelTexture` for the current variant (registered as "normbox_panel"): radiance
    L(λ, u, v) = lamp(λ) · map[j, i] on a rectangle's (u, v), piecewise constant over the 5×5
    cells.  One emitter instead of 25 keeps emitter sampling independent of the order in which
    Mitsuba happens to load the scene's objects (so renders repeat across processes)."""
    import drjit as dr
    import mitsuba as mi

    variant = mi.variant()
    if variant in _TEXTURES:
        return _TEXTURES[variant]
    jit = dr.is_jit_v(mi.Float)

    class NormboxPanelTexture(mi.Texture):
        def __init__(self, props: Any) -> None:
            mi.Texture.__init__(self, props)
            self.set_values(np.arange(360.0, 831.0, 5.0), np.ones(95), np.ones((5, 5)))

        def set_values(self, grid_nm: np.ndarray, values: np.ndarray,
                       cell_map: np.ndarray) -> None:
            """`values` (W·sr⁻¹·m⁻²·nm⁻¹) on the evenly spaced `grid_nm`; `cell_map[j, i]` the
            factor of the cell j along world y, i along world x (`scene.panel_map`): on the
            downward-facing rectangle u runs along +x and v along −y, so i = ⌊5u⌋, j = 4 − ⌊5v⌋."""
            self.grid_min = float(grid_nm[0])
            self.grid_step = float(grid_nm[1] - grid_nm[0])
            self.n = len(grid_nm)
            self.mean_value = float(np.mean(values) * np.mean(cell_map))
            flat = np.asarray(cell_map, dtype=np.float64).ravel()
            if jit:
                self.values = jit_table(mi.Float, values)
                self.map = jit_table(mi.Float, flat)
            else:
                self.values = np.asarray(values, dtype=np.float64)
                self.map = flat
                self.grid = np.asarray(grid_nm, dtype=np.float64)

        def _factor(self, si: Any, active: Any) -> Any:
            col = dr.clip(dr.floor(si.uv.x * 5.0), 0.0, 4.0)
            row = 4.0 - dr.clip(dr.floor(si.uv.y * 5.0), 0.0, 4.0)
            if not jit:
                return float(self.map[int(row) * 5 + int(col)])
            return dr.gather(mi.Float, self.map, cell_index(dr, mi, row * 5.0 + col, 25.0,
                                                            active), active)

        def _spectrum(self, wavelengths: Any, active: Any) -> Any:
            out = []
            for k in range(len(wavelengths)):
                if not jit:
                    out.append(float(np.interp(float(wavelengths[k]), self.grid, self.values)))
                    continue
                t = dr.clip((wavelengths[k] - self.grid_min) / self.grid_step, 0.0,
                            self.n - 1.0)
                i0 = cell_index(dr, mi, t, self.n - 1.0, active)
                w = dr.select(dr.isfinite(t), t - mi.Float(i0), 0.0)
                v0 = dr.gather(mi.Float, self.values, i0, active)
                v1 = dr.gather(mi.Float, self.values, i0 + 1, active)
                out.append(dr.fma(w, v1 - v0, v0))
            return mi.UnpolarizedSpectrum(*out)

        def eval(self, si: Any, active: Any = True) -> Any:
            return self._spectrum(si.wavelengths, active) * self._factor(si, active)

        def mean(self) -> float:
            return self.mean_value

        def is_spatially_varying(self) -> bool:
            return True

        def traverse(self, callback: Any) -> None:
            pass

        def to_string(self) -> str:
            return "NormboxPanelTexture[]"

    mi.register_texture("normbox_panel", lambda props: NormboxPanelTexture(props))
    _TEXTURES[variant] = NormboxPanelTexture
    return NormboxPanelTexture


def make_panel_texture(grid_nm: np.ndarray, values: np.ndarray, cell_map: np.ndarray) -> Any:
    import mitsuba as mi

    tex = panel_texture_class()(mi.Properties("normbox_panel"))
    tex.set_values(grid_nm, values, cell_map)
    return tex
