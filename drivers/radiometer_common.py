"""What the CS-1000A and CS-2000A drivers share: line I/O with deadlines, link-loss
recovery, number parsing, the colorimetric block, and the abort handshake.

Every read has a deadline on the injected clock, so nothing hangs: a reply that does not
complete in time is an `InstrumentTimeout` (nothing came) or a `ProtocolError` (a line began
but never ended — a truncated reply).  Long waits are read in slices of `poll_s` so that
`abort()` from another thread is noticed; only the thread running `measure()` touches the port.

Recovery (bounded): before each command stale input is flushed; a lost link (the port raises
`SerialException`/`OSError`) is waited for up to `reconnect_timeout_s`, the port reopened, and
remote mode entered again before the command is repeated.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from typing import Any, TypeVar

import numpy as np
from serial import SerialException

from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    DeviceError,
    InstrumentError,
    InstrumentTimeout,
    OperatorAbort,
    ProtocolError,
)
from normbox_lab.core.types import Colorimetry

T = TypeVar("T")

COLORIMETRY_FIELDS = ("Le", "Lv", "X", "Y", "Z", "x", "y", "u′", "v′", "T", "Δuv")
#: values the instruments print for "calculation error / undefined" (CS-2000 spec §4.2)
SENTINELS = (-9.9999e9, -9.9e9, -9.999, -9999.0, -9.9999, -9.999999e10)


class LinkLost(InstrumentError):
    """The port went away (USB unplugged, power blip); internal: triggers reconnection."""


class SerialRadiometer:
    """Line I/O on a pyserial-like port for Konica Minolta radiometers."""

    model = ""
    terminator = b"\n"
    #: seconds per read slice while waiting long (abort is checked between slices)
    poll_s = 1.0

    def __init__(self, port: Any, clock: Clock, *, instrument_id: str = "radiometer",
                 command_timeout_s: float = 10.0, attempts: int = 3,
                 reconnect_timeout_s: float = 10.0) -> None:
        self.port = port
        self.clock = clock
        self.instrument_id = instrument_id
        self.command_timeout_s = float(command_timeout_s)
        self.attempts = int(attempts)
        self.reconnect_timeout_s = float(reconnect_timeout_s)
        self.remote = False
        self._abort = threading.Event()
        self._measuring = False
        self._lock = threading.RLock()
        #: (command, reply) of every exchange, newest last (bounded), for status and logs
        self.history: list[tuple[bytes, bytes]] = []

    # --- errors -------------------------------------------------------------------------------
    def _protocol(self, msg: str, raw: bytes) -> ProtocolError:
        return ProtocolError(msg, raw=raw, instrument=self.instrument_id)

    def _timeout(self, msg: str) -> InstrumentTimeout:
        return InstrumentTimeout(msg, instrument=self.instrument_id)

    # --- bytes ----------------------------------------------------------------------------------
    def _write(self, cmd: bytes) -> None:
        try:
            self.port.reset_input_buffer()
            self.port.write(cmd + self.terminator)
        except (SerialException, OSError) as exc:
            raise LinkLost(f"write failed: {exc}", instrument=self.instrument_id) from exc

    def _read_exact(self, n: int, timeout_s: float) -> bytes:
        deadline = self.clock.now_s() + timeout_s
        buf = bytearray()
        while len(buf) < n:
            remaining = deadline - self.clock.now_s()
            if remaining <= 0:
                if buf:
                    raise self._protocol(f"binary block cut short ({len(buf)} of {n} bytes)",
                                         bytes(buf))
                raise self._timeout(f"no binary block within {timeout_s:g} s")
            try:
                self.port.timeout = min(remaining, self.poll_s)
                buf += self.port.read(n - len(buf))
            except (SerialException, OSError) as exc:
                raise LinkLost(f"read failed: {exc}", instrument=self.instrument_id) from exc
        return bytes(buf)

    def _read_line(self, timeout_s: float, *, watch_abort: bool = False) -> bytes | None:
        """One reply line without its terminator.  None when `watch_abort` and abort() was
        requested before the line began."""
        deadline = self.clock.now_s() + timeout_s
        buf = bytearray()
        while True:
            if watch_abort and not buf and self._abort.is_set():
                return None
            remaining = deadline - self.clock.now_s()
            if remaining <= 0:
                if buf:
                    raise self._protocol("reply cut short (no line end)", bytes(buf))
                raise self._timeout(f"no reply within {timeout_s:g} s")
            try:
                self.port.timeout = min(remaining, self.poll_s)
                buf += self.port.read_until(b"\n")
            except (SerialException, OSError) as exc:
                raise LinkLost(f"read failed: {exc}", instrument=self.instrument_id) from exc
            if buf.endswith(b"\n"):
                return bytes(buf).rstrip(b"\r\n")

    def exchange(self, cmd: bytes, timeout_s: float | None = None) -> bytes:
        """Send one command, return its reply line (no retry, no interpretation)."""
        self._write(cmd)
        reply = self._read_line(self.command_timeout_s if timeout_s is None else timeout_s)
        assert reply is not None
        self.history = (self.history + [(cmd, reply)])[-50:]
        return reply

    # --- recovery -------------------------------------------------------------------------------
    def _reconnect(self) -> None:
        """Wait for the link to come back (bounded), reopen the port, re-enter remote mode."""
        deadline = self.clock.now_s() + self.reconnect_timeout_s
        self.remote = False
        while True:
            self.clock.sleep(1.0)
            try:
                if hasattr(self.port, "close") and hasattr(self.port, "open"):
                    self.port.close()
                    self.port.open()
                self.port.reset_input_buffer()
                self._enter_remote()
                return
            except (LinkLost, InstrumentTimeout, ProtocolError, SerialException, OSError):
                if self.clock.now_s() >= deadline:
                    raise self._timeout(
                        f"link lost and not back within {self.reconnect_timeout_s:g} s") from None

    def _enter_remote(self) -> None:  # pragma: no cover - per model
        raise NotImplementedError

    def with_retries(self, action: Callable[[], T], *, retry_device: tuple[str, ...] = (),
                     busy_wait_s: float = 2.0) -> T:
        """Run `action` up to `attempts` times: transport faults are retried (after a
        reconnect when the link was lost), device errors whose code is in `retry_device`
        after `busy_wait_s`; everything else raises at once."""
        last: InstrumentError | None = None
        for attempt in range(1, self.attempts + 1):
            try:
                return action()
            except LinkLost as exc:
                last = exc
                self._reconnect()
            except (InstrumentTimeout, ProtocolError) as exc:
                last = exc
                self._resync()
            except DeviceError as exc:
                if exc.code not in retry_device or attempt == self.attempts:
                    raise
                last = exc
                self.clock.sleep(busy_wait_s)
        assert last is not None
        if isinstance(last, LinkLost):
            raise self._timeout(f"link lost: {last}") from last
        raise last

    def remeasure_on_lost_data(self, once: Callable[[], T]) -> T:
        """Run a whole measurement; when the buffer turned out empty (ER20, e.g. after a power
        blip between measuring and reading) measure again, up to `attempts` times."""
        for attempt in range(1, self.attempts + 1):
            try:
                return once()
            except DeviceError as exc:
                if exc.code != "ER20" or attempt == self.attempts:
                    raise
        raise AssertionError("unreachable")

    def _resync(self) -> None:
        """After a lost or garbled reply: let stray bytes arrive, then drop them."""
        try:
            self.port.timeout = 0.2
            self.port.read(65536)
            self.port.reset_input_buffer()
        except (SerialException, OSError):
            pass

    # --- abort ----------------------------------------------------------------------------------
    def request_abort(self) -> bool:
        """Flag an abort for the thread inside measure(); True if one was running."""
        if self._measuring:
            self._abort.set()
            return True
        return False

    def _aborted(self) -> OperatorAbort:
        self._abort.clear()
        return OperatorAbort(f"{self.instrument_id}: measurement aborted")

    # --- shared parsing ---------------------------------------------------------------------------
    def parse_number(self, text: str, raw: bytes) -> float:
        try:
            value = float(text)
        except ValueError:
            raise self._protocol(f"not a number: {text!r}", raw) from None
        if not math.isfinite(value):
            raise self._protocol(f"not a finite number: {text!r}", raw)
        return value


def undefined_to_nan(value: float) -> float:
    return math.nan if any(math.isclose(value, s, rel_tol=1e-6) for s in SENTINELS) else value


def colorimetry_from(values: list[float]) -> Colorimetry:
    """The 11-value block Le, Lv, X, Y, Z, x, y, u′, v′, T, Δuv → `Colorimetry`."""
    v = [undefined_to_nan(x) for x in values]
    return Colorimetry(Le_W_sr_m2=v[0], Lv_cd_m2=v[1], X=v[2], Y=v[3], Z=v[4], x=v[5], y=v[6],
                       u_prime=v[7], v_prime=v[8], cct_K=v[9], duv=v[10])


def check_spectrum(values: list[float], raw: bytes, instrument_id: str) -> np.ndarray:
    arr = np.asarray(values, dtype=np.float64)
    if arr.shape != (401,):
        raise ProtocolError(f"spectrum has {arr.size} values, expected 401", raw=raw,
                            instrument=instrument_id)
    if not np.all(np.isfinite(arr)):
        raise ProtocolError("spectrum holds non-finite values", raw=raw, instrument=instrument_id)
    undefined = np.isclose(arr[:, None], np.asarray(SENTINELS)[None, :], rtol=1e-6).any(axis=1)
    return np.where(undefined, np.nan, arr)
