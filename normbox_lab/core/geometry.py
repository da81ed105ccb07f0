"""The Normbox's geometry: one dataclass for the lab config, the scene and the virtual box.

Lengths in mm, angles in degrees.  Defaults are the box of the Normbox paper ([NORMBOX] in
docs/references.md): a 600 mm cube with 15 mm walls and a 19 mm ceiling, a 220 × 200 mm
aperture under the integrating sphere, walls painted grey (RAL 7004, L ≈ 65), panel
homogeneity ±3 %.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class NormboxGeometry:
    """Normbox geometry.  Lengths in mm, angles in degrees."""

    box_inner_mm: float = 600.0
    wall_thickness_mm: float = 15.0
    ceiling_thickness_mm: float = 19.0
    aperture_x_mm: float = 220.0
    aperture_y_mm: float = 200.0
    patch_size_mm: float = 50.0
    holder_size_mm: float = 80.0
    sample_height_mm: float = 200.0          # sample centre above the floor
    radiometer_distance_mm: float = 1000.0   # sample centre to radiometer front lens
    radiometer_view_deg: float = 1.0
    wall_lightness_L: float = 65.0
    panel_homogeneity_percent: float = 3.0


GEOMETRY_FIELDS: tuple[str, ...] = tuple(NormboxGeometry.__dataclass_fields__)
