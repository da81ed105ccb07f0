"""The virtual Normbox rendered by the band-vector renderer (`predict.fastrender.FastNormbox`).

`FastVirtualNormbox` is `sim.world.VirtualNormbox` with one change: `render()` goes through a
shared `FastNormbox` scene (seconds for a whole sweep) instead of Mitsuba's stock spectral path
tracer.  The demo's default world, the closure test's and the error budget's validation use it.

Random numbers: each configuration's render has its own seed, ``config_seed(render_seed,
"patch-N@ANGLE")``.  By default the world's seed base is `sim.world.TRUTH_RENDER_SEED` (+
the error sources' seed), a stream of its own: the truth's Monte-Carlo noise is independent of the
prediction's (which uses `PREDICTION_SEED`), as a measurement's noise is independent of a
rendering's.  Passing ``render_seed=PREDICTION_SEED`` makes the truth share the prediction's
random numbers (common random numbers): only for checks that want to isolate other effects,
such as `virtual_sweep`'s validation of the error budget's linearisation.

The truth's target relative standard error per band (largest band): the `render` error
source's value when it is on, else `target_rel_se`: given, else the lab config's ``[render]
truth_rel_se``, else the render quality's preset (`normbox_lab.predict.precision.PRESETS`,
`TRUTH_REL_SE` here by its old name).  The demo writes ``truth_rel_se``
into the lab config, so the error budget of a stored run knows the truth's render noise.

The truth's renders are kept in the lab config's ``[render] cache_dir`` when it names one (the
demo's does: ``demo-out/render-cache``), keyed by everything they depend on, the renderer's
source code included (`FastNormbox.render_view`): a second run of the same campaign reads the
same truth instead of tracing it again.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from normbox_lab.core.error_sources import ErrorSources
from normbox_lab.predict.fastrender import FastNormbox, config_seed
from normbox_lab.predict.precision import DEFAULT_TARGET_SE, PRESETS
from normbox_lab.predict.render import RenderResult
from normbox_lab.sim.world import ANGLE_RESOLUTION_DEG, VirtualNormbox

#: seed base of the prediction's per-configuration renders (`demo`, `pipeline.predict_run`)
PREDICTION_SEED = 1
#: the world's (truth's) target largest relative standard error per band, per render quality:
#: the presets of `normbox_lab.predict.precision` (defined there once)
TRUTH_REL_SE = PRESETS
#: first pass of the adaptive render (paths): the world's default, and a smaller one when the
#: `render` source sets a larger target (so the render does not overshoot it)
PILOT_PATHS = 1 << 14
RENDER_SOURCE_PILOT_PATHS = 1 << 11


class FastVirtualNormbox(VirtualNormbox):
    """The virtual Normbox with its truth rendered by `FastNormbox` (one shared scene)."""

    def __init__(self, config: Any = None, *, target_rel_se: float | None = None,
                 render_seed: int | None = None, fast: FastNormbox | None = None,
                 **kwargs: Any) -> None:
        super().__init__(config, **kwargs)
        render_cfg = dict(getattr(config, "render", None) or {})
        if target_rel_se is None:
            target_rel_se = render_cfg.get("truth_rel_se") or PRESETS.get(
                self.quality, DEFAULT_TARGET_SE)
        self.target_rel_se = float(target_rel_se)
        #: where the truth's renders are kept between runs (the lab config's ``[render]
        #: cache_dir``, as the stock renderer's; None: render every time)
        self.cache_dir = render_cfg.get("cache_dir") or None
        if render_seed is not None:
            self.render_seed = int(render_seed)
        self._fast = fast

    @property
    def fast(self) -> FastNormbox:
        """The scene of the truth geometry (built on first use)."""
        if self._fast is None:
            self._fast = FastNormbox(self.geometry)
        return self._fast

    @fast.setter
    def fast(self, box: FastNormbox) -> None:
        self._fast = box

    def render(self, patch: int | None, angle_deg: float, *, direct_only: bool = False,
               quality: str | None = None) -> RenderResult:
        """One configuration at full lamp output, with the world's own random numbers."""
        angle = round(float(angle_deg) / ANGLE_RESOLUTION_DEG) * ANGLE_RESOLUTION_DEG
        mat = self.patch_material(patch)
        target, pilot = self.target_rel_se, PILOT_PATHS
        if self.errors.render_rel_se:
            target, pilot = self.errors.render_rel_se, RENDER_SOURCE_PILOT_PATHS
        return self.fast.render_view(patch=mat, wall=self.wall, holder=self.holder,
                                     angle_deg=angle, lamp=self.lamp, target_rel_se=target,
                                     direct_only=direct_only,
                                     seed=config_seed(self.render_seed, f"{mat.name}@{angle:g}"),
                                     pilot_paths=pilot, cache_dir=self.cache_dir)


