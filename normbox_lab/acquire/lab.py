"""Lab assembly: from a `LabConfig` to instruments, a clock, a world and an operator.

    lab = build_lab(load_config("lab.toml"), world="analytic")
    lab.instrument("radiometer").measure()

- Drivers are found by their config name in the one registry (`normbox_lab.acquire.registry`:
  name → module, class, roles), imported lazily, and opened on first use with
  ``Driver.open(port, clock, **options)``; the options come from the driver's own signature,
  so an option the driver does not take is a ConfigError naming it.
- A composite role (``gonio``: the gonioreflectometer made of ``gonio_light_arm``,
  ``gonio_detector_arm`` and ``spectrometer``) is declared in the registry
  (`registry.COMPOSITES`): its parts and the driver function that composes them.
- The clock is ``make_clock(config.time_scale)`` unless one is given.
- A simulated lab (any ``sim://`` port) is wired from *outside*: the caller passes a
  `LabSimulation` (``normbox_lab.sim.labsim.Simulation``; ``normbox_lab.sim.labsim.build_lab``
  builds both), which registers the ``sim://`` transports, shares the lab's clock and world with
  every emulator and gives the expected luminance of each reading (for the radiometer's timing
  model).  This module imports nothing of `normbox_lab.sim`.
- A real lab's ETAs use the luminance a protocol step declares (``luminance_cd_m2``) or
  `REAL_LAB_LUMINANCE_CD_M2`, corrected during the run by the engine from the readings' real
  durations.
"""

from __future__ import annotations

import dataclasses
import logging
from collections.abc import Iterable, Mapping
from typing import Any, Protocol

from normbox_lab.acquire import registry
from normbox_lab.acquire.config import LabConfig
from normbox_lab.acquire.store_api import Store
from normbox_lab.core.capabilities import Closable, Identifiable, Settling
from normbox_lab.core.clock import Clock, make_clock
from normbox_lab.core.errors import ConfigError, NormboxError

#: a real lab's expected luminance of a reading when its step declares none (ETA only)
REAL_LAB_LUMINANCE_CD_M2 = 20.0
log = logging.getLogger("normbox_lab.acquire.lab")


class LabSimulation(Protocol):
    """What a lab asks of its simulation (`normbox_lab.sim.labsim.Simulation`)."""

    world: Any

    def attach(self, role: str, url: str) -> None:
        """An instrument of `role` was opened on `url` (the world may follow its emulator)."""

    def luminance_hint_cd_m2(self, params: Mapping[str, Any]) -> float:
        """Expected luminance of a measurement with these step parameters (ETA only)."""


def driver_class(name: str) -> type:
    return registry.driver_class(name)


