"""The simulated side of a lab, passed into `normbox_lab.acquire.lab.Lab` from outside when a
config has ``sim://`` ports (a real lab never imports this module).  `build_lab` here builds
both: a `Simulation` on the lab's clock, then the lab with it.

- registers the ``sim://`` transports (pyserial URL handler, simulated seabreeze backend) with
  `normbox_lab.core.transport`;
- resets `normbox_lab.sim.core.CONTEXT` to the lab's clock and world, so every emulator runs on
  the lab's clock;
- lets the world follow the emulated rotator's angle and sphere's output (`attach`);
- gives the expected luminance of a reading for the radiometer's timing model (ETA), from the
  closed-form analytic world — cheap where the Mitsuba world would render.
"""

from __future__ import annotations

import urllib.parse
from collections.abc import Mapping
from typing import Any

from normbox_lab.acquire.lab import Lab
from normbox_lab.acquire.lab import build_lab as assemble_lab
from normbox_lab.core.clock import Clock, make_clock
from normbox_lab.core.errors import NormboxError
from normbox_lab.core.types import ReadingGeometry
from normbox_lab.sim import core
from normbox_lab.sim.analytic_world import AnalyticWorld
from normbox_lab.sim.transport import register_url_scheme

#: the world kinds a simulated lab may name
WORLDS = ("normbox", "analytic", "none")


def make_world(kind: str | Any, config: Any = None) -> Any:
    """``"normbox"`` (Mitsuba `VirtualNormbox`), ``"analytic"`` or ``"none"``; any other object
    is used as the world as it is."""
    if not isinstance(kind, str):
        return kind
    if kind not in WORLDS:
        raise NormboxError(f"unknown world {kind!r}; known: {', '.join(WORLDS)}")
    if kind == "none":
        return None
    if kind == "analytic":
        homog = config.geometry.panel_homogeneity_percent if config is not None else 3.0
        return AnalyticWorld(panel_homogeneity_percent=homog)
    if kind == "normbox":
        from normbox_lab.sim.world import VirtualNormbox

        return VirtualNormbox(config=config)
    raise AssertionError(kind)


def build_lab(config: Any, *, world: str | Any = "normbox", clock: Clock | None = None,
              **options: Any) -> Lab:
    """A lab from `config`: with a `Simulation` of `world` on the lab's clock when the config
    has ``sim://`` ports, a real lab otherwise.  `options` go to
    `normbox_lab.acquire.lab.build_lab` (operator, virtual_operator, fault_policy, …)."""
    clock = clock if clock is not None else make_clock(config.time_scale)
    simulation = None
    if config.simulated or any(i.simulated for i in config.instruments.values()):
        simulation = Simulation(config, clock, make_world(world, config))
    return assemble_lab(config, simulation=simulation, clock=clock, **options)


def check_sim_ports(config: Any) -> None:
    """Every ``sim://DEVICE?…`` port of `config` opens as written, or a `ConfigError` (one
    line, exit 2) before any run starts: a known emulator, its options (an emulator built
    with them on a throwaway clock, then dropped), only fault kinds it has, within their
    ranges.  The lab config has read the spec's numbers and the seed
    (`acquire.params.parse_fault_spec`); the kinds are the emulator's table."""
    from normbox_lab.acquire.params import SEED, ParameterError, check_emulator_options, read
    from normbox_lab.core.clock import VirtualClock
    from normbox_lab.core.errors import ConfigError

    for role, inst in config.instruments.items():
        if not inst.simulated:
            continue
        parts = urllib.parse.urlsplit(inst.port)
        device = parts.netloc or parts.path.lstrip("/")
        line = next((i for i, raw in enumerate(str(config.text).splitlines(), 1)
                     if inst.port in raw), 0)
        options = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
        options.pop("key", None)
        spec = options.pop("faults", "")
        try:
            seed = read(options.pop("seed", "0"), SEED, "seed")
            check_emulator_options(options)
            if device == "qepro":            # on the emulated USB bus (sim.transport)
                if spec:
                    core.FaultInjector(spec, 0, core.fault_table(device)[device])
                continue
            if device not in core.EMULATORS:
                raise ValueError(f"unknown simulated device {device[:40]!r}; known: "
                                 f"{', '.join([*core.EMULATORS, 'qepro'])}")
            core.create(device, clock=VirtualClock(), faults=spec, seed=seed, world=None,
                        **options)
        except (ValueError, TypeError, ParameterError) as exc:
            raise ConfigError(config.path, line, f"instruments.{role}.port",
                              " ".join(str(exc).split())[:200]) from None


class Simulation:
    def __init__(self, config: Any, clock: Clock, world: Any) -> None:
        check_sim_ports(config)
        register_url_scheme()
        core.CONTEXT.reset(clock=clock, world=world)
        self.config = config
        self.world = world
        self._estimator: AnalyticWorld | None = world if isinstance(world, AnalyticWorld) \
            else None

    def attach(self, role: str, url: str) -> None:
        """The world reads the rotator's angle and the sphere's output from their emulators."""
        if self.world is None:
            return
        parts = urllib.parse.urlsplit(url)
        if parts.scheme != "sim":
            return
        device = parts.netloc or parts.path.lstrip("/")
        key = urllib.parse.parse_qs(parts.query).get("key", [None])[-1] or device
        emulator = core.CONTEXT.instances.get(key)
        if emulator is None:
            return
        if role == "rotator":
            self.world.attach_rotator(emulator)
        elif role == "sphere":
            self.world.attach_sphere(emulator)

    def luminance_hint_cd_m2(self, params: Mapping[str, Any]) -> float:
        est = self._analytic()
        g = ReadingGeometry.of(params)
        if g.patch is not None:
            return est.luminance_cd_m2(g.patch, g.angle_deg if g.angle_deg is not None else 90.0)
        if "x_mm" in params and "y_mm" in params:
            return est.panel_luminance_cd_m2(float(params["x_mm"]), float(params["y_mm"]))
        return 20.0

    def _analytic(self) -> AnalyticWorld:
        if self._estimator is None:
            r = self.config.render
            self._estimator = AnalyticWorld(
                lamp_cct_K=float(r.get("lamp_cct_K", 3100.0)),
                panel_luminance_cd_m2=float(r.get("panel_luminance_cd_m2", 3000.0)),
                panel_homogeneity_percent=self.config.geometry.panel_homogeneity_percent)
        return self._estimator


__all__ = ["WORLDS", "Simulation", "build_lab", "make_world"]
