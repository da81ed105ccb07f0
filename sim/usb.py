"""Emulated USB devices for pyusb: the QE Pro on a bus that unmodified python-seabreeze drives.

pyusb talks to the operating system through a *backend* (`usb.backend.IBackend`: enumerate
devices, read their descriptors, open, claim, bulk transfers, reset).  This module is such a
backend, with the emulated devices plugged into it instead of real ones.  pyseabreeze asks for a
pyusb backend by name (``seabreeze.use("pyseabreeze", pyusb_backend=NAME)`` →
``importlib.import_module("usb.backend." + NAME).get_backend()``, python-seabreeze
``pyseabreeze/transport.py``), so the bus is published as the module
``usb.backend.normbox_emulated`` and `emulated_usb` yields that name:

    from normbox_lab.sim.usb import emulated_usb
    with emulated_usb("qepro", seed=1) as backend:
        import seabreeze
        seabreeze.use("pyseabreeze", pyusb_backend=backend, network_adapter="none")
        from seabreeze.spectrometers import Spectrometer, list_devices
        spec = Spectrometer.from_first_available()      # VID 0x2457, PID 0x4004
        spec.integration_time_micros(100_000)
        counts = spec.intensities()

The yielded name is a `str` (what pyseabreeze accepts) that also carries the emulated device
(``backend.device``: the `sim.qepro.SimulatedQEProDevice` physics, with its fault injector and
clock).  One bus serves the whole process under one name, because seabreeze caches its API
object (with the backend name) and pyseabreeze caches backend instances by name: every
`emulated_usb` context plugs its device into that bus and unplugs it on exit.

Bus behaviour, as libusb shows it to pyusb:

- each (re-)enumeration gets a new bus address (a device that dropped off and came back is a
  new `usb.core.Device`; the old handle stays dead), unique in the process;
- a device whose link is down is not enumerated, and every transfer on a handle of it raises
  `usb.core.USBError` errno 19 (ENODEV, libusb's LIBUSB_ERROR_NO_DEVICE);
- a bulk read with nothing to read waits out its timeout on the device's clock, then raises
  `usb.core.USBTimeoutError` (errno 110);
- `reset_device` drops whatever the device still had queued for the host.

What a device must provide to be plugged (`UsbFunction`): its descriptors, ``present()``,
``bulk_out(endpoint, data)``, ``bulk_in(endpoint, size)`` (bytes now, or b"" for nothing),
``reset()`` and a ``clock``.  `sim.qepro.QEProUsb` is the QE Pro's.
"""

from __future__ import annotations

import contextlib
import errno
import itertools
import sys
import types
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, Protocol

import usb.backend
import usb.core

from normbox_lab.sim.usb_descriptors import Descriptor, bulk_endpoint, device_descriptor

BACKEND_NAME = "normbox_emulated"
#: libusb error codes pyusb carries in `USBError.backend_error_code`
_LIBUSB_ERROR_TIMEOUT = -7
_LIBUSB_ERROR_NO_DEVICE = -4


class UsbFunction(Protocol):
    """What a device plugged into the emulated bus provides."""

    clock: Any
    device_descriptor: Descriptor
    strings: dict[int, str]
    endpoints: list[Descriptor]         # one vendor-specific interface, configuration 1

    def present(self) -> bool: ...
    def bulk_out(self, endpoint: int, data: bytes) -> None: ...
    def bulk_in(self, endpoint: int, size: int) -> bytes: ...
    def reset(self) -> None: ...


@dataclass
class Plug:
    """One device on the bus, with the address of its current enumeration."""

    function: Any
    alive: Callable[[], bool] = lambda: True
    bus: int = 1
    address: int = 0
    was_present: bool = False
    generation: int = 0
    configuration: int = 0
    claimed: set[int] = field(default_factory=set)


@dataclass(frozen=True)
class _DeviceRef:
    plug: Plug
    generation: int
    bus: int
    address: int


@dataclass
class _Handle:
    ref: _DeviceRef


_ADDRESSES = itertools.count()


def _next_address() -> tuple[int, int]:
    n = next(_ADDRESSES)
    return 1 + n // 127, 1 + n % 127


def _no_device() -> usb.core.USBError:
    return usb.core.USBError("No such device (it may have been disconnected)",
                             _LIBUSB_ERROR_NO_DEVICE, errno.ENODEV)