# --- the virtual sweep and its prediction, for the error budget's validation -------------------
def virtual_sweep(errors: ErrorSources | str, patches: Sequence[int], angles: Sequence[float],
                  *, truth: str = "model", target_rel_se: float = 0.02,
                  boxes: dict | None = None) -> np.ndarray:
    """The virtual Normbox's reference sweep (angle-major, the world's 1 nm spectra) with the
    given error sources.  The truth shares the prediction's random numbers (`PREDICTION_SEED`)
    unless the `render` source is on, so with every source off it equals `virtual_prediction`
    exactly and each source's effect is seen alone."""
    boxes = boxes if boxes is not None else {}
    world = FastVirtualNormbox(truth=truth, errors=errors, target_rel_se=target_rel_se)
    if not world.errors.render_rel_se:
        world.render_seed = PREDICTION_SEED
    key = repr(world.geometry)
    if key not in boxes:
        boxes[key] = FastNormbox(world.geometry)
    world.fast = boxes[key]
    out = np.zeros((len(patches), len(angles), world.wavelength_nm.size))
    for ai, a in enumerate(angles):
        world.set_sample_angle(float(a))
        for pi, p in enumerate(patches):
            world.place_patch(int(p))
            out[pi, ai] = world.radiance_in_view()[1]
    return out


def virtual_prediction(patches: Sequence[int], angles: Sequence[float], *,
                       truth: str = "model", target_rel_se: float = 0.02,
                       boxes: dict | None = None,
                       seed: int = PREDICTION_SEED) -> tuple[np.ndarray, np.ndarray]:
    """The prediction with the truth materials themselves (no fitting error), nominal
    geometry, the prediction's seeds (`seed` as their base): (radiance, std_error) on the
    world's 1 nm grid."""
    from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
    from normbox_lab.predict.materials import holder_material, truth_patch, truth_wall
    from normbox_lab.predict.render import Lamp
    from normbox_lab.predict.scene import as_geometry

    boxes = boxes if boxes is not None else {}
    g = as_geometry(None)
    if repr(g) not in boxes:
        boxes[repr(g)] = FastNormbox(g)
    box = boxes[repr(g)]
    wl = RADIOMETER_WAVELENGTHS_NM
    rad = np.zeros((len(patches), len(angles), wl.size))
    se = np.zeros_like(rad)
    wall = truth_wall(truth)
    for ai, a in enumerate(angles):
        for pi, p in enumerate(patches):
            m = truth_patch(int(p), truth)
            r = box.render_view(patch=m, wall=wall, holder=holder_material(),
                                angle_deg=float(a), lamp=Lamp(), target_rel_se=target_rel_se,
                                seed=config_seed(seed, f"{m.name}@{float(a):g}"))
            rad[pi, ai] = np.interp(wl, r.wavelength_nm, r.radiance)
            se[pi, ai] = np.interp(wl, r.wavelength_nm, r.std_error)
    return rad, se
