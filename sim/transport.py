"""Reaching an emulator in-process: the ``sim://`` pyserial URL scheme and the simulated
seabreeze backend, registered with `normbox_lab.core.transport` (a pty or a loopback TCP port:
`normbox_lab.sim.serve`)."""

from __future__ import annotations

import urllib.parse
from typing import Any

import serial

from normbox_lab.core import transport
from normbox_lab.core.clock import Clock
from normbox_lab.sim import core


def register_url_scheme() -> None:
    """Make the neutral transport reach the in-process emulators: pyserial's
    ``serial_for_url("sim://cs1000a")`` and the simulated seabreeze backend (``sim``,
    ``sim://qepro?seed=1``).  `build_lab` calls it for a simulated lab."""
    transport.register_serial_scheme("normbox_lab.sim")
    transport.register_spectrometer_scheme("sim", open_simulated_spectrometer)


def open_port(url: str, **kwargs) -> serial.SerialBase:
    """pyserial's ``serial_for_url`` with ``sim://`` registered (tests and tools; pyserial's
    own exceptions, where drivers get typed errors from `normbox_lab.core.transport`)."""
    register_url_scheme()
    return serial.serial_for_url(url, **kwargs)


def open_simulated_spectrometer(target: str, clock: Clock, *, world: Any = None,
                                **_: Any) -> transport.SpectrometerLink:
    """``sim`` / ``sim://qepro?seed=1&faults=disconnect@3&key=NAME&serial=…&slide=manual&noise=off``
    → the simulated QE Pro behind the gonio's emulated arms, plugged into the emulated USB bus
    (`normbox_lab.sim.usb`); the driver opens it with seabreeze's pyseabreeze backend through
    that bus.  A bad option or fault spec is a `ValueError`."""
    from normbox_lab.sim import qepro as sim
    from normbox_lab.sim import usb

    parts = urllib.parse.urlsplit(target if "://" in target else "sim://qepro")
    q = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
    key = q.pop("key", "qepro")
    dev_opts: dict[str, Any] = {"seed": int(q.pop("seed", "0")), "faults": q.pop("faults", "")}
    noise = q.pop("noise", "on")
    if noise not in ("on", "off"):
        raise ValueError(f"noise={noise!r}: on or off")
    dev_opts["noise"] = noise == "on"
    for name in ("light_arm", "detector_arm"):
        if name in q:
            dev_opts[name] = q.pop(name)
    for name in ("tilt_deg", "arm_clearance_deg"):
        if name in q:
            dev_opts[name] = float(q.pop(name))
    if world is not None:
        dev_opts["world"] = world
    dev = sim.device(key, clock=clock, serial_number=q.pop("serial", "QEP-SIM-0001"),
                     **dev_opts)
    if world is not None:
        dev.world = world
    slide = q.pop("slide", "motorised")
    if slide not in ("motorised", "manual"):
        raise ValueError(f"slide={slide!r}: motorised or manual")
    if q:
        raise ValueError(f"unknown sim://qepro option(s): {', '.join(sorted(q))}")
    backend = getattr(dev, "usb_backend", None)
    if backend is None or backend.plug not in usb.bus().plugs:
        # on the bus while it is the lab's live device (a later lab's CONTEXT.reset unplugs it)
        backend = usb.plug_qepro(dev, alive=lambda: core.CONTEXT.instances.get(key) is dev)
        dev.usb_backend = backend
    return transport.SpectrometerLink(dev.serial_number, "pyseabreeze", str(backend),
                                      simulated=True,
                                      white_standard=sim.WhiteStandardSlide(
                                          dev, motorised=slide == "motorised"))