class EmulatedBus(usb.backend.IBackend):
    """The pyusb backend: the devices plugged into it are what `usb.core.find` sees."""

    def __init__(self) -> None:
        super().__init__()
        self.plugs: list[Plug] = []

    # --- plugging ---------------------------------------------------------------------------
    def plug(self, function: Any, alive: Callable[[], bool] | None = None) -> Plug:
        p = Plug(function, alive or (lambda: True))
        self.plugs.append(p)
        return p

    def unplug(self, plug: Plug) -> None:
        if plug in self.plugs:
            self.plugs.remove(plug)

    def _refresh(self, plug: Plug) -> bool:
        """Is the device there now?  A device that (re)appears gets a new address."""
        here = plug.alive() and plug.function.present()
        if here and not plug.was_present:
            plug.generation += 1
            plug.bus, plug.address = _next_address()
            plug.configuration = 0
            plug.claimed.clear()
        plug.was_present = here
        return here

    def _check(self, handle: _Handle) -> Plug:
        plug = handle.ref.plug
        if plug not in self.plugs or not self._refresh(plug) \
                or plug.generation != handle.ref.generation:
            raise _no_device()
        return plug

    # --- IBackend: enumeration and descriptors ----------------------------------------------
    def enumerate_devices(self) -> Iterator[_DeviceRef]:
        self.plugs = [p for p in self.plugs if p.alive()]
        for plug in list(self.plugs):
            if self._refresh(plug):
                yield _DeviceRef(plug, plug.generation, plug.bus, plug.address)

    def get_parent(self, dev: _DeviceRef) -> None:
        return None

    def get_device_descriptor(self, dev: _DeviceRef) -> Descriptor:
        d = Descriptor(**dev.plug.function.device_descriptor.__dict__)
        d.bus, d.address, d.port_number, d.speed = dev.bus, dev.address, 1, 3  # high speed
        d.port_numbers = (1,)
        return d

    def get_configuration_descriptor(self, dev: _DeviceRef, config: int) -> Descriptor:
        if config != 0:
            raise IndexError(config)
        eps = dev.plug.function.endpoints
        return Descriptor(bLength=9, bDescriptorType=0x02, wTotalLength=9 + 9 + 7 * len(eps),
                          bNumInterfaces=1, bConfigurationValue=1, iConfiguration=0,
                          bmAttributes=0x80, bMaxPower=250)

    def get_interface_descriptor(self, dev: _DeviceRef, intf: int, alt: int,
                                 config: int) -> Descriptor:
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError((intf, alt, config))
        return Descriptor(bLength=9, bDescriptorType=0x04, bInterfaceNumber=0,
                          bAlternateSetting=0, bNumEndpoints=len(dev.plug.function.endpoints),
                          bInterfaceClass=0xFF, bInterfaceSubClass=0, bInterfaceProtocol=0,
                          iInterface=0)

    def get_endpoint_descriptor(self, dev: _DeviceRef, ep: int, intf: int, alt: int,
                                config: int) -> Descriptor:
        if (intf, alt, config) != (0, 0, 0):
            raise IndexError((intf, alt, config))
        return dev.plug.function.endpoints[ep]

    # --- IBackend: handles -------------------------------------------------------------------
    def open_device(self, dev: _DeviceRef) -> _Handle:
        handle = _Handle(dev)
        self._check(handle)
        return handle

    def close_device(self, dev_handle: _Handle) -> None:
        return None

    def set_configuration(self, dev_handle: _Handle, config_value: int) -> None:
        self._check(dev_handle).configuration = int(config_value)

    def get_configuration(self, dev_handle: _Handle) -> int:
        return self._check(dev_handle).configuration

    def set_interface_altsetting(self, dev_handle: _Handle, intf: int, altsetting: int) -> None:
        self._check(dev_handle)

    def claim_interface(self, dev_handle: _Handle, intf: int) -> None:
        self._check(dev_handle).claimed.add(int(intf))

    def release_interface(self, dev_handle: _Handle, intf: int) -> None:
        handle_plug = dev_handle.ref.plug
        handle_plug.claimed.discard(int(intf))

    def is_kernel_driver_active(self, dev_handle: _Handle, intf: int) -> bool:
        return False

    def detach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        return None

    def attach_kernel_driver(self, dev_handle: _Handle, intf: int) -> None:
        return None

    def clear_halt(self, dev_handle: _Handle, ep: int) -> None:
        self._check(dev_handle)

    def reset_device(self, dev_handle: _Handle) -> None:
        self._check(dev_handle).function.reset()

    # --- IBackend: transfers -------------------------------------------------------------------
    def bulk_write(self, dev_handle: _Handle, ep: int, intf: int, data: Any,
                   timeout: int) -> int:
        plug = self._check(dev_handle)
        payload = bytes(data)
        plug.function.bulk_out(int(ep), payload)
        if plug.generation != dev_handle.ref.generation or not self._refresh(plug):
            raise _no_device()                 # it dropped off while taking the transfer
        return len(payload)

    def bulk_read(self, dev_handle: _Handle, ep: int, intf: int, buff: Any,
                  timeout: int) -> int:
        plug = self._check(dev_handle)
        data = plug.function.bulk_in(int(ep), len(buff))
        if not data:
            plug.function.clock.sleep((timeout or 1000) / 1000.0)
            self._check(dev_handle)
            raise usb.core.USBTimeoutError("Operation timed out", _LIBUSB_ERROR_TIMEOUT,
                                           errno.ETIMEDOUT)
        n = min(len(data), len(buff))
        buff[:n] = type(buff)(buff.typecode, data[:n]) if hasattr(buff, "typecode") \
            else data[:n]
        return n

    def ctrl_transfer(self, dev_handle: _Handle, bmRequestType: int, bRequest: int,
                      wValue: int, wIndex: int, data: Any, timeout: int) -> Any:
        """Standard GET_DESCRIPTOR for string descriptors (what `usb.util.get_string` asks);
        anything else stalls (EPIPE), as a device answers requests it does not know."""
        plug = self._check(dev_handle)
        if bmRequestType == 0x80 and bRequest == 0x06 and wValue >> 8 == 0x03:
            index = wValue & 0xFF
            if index == 0:
                raw = bytes([4, 3, 0x09, 0x04])                       # LANGID en-US
            else:
                text = plug.function.strings.get(index)
                if text is None:
                    raise usb.core.USBError("Pipe error", -9, errno.EPIPE)
                enc = text.encode("utf-16-le")
                raw = bytes([2 + len(enc), 3]) + enc
            n = min(len(raw), len(data))
            data[:n] = type(data)(data.typecode, raw[:n])
            return n
        raise usb.core.USBError("Pipe error", -9, errno.EPIPE)


