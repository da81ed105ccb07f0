"""pyserial URL handler for ``sim://DEVICE?faults=SPEC&seed=N&key=NAME``.

Registered by `normbox_lab.sim.transport.register_url_scheme()` (the lab assembly and the
tests call it).  The port talks to the live emulator `key` (default: DEVICE) in
`normbox_lab.sim.core.CONTEXT`, moving that context's clock: a read with a timeout on a
virtual clock jumps to the emulator's next event instead of sleeping, so simulated minutes of
integration pass instantly at time-scale 0 and deterministically at any scale.
"""

from __future__ import annotations

import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from normbox_lab.acquire.params import SEED, ParameterError, read
from normbox_lab.core.clock import VirtualClock
from normbox_lab.sim import core


class ModemLinesOn:
    """Control lines of an emulated link: RTS, DTR and break accepted and ignored; CTS, DSR
    and CD read on, RI off (a pyserial `SerialBase` mixin; also the RFC 2217 server's)."""

    def _update_rts_state(self) -> None: ...
    def _update_dtr_state(self) -> None: ...
    def _update_break_state(self) -> None: ...

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True


class Serial(ModemLinesOn, SerialBase):
    """A pyserial port whose other end is an in-process emulator."""

    emulator: core.Emulator

    def open(self) -> None:
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        if self.is_open:
            raise SerialException("port already open")
        parts = urllib.parse.urlsplit(self._port)
        if parts.scheme != "sim":
            raise SerialException(f"expected a sim:// URL, got {self._port!r}")
        device = parts.netloc or parts.path.lstrip("/")
        opts = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
        key = opts.pop("key", None)
        faults = opts.pop("faults", "")
        try:
            seed = read(opts.pop("seed", "0"), SEED, "seed")     # the one parser of numbers
            self.emulator = core.instance(device, key=key, faults=faults, seed=seed, **opts)
        except (ValueError, TypeError, ParameterError) as exc:
            raise SerialException(f"cannot open {self._port!r}: {exc}") from exc
        if faults and key is None and self.emulator.faults.rules == {}:
            self.emulator.faults = core.FaultInjector(
                faults, seed, core.TRANSPORT_FAULTS + self.emulator.device_faults)
        self._rx = bytearray()
        self.is_open = True

    def close(self) -> None:
        self.is_open = False

    def _reconfigure_port(self, force_update: bool = False) -> None:
        """Baud rate, parity and handshake do not matter to an in-process emulator."""

    # --- reading and writing ---------------------------------------------------------------
    @property
    def in_waiting(self) -> int:
        self._check_open()
        self._rx += self.emulator.take_output()
        return len(self._rx)

    def write(self, data: bytes) -> int:
        self._check_open()
        self.emulator.poll()
        if not self.emulator.connected:
            raise SerialException(f"{self._port}: device disconnected")
        self.emulator.feed(bytes(data))
        return len(data)

    def read(self, size: int = 1) -> bytes:
        return self._read(lambda buf: len(buf) >= size, size)

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        def done(buf: bytearray) -> bool:
            return expected in buf or (size is not None and len(buf) >= size)

        def cut(buf: bytearray) -> int:
            i = buf.find(expected)
            n = i + len(expected) if i >= 0 else len(buf)
            return min(n, size) if size is not None else n

        return self._read(done, None, cut)

    def _read(self, done, size, cut=None) -> bytes:
        self._check_open()
        clock = self.emulator.clock
        deadline = None if self._timeout is None else clock.now_s() + self._timeout
        while True:
            self.emulator.poll()
            if not self.emulator.connected and not self._rx:
                # A real USB-serial adapter disappears: reads fail.
                raise SerialException(f"{self._port}: device disconnected")
            self._rx += self.emulator.take_output()
            if done(self._rx):
                break
            nxt = self.emulator.next_event_s()
            now = clock.now_s()
            if deadline is not None and (nxt is None or nxt > deadline):
                self._wait(clock, deadline - now)
                self._rx += self.emulator.take_output()
                break
            if nxt is None:
                break  # nothing will ever arrive: do not spin forever on a virtual clock
            self._wait(clock, max(0.0, nxt - now))
        n = (cut(self._rx) if cut else min(size, len(self._rx)))
        data = bytes(self._rx[:n])
        del self._rx[:n]
        return data

    @staticmethod
    def _wait(clock, duration_s: float) -> None:
        if duration_s > 0:
            clock.sleep(duration_s)
        elif not isinstance(clock, VirtualClock):
            clock.sleep(0.001)

    def reset_input_buffer(self) -> None:
        self._check_open()
        self.emulator.take_output()
        self._rx.clear()

    def reset_output_buffer(self) -> None:
        self._check_open()

    def flush(self) -> None:
        self._check_open()

    def _check_open(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()



__all__ = ["Serial"]
