"""The Normbox fit model as a stand-alone Mitsuba 3 BSDF plugin ("normbox_fit").

This file is shipped as ``normbox_bsdf.py`` in every scene package (`normbox-lab scene export`)
and must stay self-contained: it imports only Mitsuba, Dr.Jit and the standard library, never
anything of normbox-lab, so that a package renders with stock Mitsuba alone.

    f(λ, ωi, ωo) = kd(λ)/π + ks(λ) · D(h; α) · F(ωi·h; η) · G1(ωi) · G1(ωo) / (4 cosθi cosθo) − c

in sr⁻¹: GGX (Trowbridge-Reitz) D(h) = α² / (π (cos²θh (α² − 1) + 1)²), Smith's separable
masking G1(ω) = 2 / (1 + √(1 + α² tan²θ)), the Cook & Torrance unpolarised dielectric Fresnel
F = ½ (g−b)²/(g+b)² · (1 + [b(g+b) − 1]² / [b(g−b) + 1]²) with g = √(η² − 1 + b²), b = ωi·h,
one real η and one constant c (sr⁻¹) for the whole spectrum, spectral kd and ks.  Two-sided.

Scene description (Mitsuba XML)::

    <bsdf type="normbox_fit" id="p19">
        <spectrum name="kd" value="360:0.85, 365:0.86, ..."/>
        <spectrum name="ks" value="360:0.48, ..."/>
        <float name="alpha" value="0.6"/> <float name="eta" value="1.5"/> <float name="c" value="0.001"/>
    </bsdf>

`kd` and `ks` are textures: spectra in spectral variants, and in RGB variants Mitsuba turns
them into RGB as a triplet renderer would (unbounded, so ks > 1 is kept).  Call `register()`
after `mitsuba.set_variant(...)`; the plugin works in every JIT variant (llvm_ad_*, cuda_ad_*)
and, slowly, in the scalar ones.  Sampling: cosine hemisphere with probability `p_diffuse`,
GGX visible normals otherwise, weighted by their mixture pdf.
"""

from __future__ import annotations

from typing import Any

PLUGIN_NAME = "normbox_fit"


def _scalar(value: Any) -> float:
    """A Python float from a Mitsuba scalar or a one-element JIT array."""
    try:
        return float(value)
    except TypeError:
        return float(value[0])


def _ggx_fresnel_lobes(dr: Any, mi: Any, alpha: Any, wi: Any, wo: Any, active: Any,
                       eta: Any) -> tuple[Any, Any, Any]:
    """(valid, F, D·G1·G1 / (4 cosθi cosθo)) for local directions, wi.z > 0: GGX D, Smith's
    separable G1, Cook-Torrance's unpolarised Fresnel with η."""
    cos_i = mi.Frame3f.cos_theta(wi)
    cos_o = mi.Frame3f.cos_theta(wo)
    valid = active & (cos_i > 0) & (cos_o > 0)
    h = dr.normalize(wi + wo)
    cos_h = mi.Frame3f.cos_theta(h)
    a2 = alpha * alpha
    c2 = cos_h * cos_h
    d = a2 / (dr.pi * dr.square(c2 * (a2 - 1.0) + 1.0))
    d = dr.select(cos_h > 0, d, 0.0)

    def g1(cos_t: Any) -> Any:
        cc = dr.clip(cos_t * cos_t, 1e-30, 1.0)
        return 2.0 / (1.0 + dr.sqrt(1.0 + a2 * (1.0 - cc) / cc))

    geo = d * g1(cos_i) * g1(cos_o) / (4.0 * dr.select(valid, cos_i * cos_o, 1.0))
    geo = dr.select(valid, geo, 0.0)
    b = dr.clip(dr.dot(wi, h), 0.0, 1.0)
    g = dr.sqrt(dr.fmax(eta * eta - 1.0 + b * b, 0.0))
    fa = (g - b) / (g + b)
    fb = (b * (g + b) - 1.0) / (b * (g - b) + 1.0)
    return valid, 0.5 * fa * fa * (1.0 + fb * fb), geo


def _mixture_pdf(dr: Any, mi: Any, alpha: Any, p_diffuse: Any, wi: Any, wo: Any,
                 active: Any) -> Any:
    """The pdf of the two-lobe sampling: cosine hemisphere with probability `p_diffuse`, GGX
    visible normals otherwise."""
    cos_o = mi.Frame3f.cos_theta(wo)
    pdf_d = mi.warp.square_to_cosine_hemisphere_pdf(wo)
    distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, alpha, True)
    m = dr.normalize(wi + wo)
    dwh = dr.dot(wo, m)
    pdf_s = distr.pdf(wi, m) / (4.0 * dr.abs(dwh))
    pdf_s = dr.select(dwh > 0, pdf_s, 0.0)
    pdf = p_diffuse * pdf_d + (1.0 - p_diffuse) * pdf_s
    return dr.select(active & (cos_o > 0), pdf, 0.0)