_BUS: EmulatedBus | None = None


def bus() -> EmulatedBus:
    """The process's emulated bus, published as pyusb backend ``usb.backend.normbox_emulated``
    (pyseabreeze: ``pyusb_backend="normbox_emulated"``)."""
    global _BUS
    if _BUS is None:
        _BUS = EmulatedBus()
        module = types.ModuleType(f"usb.backend.{BACKEND_NAME}")
        module.get_backend = bus                       # type: ignore[attr-defined]
        module.__doc__ = "normbox-lab's emulated USB bus (normbox_lab.sim.usb)"
        sys.modules[module.__name__] = module
        setattr(usb.backend, BACKEND_NAME, module)
    return _BUS


def get_backend() -> EmulatedBus:
    """pyusb's backend-module convention."""
    return bus()


class BackendName(str):
    """The pyusb backend name pyseabreeze takes, carrying the device it reaches."""

    device: Any
    function: Any
    plug: Plug


def plug_qepro(device: Any, alive: Callable[[], bool] | None = None) -> BackendName:
    """Put the QE Pro `device` (a `sim.qepro.SimulatedQEProDevice`) on the bus; returns the
    backend name, with `.device`, `.function` and `.plug`."""
    from normbox_lab.sim.qepro import QEProUsb

    function = QEProUsb(device)
    plug = bus().plug(function, alive)
    name = BackendName(BACKEND_NAME)
    name.device, name.function, name.plug = device, function, plug
    return name


@contextlib.contextmanager
def emulated_usb(kind: str = "qepro", *, seed: int = 0, faults: str = "", clock: Any = None,
                 world: Any = None, serial_number: str = "QEP-SIM-0001",
                 **options: Any) -> Iterator[BackendName]:
    """Plug an emulated USB device for the duration of the block; yields the pyusb backend
    name for ``seabreeze.use("pyseabreeze", pyusb_backend=...)``.

    `kind`: ``"qepro"`` (Ocean Insight QE Pro, VID 0x2457 PID 0x4004).  `seed`, `faults`
    (the ``sim://qepro`` fault spec: ``disconnect@3:30``, ``saturation``, ``tec-drift``,
    ``dark-drift``, ``lamp-dim@5:0.5`` …), `clock` (default a `VirtualClock`), `world` and
    further `SimulatedQEProDevice` options (``light_arm``, ``detector_arm``, ``lamp`` …)."""
    if kind != "qepro":
        raise ValueError(f"no emulated USB device {kind!r} (known: qepro)")
    from normbox_lab.core.clock import VirtualClock
    from normbox_lab.sim.qepro import SimulatedQEProDevice

    device = SimulatedQEProDevice(clock if clock is not None else VirtualClock(), world=world,
                                  serial_number=serial_number, faults=faults, seed=seed,
                                  **options)
    name = plug_qepro(device)
    try:
        yield name
    finally:
        bus().unplug(name.plug)


__all__ = ["BACKEND_NAME", "BackendName", "Descriptor", "EmulatedBus", "UsbFunction", "bulk_endpoint",
           "bus", "device_descriptor", "emulated_usb", "get_backend", "plug_qepro"]
