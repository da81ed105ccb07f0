"""The Normbox as a Mitsuba 3 scene: one builder for the virtual world and the prediction.

Coordinates (metres; the config is in mm):
- x: horizontal, along the sample's rotation axis (parallel to the open side);
  y: depth, the open side at y = −L/2, the back wall at y = +L/2; z: up, floor z = 0,
  ceiling (inner surface) z = L, with L = `box_inner_mm` (600 mm).
- Ceiling aperture `aperture_x_mm` × `aperture_y_mm` (220 × 200) centred in the ceiling; its
  four side faces are `ceiling_thickness_mm` (19 mm) high; the sphere's opal panel closes it at
  z = L + ceiling thickness and emits downwards, modulated by the 5×5 homogeneity map (one
  emitter with a lamp × map texture, or 25 emitting cells).  The walls are modelled by their inner faces (painted grey); the 15 mm wall
  thickness only fixes the outer rim of the open side, which no light inside the box reaches the
  radiometer through, so it is not modelled.  Outside the box the lab is dark.
- The sample holder (black) stands in the middle: a post from the floor and a plate of
  `holder_size_mm` behind the patch.  The patch (`patch_size_mm` square) is centred at
  (0, 0, `sample_height_mm`) and rotated about the x axis by the sample angle s: its normal is
  n(s) = (0, −sin s, cos s), so s = 0° faces the ceiling (the light), s = 90° the radiometer.
- The radiometer sits on the open side at (0, −`radiometer_distance_mm`, sample height) looking
  along +y at the sample centre: a perspective sensor with a `radiometer_view_deg` (1°) square
  field of view, 10 × 10 px, every pixel a full spectrum (`specfilm`), averaged.  At s the
  radiometer sees the sample at 90° − s from its normal (paper: 60…0° for s = 30…90°).

`NormboxGeometry` (`normbox_lab.core.geometry`, also the lab config's `[geometry]`); every function here
accepts any object with those attribute names.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from normbox_lab.core.geometry import GEOMETRY_FIELDS, NormboxGeometry

#: a 5×5 map of the opal panel's relative radiance (rows: y from −, columns: x from −), the
#: pattern of an integrating-sphere port: brightest near the centre, darker corners; `panel_map`
#: removes its mean and scales it so that the mean is exactly 1 and the largest deviation is
#: exactly the homogeneity (3 %).
_MAP_PATTERN = np.array([[-1.00, -0.55, -0.30, -0.45, -0.85],
                         [-0.50, 0.15, 0.45, 0.25, -0.35],
                         [-0.25, 0.50, 1.00, 0.60, -0.10],
                         [-0.55, 0.10, 0.40, 0.20, -0.40],
                         [-0.95, -0.60, -0.25, -0.40, -0.80]])




def as_geometry(obj: Any = None) -> NormboxGeometry:
    """A `NormboxGeometry` from any object with (some of) its attribute names; None: defaults."""
    if obj is None:
        return NormboxGeometry()
    if isinstance(obj, NormboxGeometry):
        return obj
    geo = getattr(obj, "geometry", None)       # a LabConfig
    if geo is not None and not isinstance(obj, (int, float)):
        obj = geo
    base = NormboxGeometry()
    return NormboxGeometry(**{f: float(getattr(obj, f, getattr(base, f))) for f in GEOMETRY_FIELDS})


def panel_map(homogeneity_percent: float = 3.0) -> np.ndarray:
    """(5, 5) relative radiance of the opal panel: mean 1, largest deviation ± homogeneity."""
    p = _MAP_PATTERN - _MAP_PATTERN.mean()
    return 1.0 + homogeneity_percent / 100.0 * p / np.abs(p).max()


def panel_map_at(x_mm: float, y_mm: float, geometry: Any = None) -> float:
    """Relative panel radiance at a point of the panel (mm from its centre), bilinear between the
    25 cell centres (constant beyond the outer centres)."""
    g = as_geometry(geometry)
    m = panel_map(g.panel_homogeneity_percent)
    cx = (np.arange(5) + 0.5) / 5 * g.aperture_x_mm - g.aperture_x_mm / 2
    cy = (np.arange(5) + 0.5) / 5 * g.aperture_y_mm - g.aperture_y_mm / 2
    row = np.array([np.interp(x_mm, cx, m[j]) for j in range(5)])
    return float(np.interp(y_mm, cy, row))


def sample_normal(angle_deg: float) -> np.ndarray:
    s = math.radians(angle_deg)
    return np.array([0.0, -math.sin(s), math.cos(s)])


def radiometer_position_m(geometry: Any = None) -> np.ndarray:
    g = as_geometry(geometry)
    return np.array([0.0, -g.radiometer_distance_mm, g.sample_height_mm]) / 1000.0


def sample_centre_m(geometry: Any = None) -> np.ndarray:
    g = as_geometry(geometry)
    return np.array([0.0, 0.0, g.sample_height_mm / 1000.0])


def panel_cells_m(geometry: Any = None) -> list[tuple[np.ndarray, float, float, float]]:
    """The 25 sub-panels: (centre (3,), half-size x, half-size y, relative radiance)."""
    g = as_geometry(geometry)
    m = panel_map(g.panel_homogeneity_percent)
    ax, ay = g.aperture_x_mm / 1000.0, g.aperture_y_mm / 1000.0
    z = (g.box_inner_mm + g.ceiling_thickness_mm) / 1000.0
    cells = []
    for j in range(5):
        for i in range(5):
            cx = (i + 0.5) / 5 * ax - ax / 2
            cy = (j + 0.5) / 5 * ay - ay / 2
            cells.append((np.array([cx, cy, z]), ax / 10, ay / 10, float(m[j, i])))
    return cells


# --- Mitsuba scene description --------------------------------------------------------------------
def _rect(T: Any, centre: Any, rot: list[tuple[tuple[float, float, float], float]],
          half: tuple[float, float], bsdf: Any) -> dict[str, Any]:
    tr = T().translate(list(map(float, centre)))
    for axis, angle in rot:
        tr = tr @ T().rotate(list(axis), angle)
    tr = tr @ T().scale([half[0], half[1], 1.0])
    return {"type": "rectangle", "to_world": tr, "bsdf": bsdf}


def _box(T: Any, centre: Any, angle_deg: float, half: tuple[float, float, float],
         bsdf: Any) -> dict[str, Any]:
    tr = T().translate(list(map(float, centre))) @ T().rotate([1, 0, 0], angle_deg) \
        @ T().scale(list(half))
    return {"type": "cube", "to_world": tr, "bsdf": bsdf}


#: the shapes that turn with the sample angle (everything else is fixed)
MOVING_SHAPES = ("patch", "holder_plate")
HOLDER_PLATE_THICKNESS_M = 0.005


def moving_transforms(geometry: Any, angle_deg: float) -> dict[str, Any]:
    """`mi.ScalarTransform4f` to_world of the patch (a rectangle) and the holder plate (a cube)
    at a sample angle; the plate's front face is 0.5 mm behind the patch."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    g = as_geometry(geometry)
    c = sample_centre_m(g)
    n = sample_normal(angle_deg)
    ps = g.patch_size_mm / 2000.0
    hs = g.holder_size_mm / 2000.0
    t = HOLDER_PLATE_THICKNESS_M
    return {"patch": _rect(T, c, [((1, 0, 0), angle_deg)], (ps, ps), None)["to_world"],
            "holder_plate": _box(T, c - n * (t + 0.0005), angle_deg, (hs, hs, t),
                                 None)["to_world"]}