def two_lobe_base() -> type:
    """What every BSDF of the model shares, however it stores kd and ks: the GGX geometry and
    Cook-Torrance Fresnel (`_lobes`), the two-lobe sampling (cosine hemisphere with probability
    `p_diffuse`, GGX visible normals otherwise, their mixture pdf) and Mitsuba's BSDF interface.
    A BSDF derives from it (it is an `mi.BSDF`), sets `alpha` and `p_diffuse` and defines `_f`.
    (normbox-lab's own `predict.mitsuba_bsdf` derives from it too: one copy of the maths.)"""
    import drjit as dr
    import mitsuba as mi

    class TwoLobes(mi.BSDF):
        alpha: Any
        p_diffuse: Any

        def _f(self, si: Any, wi: Any, wo: Any, active: Any) -> Any:
            raise NotImplementedError

        def _two_sided_lobes(self) -> None:
            """Mitsuba's components: a diffuse and a glossy reflection, both sides."""
            diffuse = (mi.BSDFFlags.DiffuseReflection | mi.BSDFFlags.FrontSide
                       | mi.BSDFFlags.BackSide)
            glossy = (mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
                      | mi.BSDFFlags.BackSide)
            self.m_components = [diffuse, glossy]
            self.m_flags = diffuse | glossy

        def _lobes(self, wi: Any, wo: Any, active: Any, eta: Any) -> tuple[Any, Any, Any]:
            """(valid, F, D·G1·G1 / (4 cosθi cosθo)) for local directions, wi.z > 0."""
            return _ggx_fresnel_lobes(dr, mi, self.alpha, wi, wo, active, eta)

        def _pdf(self, wi: Any, wo: Any, active: Any) -> Any:
            return _mixture_pdf(dr, mi, self.alpha, self.p_diffuse, wi, wo, active)

        @staticmethod
        def _to_front(si: Any) -> tuple[Any, Any]:
            flip = mi.Frame3f.cos_theta(si.wi) < 0
            return mi.Vector3f(si.wi.x, si.wi.y, dr.abs(si.wi.z)), flip

        def sample(self, ctx: Any, si: Any, sample1: Any, sample2: Any, active: Any = True):
            wi, flip = self._to_front(si)
            use_d = sample1 < self.p_diffuse
            wo_d = mi.warp.square_to_cosine_hemisphere(sample2)
            distr = mi.MicrofacetDistribution(mi.MicrofacetType.GGX, self.alpha, True)
            m, _ = distr.sample(wi, sample2)
            wo = dr.select(use_d, wo_d, mi.reflect(wi, m))
            pdf = self._pdf(wi, wo, active)
            ok = active & (pdf > 0) & (mi.Frame3f.cos_theta(wo) > 0)
            f = self._f(si, wi, wo, ok)
            value = f * mi.Frame3f.cos_theta(wo) / dr.select(ok, pdf, 1.0)
            bs = dr.zeros(mi.BSDFSample3f)
            bs.wo = mi.Vector3f(wo.x, wo.y, dr.select(flip, -wo.z, wo.z))
            bs.pdf = dr.select(ok, pdf, 0.0)
            bs.eta = 1.0
            bs.sampled_type = dr.select(use_d, mi.UInt32(+mi.BSDFFlags.DiffuseReflection),
                                        mi.UInt32(+mi.BSDFFlags.GlossyReflection))
            bs.sampled_component = dr.select(use_d, mi.UInt32(0), mi.UInt32(1))
            return bs, dr.select(ok, value, 0.0)

        def eval(self, ctx: Any, si: Any, wo: Any, active: Any = True):
            wi, flip = self._to_front(si)
            wo_l = mi.Vector3f(wo.x, wo.y, dr.select(flip, -wo.z, wo.z))
            f = self._f(si, wi, wo_l, active)
            return dr.select(active, f * dr.fmax(mi.Frame3f.cos_theta(wo_l), 0.0), 0.0)

        def pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True):
            wi, flip = self._to_front(si)
            wo_l = mi.Vector3f(wo.x, wo.y, dr.select(flip, -wo.z, wo.z))
            return self._pdf(wi, wo_l, active)

        def eval_pdf(self, ctx: Any, si: Any, wo: Any, active: Any = True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def traverse(self, callback: Any) -> None:
            pass

        def parameters_changed(self, keys: Any) -> None:
            pass

    return TwoLobes


def register() -> Any:
    """Register the plugin for the current Mitsuba variant; returns the class."""
    import drjit as dr
    import mitsuba as mi

    class NormboxFitBSDF(two_lobe_base()):
        def __init__(self, props: Any) -> None:
            mi.BSDF.__init__(self, props)
            self.kd = props.get_unbounded_texture("kd")
            self.ks = props.get_unbounded_texture("ks")
            self.alpha_value = float(props.get("alpha", 0.5))
            self.eta_value = float(props.get("eta", 1.5))
            self.c_value = float(props.get("c", 0.0))
            jit = dr.is_jit_v(mi.Float)
            self.alpha = dr.opaque(mi.Float, self.alpha_value) if jit else self.alpha_value
            self.eta = dr.opaque(mi.Float, self.eta_value) if jit else self.eta_value
            self.c = dr.opaque(mi.Float, self.c_value) if jit else self.c_value
            ks_mean = _scalar(self.ks.mean())
            kd_mean = _scalar(self.kd.mean())
            p_glossy = 0.0 if ks_mean <= 0 else min(
                0.5, max(0.15, 0.25 / max(self.alpha_value, 0.1) * ks_mean
                         / (ks_mean + max(kd_mean, 0.0))))
            self.p_diffuse = 1.0 - p_glossy
            self._two_sided_lobes()

        def _f(self, si: Any, wi: Any, wo: Any, active: Any) -> Any:
            """f (sr⁻¹) for local directions, wi.z > 0 (no cosine)."""
            valid, fres, geo = self._lobes(wi, wo, active, self.eta)
            kd = self.kd.eval(si, active)
            ks = self.ks.eval(si, active)
            f = kd * dr.inv_pi + ks * (fres * geo) - self.c
            return dr.select(valid, f, 0.0)

        def to_string(self) -> str:
            return (f"NormboxFitBSDF[alpha={self.alpha_value}, eta={self.eta_value}, "
                    f"c={self.c_value}]")

    mi.register_bsdf(PLUGIN_NAME, lambda props: NormboxFitBSDF(props))
    return NormboxFitBSDF
