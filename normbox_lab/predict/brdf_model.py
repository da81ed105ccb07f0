"""The fit model: Cook-Torrance with GGX, Smith G1 and the Cook-Torrance Fresnel (paper Eqs. 1-6).

    f(λ, ωi, ωo) = kd(λ)/π + ks(λ) · D(h; α) · F(ωi·h; η) · G1(ωi) · G1(ωo) / (4 cosθi cosθo) − c

in sr⁻¹, with one roughness α, one global refractive index η and one constant c for the whole
spectrum, and spectral diffuse / specular albedos kd(λ), ks(λ).  Everything is vectorised numpy.

Geometry convention (used by the gonioreflectometer data, the fit and the virtual Normbox):
- z is the surface normal; the measurement plane is the x-z plane.
- θi and θo are *signed* polar angles of the direction vectors ωi (towards the light) and ωo
  (towards the detector), both measured from the normal in the same sense (positive towards +x).
  So θo = θi would be retro-reflection (the light's own direction, blocked in a real gonio
  without the tilt) and **the specular (mirror) direction of θi is θo = −θi**; e.g. the light at
  θi = −30° has its specular peak at θo = +30°.  The gonio set is θi = −80…0 step 10 and
  θo = −80…80 step 10 (9 × 17 = 153 geometries).
- The light arm is tilted +tilt out of the plane, the detector arm −tilt (default 4°, as in the
  paper): each direction keeps a constant elevation of `tilt` above/below the x-z plane,
  ω = (sinθ·cos t, ±sin t, cosθ·cos t).  The retro geometry θo = θi therefore measures at an
  8° separation between light and detector, which is what lets the device see backscatter.

The Fresnel term is Cook & Torrance's unpolarised dielectric form
    F = ½ (g−c)²/(g+c)² · (1 + [c(g+c) − 1]² / [c(g−c) + 1]²),  g = √(η² − 1 + c²),  c = ωi·h.
(The Normbox paper's Eq. 5 prints √(η − 1 + c²) and c(g+1); both are typos of the original
Cook-Torrance formula, which is the one whose normal-incidence value is ((η−1)/(η+1))².)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

#: The paper's gonioreflectometer geometry set.
GONIO_THETA_I_DEG = np.arange(-80.0, 1.0, 10.0)     # 9 incident angles
GONIO_THETA_O_DEG = np.arange(-80.0, 81.0, 10.0)    # 17 outgoing angles
GONIO_TILT_DEG = 4.0


def gonio_geometry(tilt_deg: float = GONIO_TILT_DEG) -> tuple[np.ndarray, np.ndarray]:
    """The 153 (θi, θo) pairs of the in-plane gonio set, flattened (θi-major), in degrees."""
    ti, to = np.meshgrid(GONIO_THETA_I_DEG, GONIO_THETA_O_DEG, indexing="ij")
    return ti.ravel(), to.ravel()


def inplane_directions(theta_i_deg: Any, theta_o_deg: Any,
                       tilt_deg: float = GONIO_TILT_DEG) -> tuple[np.ndarray, np.ndarray]:
    """Unit vectors (…, 3) for signed in-plane angles; light arm +tilt, detector arm −tilt."""
    ti = np.deg2rad(np.asarray(theta_i_deg, dtype=np.float64))
    to = np.deg2rad(np.asarray(theta_o_deg, dtype=np.float64))
    ti, to = np.broadcast_arrays(ti, to)
    t = np.deg2rad(float(tilt_deg))
    ct, st = np.cos(t), np.sin(t)
    wi = np.stack([np.sin(ti) * ct, np.full_like(ti, st), np.cos(ti) * ct], axis=-1)
    wo = np.stack([np.sin(to) * ct, np.full_like(to, -st), np.cos(to) * ct], axis=-1)
    return wi, wo


def ggx_d(cos_theta_h: Any, alpha: float) -> np.ndarray:
    """GGX normal distribution D(h) = α² / (π cos⁴θh (α² + tan²θh)²); 0 below the horizon."""
    c = np.asarray(cos_theta_h, dtype=np.float64)
    a2 = float(alpha) ** 2
    c2 = c * c
    denom = np.pi * (c2 * (a2 - 1.0) + 1.0) ** 2
    return np.where(c > 0.0, a2 / np.maximum(denom, 1e-300), 0.0)


def smith_g1(cos_theta: Any, alpha: float) -> np.ndarray:
    """Smith's monodirectional masking for GGX, 2 / (1 + √(1 + α² tan²θ)); 0 below the horizon."""
    c = np.asarray(cos_theta, dtype=np.float64)
    c2 = np.clip(c * c, 1e-300, 1.0)
    tan2 = (1.0 - c2) / c2
    return np.where(c > 0.0, 2.0 / (1.0 + np.sqrt(1.0 + float(alpha) ** 2 * tan2)), 0.0)


def fresnel_cook_torrance(cos_beta: Any, eta: float) -> np.ndarray:
    """Unpolarised dielectric Fresnel reflectance (Cook & Torrance 1982) for relative index η."""
    c = np.clip(np.asarray(cos_beta, dtype=np.float64), 0.0, 1.0)
    g = np.sqrt(float(eta) ** 2 - 1.0 + c * c)
    a = (g - c) / (g + c)
    b = (c * (g + c) - 1.0) / (c * (g - c) + 1.0)
    return 0.5 * a * a * (1.0 + b * b)