def aperture_sides_m(geometry: Any = None) -> tuple:
    """The aperture's four side faces (as `scene_dict` builds them), each (corner, edge 1,
    edge 2) in metres: lit by the panel from close by, small and bright as the sample sees
    them (`predict.guide.GuideRects`)."""
    g = as_geometry(geometry)
    top = g.box_inner_mm / 1000.0
    hx, hy = g.aperture_x_mm / 2000.0, g.aperture_y_mm / 2000.0
    up = (0.0, 0.0, g.ceiling_thickness_mm / 1000.0)
    along_y, along_x = (0.0, 2 * hy, 0.0), (2 * hx, 0.0, 0.0)
    return (((-hx, -hy, top), along_y, up), ((hx, -hy, top), along_y, up),
            ((-hx, -hy, top), along_x, up), ((-hx, hy, top), along_x, up))


def scene_dict(geometry: Any, *, angle_deg: float, patch_bsdf: Any, wall_bsdf: Any,
               holder_bsdf: Any, lamp_values: np.ndarray, lamp_grid_nm: np.ndarray,
               film: dict[str, Any], max_depth: int = 12,
               post_bsdf: Any = None, panel_radiance: Any = None) -> dict[str, Any]:
    """The Mitsuba scene (a `mi.load_dict` dictionary) for one sample angle.

    The BSDFs are Mitsuba objects (or plugin dicts); `lamp_values` (W·sr⁻¹·m⁻²·nm⁻¹ on
    `lamp_grid_nm`, evenly spaced) is the panel's mean spectral radiance; each of the 25
    sub-panels gets it times its map factor.  `film` is the sensor's film dict.  `post_bsdf`
    (default: the holder's) should be a separate object when the plate is moved in place:
    Mitsuba merges meshes that share a BSDF, and a merged plate is no longer addressable.
    `panel_radiance`: a Mitsuba texture for a single emitting panel (the renderer's
    `mitsuba_bsdf.make_panel_texture`: lamp × map); None: 25 emitting cells "panel_00".."24"."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    g = as_geometry(geometry)
    a = g.box_inner_mm / 2000.0
    top = g.box_inner_mm / 1000.0
    hx, hy = g.aperture_x_mm / 2000.0, g.aperture_y_mm / 2000.0
    tc = g.ceiling_thickness_mm / 1000.0
    d: dict[str, Any] = {"type": "scene",
                         "integrator": {"type": "path", "max_depth": int(max_depth),
                                        "rr_depth": 6, "hide_emitters": False}}
    # walls (inner faces), normals into the box
    d["floor"] = _rect(T, [0, 0, 0], [], (a, a), wall_bsdf)
    d["back"] = _rect(T, [0, a, a], [((1, 0, 0), 90)], (a, a), wall_bsdf)
    d["left"] = _rect(T, [-a, 0, a], [((0, 1, 0), 90)], (a, a), wall_bsdf)
    d["right"] = _rect(T, [a, 0, a], [((0, 1, 0), -90)], (a, a), wall_bsdf)
    # ceiling with the aperture: four strips facing down
    down = [((1, 0, 0), 180)]
    d["ceil_front"] = _rect(T, [0, -(a + hy) / 2, top], down, (a, (a - hy) / 2), wall_bsdf)
    d["ceil_back"] = _rect(T, [0, (a + hy) / 2, top], down, (a, (a - hy) / 2), wall_bsdf)
    d["ceil_left"] = _rect(T, [-(a + hx) / 2, 0, top], down, ((a - hx) / 2, hy), wall_bsdf)
    d["ceil_right"] = _rect(T, [(a + hx) / 2, 0, top], down, ((a - hx) / 2, hy), wall_bsdf)
    # the aperture's side faces (ceiling panel edges), facing into the opening
    zc = top + tc / 2
    d["ap_left"] = _rect(T, [-hx, 0, zc], [((0, 1, 0), 90)], (tc / 2, hy), wall_bsdf)
    d["ap_right"] = _rect(T, [hx, 0, zc], [((0, 1, 0), -90)], (tc / 2, hy), wall_bsdf)
    d["ap_front"] = _rect(T, [0, -hy, zc], [((1, 0, 0), -90)], (hx, tc / 2), wall_bsdf)
    d["ap_back"] = _rect(T, [0, hy, zc], [((1, 0, 0), 90)], (hx, tc / 2), wall_bsdf)
    # the opal panel facing down: one emitter with a lamp × map texture, or 25 emitting cells
    black = {"type": "diffuse", "reflectance": {"type": "uniform", "value": 0.0}}
    if panel_radiance is not None:
        panel = _rect(T, [0.0, 0.0, top + tc], down, (hx, hy), black)
        panel["emitter"] = {"type": "area", "radiance": panel_radiance}
        d["panel"] = panel
    else:
        wmin, wmax = float(lamp_grid_nm[0]), float(lamp_grid_nm[-1])
        for k, (centre, ex, ey, factor) in enumerate(panel_cells_m(g)):
            vals = ", ".join(f"{v:.9g}" for v in np.asarray(lamp_values) * factor)
            cell = _rect(T, centre, down, (ex, ey), black)
            cell["emitter"] = {"type": "area",
                               "radiance": {"type": "regular", "wavelength_min": wmin,
                                            "wavelength_max": wmax, "values": vals}}
            d[f"panel_{k:02d}"] = cell
    # holder and patch, rotated about x through the sample centre
    h = g.sample_height_mm / 1000.0
    moving = moving_transforms(g, angle_deg)
    d["patch"] = {"type": "rectangle", "to_world": moving["patch"], "bsdf": patch_bsdf}
    d["holder_plate"] = {"type": "cube", "to_world": moving["holder_plate"], "bsdf": holder_bsdf}
    hs = g.holder_size_mm / 2000.0
    post_top = max(h - hs - 0.01, 0.02)
    d["holder_post"] = _box(T, [0, 0, post_top / 2], 0.0, (0.015, 0.015, post_top / 2),
                            holder_bsdf if post_bsdf is None else post_bsdf)
    # the radiometer
    origin = radiometer_position_m(g)
    c = sample_centre_m(g)
    d["sensor"] = {"type": "perspective", "fov": float(g.radiometer_view_deg), "fov_axis": "x",
                   "near_clip": 0.01, "far_clip": 10.0,
                   "to_world": T().look_at(origin=list(map(float, origin)),
                                           target=list(map(float, c)), up=[0, 0, 1]),
                   # independent: Mitsuba's stratified sampler gave band values at 90° a
                   # ripple that did not change with the seed (±0.8 % per band, period ≈ 51
                   # nm; tests/predict/test_reference_sampler.py)
                   "sampler": {"type": "independent"},
                   "film": film}
    return d


def band_film(band_centres_nm: np.ndarray, band_width_nm: float, pixels: int = 10) -> dict:
    """A `specfilm` with one triangular band (unit height, half-width = band_width) per centre;
    the bands sum to 1 between the first and last centre, so wavelengths are sampled uniformly
    and channel j estimates ∫ hat_j(λ) L(λ) dλ ≈ band_width · L(λ_j)."""
    film: dict[str, Any] = {"type": "specfilm", "width": pixels, "height": pixels,
                            "component_format": "float32", "rfilter": {"type": "box"}}
    w = float(band_width_nm)
    for k, lam in enumerate(band_centres_nm):
        film[f"b{k:04d}"] = {"type": "spectrum",
                             "value": [(float(lam - w), 0.0), (float(lam), 1.0),
                                       (float(lam + w), 0.0)]}
    return film
