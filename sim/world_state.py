"""What the operator and the motors change in a world, shared by every world of the `World`
protocol (`sim/core.py`): the closed-form `analytic_world.AnalyticWorld` and the rendered
`world.VirtualNormbox` (and its `fast_world.FastVirtualNormbox`).

State, and who changes it:
- the patch on the holder: `place_patch(n)` / `remove_patch()` (the operator step, or the
  virtual operator); `placed` lists every placement in order;
- the sample angle: the rotator emulator attached with `attach_rotator(obj)` (its
  `angle_deg()` is read at every measurement), or `set_sample_angle(angle_deg)` when none is;
- the lamp: the sphere emulator attached with `attach_sphere(obj)` (`relative_output()` scales
  the radiance; its `state()`, when it has one, is recorded in `lamp_state`), or `lamp_level`;
- the light-map aim: `aim_panel(x_mm, y_mm)` points the radiometer at a point of the opal panel
  (until the next `place_patch` / `clear_aim`);
- the gonioreflectometer's sample: `mount_gonio_material(name)`.
"""

from __future__ import annotations

from typing import Any


class WorldState:
    """The operator's and the motors' state of a world; a world subclasses it and adds what the
    instruments see (`radiance_in_view`, `brdf_truth`, …)."""

    def __init__(self) -> None:
        self.patch: int | None = None
        self.placed: list[int] = []
        self.sample_angle_deg = 90.0
        self.lamp_level = 1.0               # 0 = off, when no sphere emulator is attached
        self.rotator: Any = None
        self.sphere: Any = None
        self.lamp_state: Any = None
        self.aim: tuple[float, float] | None = None   # (x_mm, y_mm) on the panel, or None
        self.gonio_material: str | int | None = None

    # --- what the operator and the motors change ----------------------------------------------
    def place_patch(self, n: int) -> None:
        if not 1 <= int(n) <= 24:
            raise ValueError(f"no ColorChecker patch {n} (1..24)")
        self.patch = int(n)
        self.placed.append(int(n))
        self.aim = None

    def remove_patch(self) -> None:
        self.patch = None

    def set_sample_angle(self, angle_deg: float) -> None:
        self.sample_angle_deg = float(angle_deg)

    def attach_rotator(self, rotator: Any) -> None:
        """An object with `angle_deg()` (the rotator emulator); None detaches."""
        self.rotator = rotator

    def attach_sphere(self, sphere: Any) -> None:
        """An object with `relative_output()` (and optionally `state()`): the sphere emulator."""
        self.sphere = sphere

    def aim_panel(self, x_mm: float, y_mm: float) -> None:
        self.aim = (float(x_mm), float(y_mm))

    def clear_aim(self) -> None:
        self.aim = None

    def mount_gonio_material(self, name: str | int) -> None:
        self.gonio_material = name

    # --- state as the instruments see it -------------------------------------------------------
    def angle_deg(self) -> float:
        if self.rotator is not None:
            return float(self.rotator.angle_deg())
        return float(self.sample_angle_deg)

    def relative_output(self) -> float:
        if self.sphere is not None:
            state = getattr(self.sphere, "state", None)
            self.lamp_state = state() if callable(state) else state
            return float(self.sphere.relative_output())
        return float(self.lamp_level)
