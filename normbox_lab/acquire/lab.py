"""Lab assembly: from a `LabConfig` to instruments, a clock, a world and an operator.

    lab = build_lab(load_config("lab.toml"), world="analytic")
    lab.instrument("radiometer").measure()

- Drivers are found by their config name (`DRIVERS`: name → module, class), imported lazily,
  and opened on first use with ``Driver.open(port, clock, **options)``.
- The role ``gonio`` is composed from ``gonio_light_arm``, ``gonio_detector_arm`` and
  ``spectrometer`` by `normbox_lab.drivers.gonio` (when that module exists).
- The clock is ``make_clock(config.time_scale)``; a simulated lab shares it (and the world)
  with ``normbox_lab.sim.core.CONTEXT``, so every emulator runs on the lab's clock.
- Worlds (simulated labs): ``"normbox"`` (the Mitsuba `VirtualNormbox`, slow: seconds per new
  configuration), ``"analytic"`` (`sim/analytic_world.py`, closed form, milliseconds), or
  ``"none"``.  The `VirtualOperator` answers prompts in simulated labs.
"""

from __future__ import annotations

import dataclasses
import importlib
from collections.abc import Mapping
from typing import Any

from normbox_lab.acquire.config import LabConfig
from normbox_lab.core.capabilities import Closable, Identifiable
from normbox_lab.core.clock import Clock, make_clock
from normbox_lab.core.errors import ConfigError, NormboxError

#: config driver name → (module, class names to try, in order)
DRIVERS: dict[str, tuple[str, tuple[str, ...]]] = {
    "cs1000a": ("normbox_lab.drivers.cs1000", ("CS1000A", "CS1000", "Cs1000A")),
    "cs2000a": ("normbox_lab.drivers.cs2000", ("CS2000A", "CS2000", "Cs2000A")),
    "apt-k10cr1": ("normbox_lab.drivers.rotator_apt", ("AptRotationStage",)),
    "zaber": ("normbox_lab.drivers.rotator_zaber", ("ZaberRotationStage",)),
    "sphere-scpi": ("normbox_lab.drivers.sphere", ("SphereLightSource",)),
    "qepro": ("normbox_lab.drivers.qepro", ("QEPro", "QePro", "QEProSpectrometer")),
}
GONIO_ROLES = ("gonio_light_arm", "gonio_detector_arm", "spectrometer")
WORLDS = ("normbox", "analytic", "none")


def driver_class(name: str) -> type:
    try:
        module_name, class_names = DRIVERS[name]
    except KeyError:
        raise NormboxError(f"unknown driver {name!r}; known: {', '.join(DRIVERS)}") from None
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name == module_name:
            raise NormboxError(f"driver {name!r}: module {module_name} is not installed") from exc
        raise
    for cls_name in class_names:
        cls = getattr(module, cls_name, None)
        if cls is not None:
            return cls
    raise NormboxError(f"driver {name!r}: {module_name} has none of {', '.join(class_names)}")


def make_world(kind: str | Any, config: LabConfig | None = None) -> Any:
    if not isinstance(kind, str):
        return kind                       # an object: used as it is
    if kind == "none":
        return None
    if kind == "analytic":
        from normbox_lab.sim.analytic_world import AnalyticWorld

        homog = config.geometry.panel_homogeneity_percent if config is not None else 3.0
        return AnalyticWorld(panel_homogeneity_percent=homog)
    if kind == "normbox":
        from normbox_lab.sim.world import VirtualNormbox

        return _construct_virtual_normbox(VirtualNormbox, config)
    raise NormboxError(f"unknown world {kind!r}; known: {', '.join(WORLDS)}")


def _construct_virtual_normbox(cls: type, config: LabConfig | None) -> Any:
    if config is None:
        return cls()
    for kwargs in ({"config": config}, {"geometry": config.geometry}, {}):
        try:
            return cls(**kwargs)
        except TypeError:
            continue
    return cls()