class Lab:
    """The assembled lab.  Instruments open on first use (`instrument(role)`)."""

    def __init__(self, config: LabConfig, clock: Clock, *, world: Any = None,
                 operator: Any = None, instruments: Mapping[str, Any] | None = None,
                 simulation: LabSimulation | None = None) -> None:
        self.config = config
        self.clock = clock
        self.world = world
        self.operator = operator
        #: the simulated lab's wiring (passed in from outside), None for a real lab
        self.simulation = simulation
        self._open: dict[str, Any] = dict(instruments or {})

    @property
    def simulated(self) -> bool:
        return self.config.simulated

    def roles(self) -> list[str]:
        roles = list(self.config.instruments)
        roles += [name for name, c in registry.COMPOSITES.items()
                  if all(r in self.config.instruments for r in c.parts)]
        return roles

    def light_sources(self) -> tuple[str, ...]:
        """The roles whose driver is a light source (`Settling`), from the driver classes of
        the registry: nothing is opened to answer."""
        out = []
        for role, cfg in self.config.instruments.items():
            try:
                cls = driver_class(cfg.driver)
            except (ImportError, NormboxError) as exc:   # (then it cannot be opened either)
                log.warning("%s: driver %s not importable: %s", role, cfg.driver, exc)
                continue
            if issubclass(cls, Settling):
                out.append(role)
        return tuple(out)

    def instrument(self, role: str) -> Any:
        inst = self._open.get(role)
        if inst is not None:
            return inst
        composite = registry.COMPOSITES.get(role)
        if composite is not None:
            parts = {r: self.instrument(r) for r in composite.parts}
            inst = registry.composer(role)(parts, self.clock, self.operator and self.ask_operator)
        else:
            try:
                cfg = self.config.instruments[role]
            except KeyError:
                raise ConfigError(self.config.path, 0, f"instruments.{role}",
                                  "the protocol needs this instrument; add it to the lab "
                                  "config") from None
            cls = driver_class(cfg.driver)
            inst = _open_driver(cls, cfg, self.config.path, self.clock)
            if cfg.simulated and self.simulation is not None:
                self.simulation.attach(role, cfg.port)
        self._open[role] = inst
        return inst

    def ask_operator(self, key: str, message: str, **data: Any) -> str:
        """A prompt from inside an instrument (e.g. the gonio's white standard)."""
        from normbox_lab.acquire.events import PromptRequest

        return self.operator(PromptRequest(0, key, "operator", message, ("ok",), data))

    # --- what the engine asks of a lab ----------------------------------------------------------
    def luminance_hint_cd_m2(self, step: Any) -> float:
        """Expected luminance of a measurement, for the radiometer's timing model (ETA): what
        the step declares, else (simulated lab) the simulation's closed-form estimate, else
        `REAL_LAB_LUMINANCE_CD_M2`."""
        p = step.params
        if "luminance_cd_m2" in p:
            return float(p["luminance_cd_m2"])
        if self.simulation is not None:
            return self.simulation.luminance_hint_cd_m2(p)
        return REAL_LAB_LUMINANCE_CD_M2

    def provenance(self) -> dict[str, Any]:
        """What a new run records about the lab."""
        return {"lab_config": self.config.text, "seeds": {"lab": self.config.seed}}

    def identities(self, roles: Iterable[str] | None = None) -> dict[str, dict[str, Any]]:
        """The identity of each open instrument, of `roles` only when given (the gonio's
        parts come with "gonio")."""
        wanted = None if roles is None else set(roles)
        for name, composite in registry.COMPOSITES.items():
            if wanted is not None and name in wanted:
                wanted.update(composite.parts)
        out = {}
        for role, inst in list(self._open.items()):
            if wanted is not None and role not in wanted:
                continue
            d = dataclasses.asdict(inst.identify()) if isinstance(inst, Identifiable) else \
                {"identity": repr(inst)}
            cfg = self.config.instruments.get(role)
            if cfg is not None:
                d.update(driver=cfg.driver, port=cfg.port)
            out[role] = d
        return out

    def record_identities(self, store: Store, run_id: int, segment: int = 1,
                          roles: Iterable[str] | None = None) -> None:
        import datetime

        from normbox_lab.acquire.trust import calibration_flag, calibration_record

        for role, ident in self.identities(roles).items():
            # the calibration in force is recorded with the instrument; an expired one is a
            # quality warning of the run
            cal = calibration_record(self.config, role)
            store.add_instrument(run_id, role, {**ident, "segment": segment}, calibration=cal)
            if cal is not None:
                calibration_flag(store, run_id, role, cal, datetime.date.today())

    def close(self) -> None:
        for inst in self._open.values():
            if isinstance(inst, Closable):
                try:
                    inst.close()
                except (NormboxError, OSError):
                    pass
        self._open.clear()


def _open_driver(cls: type, cfg: Any, config_path: str, clock: Clock) -> Any:
    """``cls.open(port, clock, **options)`` with the options its signature takes
    (`registry.signature_options`); any other option is a ConfigError naming it."""
    accepted = registry.signature_options(cls)
    for key in cfg.options:
        if key not in accepted:
            raise ConfigError(config_path, 0, f"instruments.{cfg.role}.{key}",
                              f"not an option of driver {cfg.driver!r}; it takes "
                              f"{', '.join(sorted(accepted)) or 'none'}")
    return cls.open(cfg.port, clock, **cfg.options)


def build_lab(config: LabConfig, *, simulation: LabSimulation | None = None,
              clock: Clock | None = None, operator: Any = None,
              virtual_operator: bool | None = None, fault_policy: str = "retry",
              operator_response_s: float = 5.0) -> Lab:
    """Assemble a lab.  A config with ``sim://`` ports needs its `simulation`, built outside on
    the same `clock` (``normbox_lab.sim.labsim.build_lab`` does both); a simulated lab gets the
    virtual operator by default."""
    clock = clock if clock is not None else make_clock(config.time_scale)
    if simulation is None and (config.simulated
                               or any(i.simulated for i in config.instruments.values())):
        raise NormboxError("this lab config has sim:// ports: build it with its simulation "
                           "(normbox_lab.sim.labsim.build_lab)")
    world_obj = simulation.world if simulation is not None else None
    if virtual_operator is None:
        virtual_operator = config.simulated and operator is None
    if operator is None and virtual_operator:
        from normbox_lab.acquire.operator import VirtualOperator

        operator = VirtualOperator(world_obj, clock, fault_policy=fault_policy,
                                   response_s=operator_response_s)
    return Lab(config, clock, world=world_obj, operator=operator, simulation=simulation)