def specular_basis(wi: np.ndarray, wo: np.ndarray, alpha: float, eta: float) -> np.ndarray:
    """D·F·G1·G1 / (4 cosθi cosθo) per geometry (…,): the factor that multiplies ks(λ)."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    h = wi + wo
    h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
    cos_i = wi[..., 2]
    cos_o = wo[..., 2]
    cos_h = h[..., 2]
    cos_d = np.sum(wi * h, axis=-1)
    valid = (cos_i > 0.0) & (cos_o > 0.0)
    num = (ggx_d(cos_h, alpha) * fresnel_cook_torrance(cos_d, eta)
           * smith_g1(cos_i, alpha) * smith_g1(cos_o, alpha))
    den = 4.0 * np.where(valid, cos_i * cos_o, 1.0)
    return np.where(valid, num / den, 0.0)


def ct_ggx_brdf(wi: np.ndarray, wo: np.ndarray, kd: Any, ks: Any, alpha: float, eta: float,
                c: float) -> np.ndarray:
    """The fit model in sr⁻¹, shape (…, n_wavelengths) for directions (…, 3) and kd, ks (n_λ,)."""
    kd = np.atleast_1d(np.asarray(kd, dtype=np.float64))
    ks = np.atleast_1d(np.asarray(ks, dtype=np.float64))
    spec = specular_basis(wi, wo, alpha, eta)[..., None]
    return kd / np.pi + ks * spec - float(c)


@dataclass
class GgxParameters:
    """The fit model's parameters of one material: spectra kd, ks on `wavelength_nm`, GGX
    roughness α, the global Fresnel η, the constant c (sr⁻¹).  The fitted `MaterialFit` and
    the rendered `materials.Material` (which adds the truth's extras) both extend it."""

    name: str
    wavelength_nm: np.ndarray
    kd: np.ndarray
    ks: np.ndarray
    alpha: float
    eta: float
    c: float


class ArtifactSink(Protocol):
    """Where a fit is written: the one call of the measurement store
    (`normbox_lab.acquire.store_api.Store`) a fit makes.  The prediction's floor stands below
    the store's and names no store type of its own; any `Store` is an `ArtifactSink`."""

    def add_artifact(self, kind: str, name: str, arrays: Mapping[str, Any] | None = None, *,
                     metadata: Mapping[str, Any] | None = None,
                     run_ref: int | str | None = None) -> int: ...


@dataclass
class MaterialFit(GgxParameters):
    """One material's fitted model parameters (store artifact kind "fit", name = material)."""

    fit_error_pct: float          # relative RMS error of the fit over all valid samples, in %
    w: float                      # cos^w θi weighting exponent used in the cost
    cost: float = float("nan")    # final Löw log cost E (paper Eq. 9)
    tilt_deg: float = GONIO_TILT_DEG
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.wavelength_nm = np.asarray(self.wavelength_nm, dtype=np.float64)
        self.kd = np.asarray(self.kd, dtype=np.float64)
        self.ks = np.asarray(self.ks, dtype=np.float64)

    def brdf(self, wi: np.ndarray, wo: np.ndarray) -> np.ndarray:
        """Evaluate the fitted model, (…, n_λ) sr⁻¹."""
        return ct_ggx_brdf(wi, wo, self.kd, self.ks, self.alpha, self.eta, self.c)

    def brdf_inplane(self, theta_i_deg: Any, theta_o_deg: Any) -> np.ndarray:
        wi, wo = inplane_directions(theta_i_deg, theta_o_deg, self.tilt_deg)
        return self.brdf(wi, wo)

    def to_arrays(self) -> dict[str, np.ndarray]:
        return {"wavelength_nm": self.wavelength_nm, "kd": self.kd, "ks": self.ks}

    def to_metadata(self) -> dict[str, Any]:
        return {"model": "cook-torrance-ggx-smith-ctfresnel-minus-c",
                "alpha": float(self.alpha), "eta": float(self.eta), "c_per_sr": float(self.c),
                "fit_error_pct": float(self.fit_error_pct), "w": float(self.w),
                "cost": float(self.cost), "tilt_deg": float(self.tilt_deg),
                **dict(self.metadata)}

    def store(self, store: ArtifactSink, run_ref: int | str | None = None) -> int:
        """Write as an artifact: `store.add_artifact(kind="fit", name=self.name, ...)`."""
        return store.add_artifact(kind="fit", name=self.name, arrays=self.to_arrays(),
                                  metadata=self.to_metadata(), run_ref=run_ref)

    @classmethod
    def from_artifact(cls, artifact: Any) -> MaterialFit:
        """From a store `Artifact` (or anything with .name, .arrays, .metadata)."""
        md: Mapping[str, Any] = dict(artifact.metadata)
        known = {"model", "alpha", "eta", "c_per_sr", "fit_error_pct", "w", "cost", "tilt_deg"}
        return cls(name=artifact.name,
                   wavelength_nm=artifact.arrays["wavelength_nm"],
                   kd=artifact.arrays["kd"], ks=artifact.arrays["ks"],
                   alpha=float(md["alpha"]), eta=float(md["eta"]), c=float(md["c_per_sr"]),
                   fit_error_pct=float(md["fit_error_pct"]), w=float(md["w"]),
                   cost=float(md.get("cost", float("nan"))),
                   tilt_deg=float(md.get("tilt_deg", GONIO_TILT_DEG)),
                   metadata={k: v for k, v in md.items() if k not in known})