class Lab:
    """The assembled lab.  Instruments open on first use (`instrument(role)`)."""

    def __init__(self, config: LabConfig, clock: Clock, *, world: Any = None,
                 operator: Any = None, instruments: Mapping[str, Any] | None = None) -> None:
        self.config = config
        self.clock = clock
        self.world = world
        self.operator = operator
        self._open: dict[str, Any] = dict(instruments or {})

    @property
    def simulated(self) -> bool:
        return self.config.simulated

    def roles(self) -> list[str]:
        roles = list(self.config.instruments)
        if all(r in self.config.instruments for r in GONIO_ROLES):
            roles.append("gonio")
        return roles

    def instrument(self, role: str) -> Any:
        inst = self._open.get(role)
        if inst is not None:
            return inst
        if role == "gonio":
            inst = self._open_gonio()
        else:
            try:
                cfg = self.config.instruments[role]
            except KeyError:
                raise ConfigError(self.config.path, 0, f"instruments.{role}",
                                  "the protocol needs this instrument; add it to the lab "
                                  "config") from None
            cls = driver_class(cfg.driver)
            options = {k: v for k, v in cfg.options.items()}
            inst = _open_driver(cls, cfg.port, self.clock, options)
            if cfg.simulated and self.world is not None:
                self._attach_to_world(role, cfg.port)
        self._open[role] = inst
        return inst

    def _attach_to_world(self, role: str, url: str) -> None:
        """The world reads the rotator's angle and the sphere's output from their emulators."""
        emu = _emulator_for(url)
        if emu is None:
            return
        if role == "rotator" and hasattr(emu, "angle_deg") and \
                hasattr(self.world, "attach_rotator"):
            self.world.attach_rotator(emu)
        elif role == "sphere" and hasattr(emu, "relative_output") and \
                hasattr(self.world, "attach_sphere"):
            self.world.attach_sphere(emu)

    def _open_gonio(self) -> Any:
        try:
            gonio_mod = importlib.import_module("normbox_lab.drivers.gonio")
        except ModuleNotFoundError as exc:
            raise NormboxError("the gonioreflectometer driver (normbox_lab.drivers.gonio) is "
                               "not installed") from exc
        parts = {r: self.instrument(r) for r in GONIO_ROLES}
        cls = next((getattr(gonio_mod, n) for n in ("Gonioreflectometer", "InPlaneGonio",
                                                    "Gonio") if hasattr(gonio_mod, n)), None)
        if cls is None:
            raise NormboxError("normbox_lab.drivers.gonio defines no Gonioreflectometer class")
        build = getattr(cls, "from_parts", None) or cls
        extra: dict[str, Any] = {}
        white = getattr(gonio_mod, "OperatorWhiteStandard", None)
        if not hasattr(parts["spectrometer"], "white_standard") and white is not None \
                and self.operator is not None:
            # a real gonio: the operator places the Spectralon during `calibrate`
            extra["white_standard"] = white(lambda message: self.ask_operator(
                "gonio/white-standard", message, action="white_standard"))
        return build(spectrometer=parts["spectrometer"], light_arm=parts["gonio_light_arm"],
                     detector_arm=parts["gonio_detector_arm"], clock=self.clock, **extra)

    def ask_operator(self, key: str, message: str, **data: Any) -> str:
        """A prompt from inside an instrument (e.g. the gonio's white standard)."""
        from normbox_lab.acquire.events import PromptRequest

        return self.operator(PromptRequest(0, key, "operator", message, ("ok",), data))

    # --- what the engine asks of a lab ----------------------------------------------------------
    def luminance_hint_cd_m2(self, step: Any) -> float:
        """Expected luminance of a measurement, for the radiometer's timing model (ETA).

        From the closed-form analytic world (the lab's own world when it is analytic, else one
        built with the render table's lamp): cheap, where the Mitsuba world would render."""
        p = step.params
        if "luminance_cd_m2" in p:
            return float(p["luminance_cd_m2"])
        est = self._estimator()
        if "patch" in p:
            return est.luminance_cd_m2(int(p["patch"]), float(p.get("angle_deg", 90.0)))
        if "x_mm" in p and "y_mm" in p:
            return est.panel_luminance_cd_m2(float(p["x_mm"]), float(p["y_mm"]))
        return 20.0

    def _estimator(self) -> Any:
        from normbox_lab.sim.analytic_world import AnalyticWorld

        if isinstance(self.world, AnalyticWorld):
            return self.world
        if getattr(self, "_est", None) is None:
            r = self.config.render
            self._est = AnalyticWorld(
                lamp_cct_K=float(r.get("lamp_cct_K", 3100.0)),
                panel_luminance_cd_m2=float(r.get("panel_luminance_cd_m2", 3000.0)),
                panel_homogeneity_percent=self.config.geometry.panel_homogeneity_percent)
        return self._est

    def provenance(self) -> dict[str, Any]:
        """What a new run records about the lab."""
        return {"lab_config": self.config.text, "seeds": {"lab": self.config.seed}}

    def identities(self) -> dict[str, dict[str, Any]]:
        out = {}
        for role, inst in self._open.items():
            d = dataclasses.asdict(inst.identify()) if isinstance(inst, Identifiable) else \
                {"identity": repr(inst)}
            cfg = self.config.instruments.get(role)
            if cfg is not None:
                d.update(driver=cfg.driver, port=cfg.port)
            out[role] = d
        return out

    def record_identities(self, store: Any, run_id: int, segment: int = 1) -> None:
        for role, ident in self.identities().items():
            store.add_instrument(run_id, role, {**ident, "segment": segment})

    def close(self) -> None:
        for inst in self._open.values():
            if isinstance(inst, Closable):
                try:
                    inst.close()
                except (NormboxError, OSError):
                    pass
        self._open.clear()


def _emulator_for(url: str) -> Any:
    import urllib.parse

    from normbox_lab.sim import core

    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        return None
    device = parts.netloc or parts.path.lstrip("/")
    key = urllib.parse.parse_qs(parts.query).get("key", [None])[-1] or device
    return core.CONTEXT.instances.get(key)


def _open_driver(cls: type, port: str, clock: Clock, options: dict[str, Any]) -> Any:
    try:
        return cls.open(port, clock, **options)
    except TypeError:
        # options the driver does not take (limits used by the lab only): pass what it accepts
        import inspect

        sig = inspect.signature(cls.open)
        if any(p.kind == p.VAR_KEYWORD for p in sig.parameters.values()):
            raise
        accepted = {k: v for k, v in options.items() if k in sig.parameters}
        return cls.open(port, clock, **accepted)


def build_lab(config: LabConfig, *, world: str | Any = "normbox", clock: Clock | None = None,
              operator: Any = None, virtual_operator: bool | None = None,
              fault_policy: str = "retry", operator_response_s: float = 5.0) -> Lab:
    """Assemble a lab.  Simulated labs get `world` and (by default) the virtual operator."""
    clock = clock if clock is not None else make_clock(config.time_scale)
    world_obj = None
    if config.simulated or any(i.simulated for i in config.instruments.values()):
        from normbox_lab.sim import core

        world_obj = make_world(world, config)
        core.CONTEXT.reset(clock=clock, world=world_obj)
    if virtual_operator is None:
        virtual_operator = config.simulated and operator is None
    if operator is None and virtual_operator:
        from normbox_lab.acquire.operator import VirtualOperator

        operator = VirtualOperator(world_obj, clock, fault_policy=fault_policy,
                                   response_s=operator_response_s)
    return Lab(config, clock, world=world_obj, operator=operator)
