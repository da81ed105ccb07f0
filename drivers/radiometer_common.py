"""What the CS-1000A and CS-2000A drivers share: line I/O with deadlines, link-loss
recovery, resynchronisation after a lost reply, number parsing, the colorimetric block, the
abort handshake, plausibility checks of what the wire delivered, and (`KonicaMinoltaRadiometer`)
the reply grammar, command retries and the measure skeleton of both models.

Every read has a deadline on the injected clock, so nothing hangs: a reply that does not
complete in time is an `InstrumentTimeout` (nothing came) or a `ProtocolError` (a line began
but never ended — a truncated reply).  Long waits are read in slices of `poll_s` so that
`abort()` from another thread is noticed; only the thread running `measure()` touches the port.

Recovery (bounded): before each command stale input is flushed; a lost link (the port raises
`SerialException`/`OSError`) is waited for up to `reconnect_timeout_s`, the port reopened, and
remote mode entered again before the command is repeated.

Late replies and garbled transfers: neither model numbers its replies nor checks its bytes, so
a reply that arrives after its deadline would be taken as the answer to a later command, and a
flipped bit in a data line is a plausible wrong number.  So:
  - a reply later than its timeout is waited for up to `late_window_s` more (nothing else
    has been sent, so it can only answer this command; it counts as a line fault); when
    even that passes, the line is drained for as long again (the late reply is dropped when
    it comes) before the command is repeated;
  - a reply given up on may come later still: until the sync query has been answered after
    it, the line is unsettled and the next command is preceded by a resynchronisation; and
    a sync query's own reply (a shape no other command gives) is dropped wherever it comes
    while another command is outstanding — a sync query given up on leaves one on its way;
  - every data block (a spectral or colorimetric line, a MEDR block) is read until two reads
    agree byte for byte (`agreed_blocks`): the instrument's buffer does not change between
    reads, a garbled or stray line does.  A reply that breaks the framing (an ``OK`` or
    ``ER`` where data belong, a cut-short line) aborts the pass, drains the line and starts a
    new one; after `block_reads` passes without agreement it is a `ProtocolError`;
  - the agreed transfer is then checked for plausibility: value counts, the range for the
    instrument, no isolated band far off its neighbours, and the instrument's own colorimetry
    (Lv, x, y) equal to what the spectrum gives (CIE 1931 2° from colour-science).  An
    implausible transfer is read again; one that stays implausible raises `ImplausibleData` —
    never a silently wrong reading.
The extra lab time per reading (the second read of every block) is in docs/radiometers.md.
"""

from __future__ import annotations

import functools
import math
import threading
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, TypeVar

import numpy as np
from serial import SerialException

from normbox_lab.core import transport
from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import (
    DeviceError,
    ImplausibleData,
    InstrumentError,
    InstrumentTimeout,
    OperatorAbort,
    ProtocolError,
)
from normbox_lab.core.spectral import RADIOMETER_WAVELENGTHS_NM
from normbox_lab.core.types import Colorimetry, SpectralReading

T = TypeVar("T")

COLORIMETRY_FIELDS = ("Le", "Lv", "X", "Y", "Z", "x", "y", "u′", "v′", "T", "Δuv")
#: values the instruments print for "calculation error / undefined" (CS-2000 spec §4.2)
SENTINELS = (-9.9999e9, -9.9e9, -9.999, -9999.0, -9.9999, -9.999999e10)
#: reads of every data block when the line is clean (`agreed_blocks`: two must agree)
TRANSFER_READS = 2


class LinkLost(InstrumentError):
    """The port went away (USB unplugged, power blip); internal: triggers reconnection."""


class SerialRadiometer:
    """Line I/O on a pyserial-like port for Konica Minolta radiometers."""

    model = ""
    terminator = b"\n"
    #: seconds per read slice while waiting long (abort is checked between slices)
    poll_s = 1.0
    #: after a lost or garbled reply: the line counts as drained after this long without a byte
    resync_quiet_s = 0.5
    #: ... and the drain stops after this long even if bytes keep coming
    resync_max_s = 5.0
    #: a reply later than its timeout is still waited for this long (None: the command
    #: timeout); after that the line is drained for as long again before the command is
    #: repeated
    late_window_s: float | None = None
    #: passes over a data transfer before disagreeing reads are a ProtocolError
    block_reads = 10
    #: a query whose reply no other command gives (`is_sync_reply`): sent after a timeout to
    #: find where the line stands
    sync_command = b""
    #: sync replies dropped while waiting for one reply before it is a ProtocolError
    max_stray_replies = 8

    def __init__(self, port: transport.Port, clock: Clock, *,
                 instrument_id: str = "radiometer", command_timeout_s: float = 10.0, attempts: int = 3,
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
        #: line faults seen (timeouts, garbled replies, lost links) since opening
        self.line_faults = 0
        #: the command last written (its reply is the one outstanding)
        self._outstanding = b""
        #: a reply was given up on and the sync query has not been answered since: the reply
        #: may still come, so the next command first resynchronises
        self._unsettled = False

    # --- errors -------------------------------------------------------------------------------
    def _protocol(self, msg: str, raw: bytes) -> ProtocolError:
        return ProtocolError(msg, raw=raw, instrument=self.instrument_id)

    def _timeout(self, msg: str) -> InstrumentTimeout:
        return InstrumentTimeout(msg, instrument=self.instrument_id)

    # --- bytes ----------------------------------------------------------------------------------
    def _write(self, cmd: bytes) -> None:
        if self._unsettled and self.sync_command and cmd != self.sync_command:
            # a reply given up on may still be on its way: find where the line stands first
            # (once: an instrument that answers not even the sync query is left to the
            # command's own timeout)
            self._resync(late=True)
            self._unsettled = False
        try:
            self.port.reset_input_buffer()
            self.port.write(cmd + self.terminator)
        except (SerialException, OSError) as exc:
            raise LinkLost(f"write failed: {exc}", instrument=self.instrument_id) from exc
        self._outstanding = cmd

    def _read_exact(self, n: int, timeout_s: float) -> bytes:
        deadline = self.clock.now_s() + timeout_s
        buf = bytearray()
        while len(buf) < n:
            remaining = deadline - self.clock.now_s()
            if remaining <= 1e-9:           # (a float residue would never elapse)
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
            if remaining <= 1e-9:           # (a float residue would never elapse)
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
        reply = self.read_reply(self.command_timeout_s if timeout_s is None else timeout_s)
        assert reply is not None
        self.history = (self.history + [(cmd, reply)])[-50:]
        return reply

    def read_reply(self, timeout_s: float, *, watch_abort: bool = False) -> bytes | None:
        """The reply to the one command outstanding.  One that has not begun within
        `timeout_s` is waited for up to `late_window_s` more (a line fault): nothing else has
        been sent, so a line that comes now can only answer this command.  A sync query's
        reply while another command is outstanding answers a sync query given up on: it is
        dropped (a line fault) and the reply waited for anew.  None when `watch_abort` and
        abort() was requested before the line began."""
        line: bytes | None = b""
        for _ in range(self.max_stray_replies + 1):
            line = self._read_reply_once(timeout_s, watch_abort=watch_abort)
            if line is None or not self._stray_sync_reply(line):
                return line
            self._count_line_fault()
        raise self._protocol("only stray sync replies on the line", line or b"")

    def _read_reply_once(self, timeout_s: float, *, watch_abort: bool) -> bytes | None:
        try:
            return self._read_line(timeout_s, watch_abort=watch_abort)
        except InstrumentTimeout:
            self._count_line_fault()
            try:
                return self._read_line(self._late_window_s(), watch_abort=watch_abort)
            except InstrumentTimeout:
                self._unsettled = True          # the reply may still come
                raise self._timeout(f"no reply within {timeout_s + self._late_window_s():g} s"
                                    ) from None

    def _stray_sync_reply(self, raw: bytes) -> bool:
        """`raw` has the sync query's shape while another command is outstanding."""
        return bool(self.sync_command) and self._outstanding != self.sync_command \
            and self.is_sync_reply(raw)

    def _late_window_s(self) -> float:
        return self.command_timeout_s if self.late_window_s is None else self.late_window_s

    # --- recovery -------------------------------------------------------------------------------
    def _reconnect(self) -> None:
        """Wait for the link to come back (bounded), reopen the port, re-enter remote mode."""
        self._count_line_fault()
        self.remote = False

        def attempt() -> None:
            transport.reopen(self.port)
            self.port.reset_input_buffer()
            self._enter_remote()

        transport.recover_link(
            self.clock, self.reconnect_timeout_s, attempt,
            retry_on=(LinkLost, InstrumentTimeout, ProtocolError, SerialException, OSError),
            instrument_id=self.instrument_id, error=InstrumentTimeout,
            first_wait_s=1.0, interval_s=1.0)

    def _enter_remote(self) -> None:  # pragma: no cover - per model
        raise NotImplementedError

    def with_retries(self, action: Callable[[], T], *, retry_device: tuple[str, ...] = (),
                     busy_wait_s: float = 2.0) -> T:
        """Run `action` up to `attempts` times: transport faults are retried (after a
        reconnect when the link was lost, after a resynchronisation when a reply was late or
        made no sense), device errors whose code is in `retry_device` after `busy_wait_s`;
        everything else raises at once.  A timeout or a garbled reply after which the sync
        query found the line answering does not count against `attempts` (at most `attempts`
        such faults are spared)."""
        last: InstrumentError | None = None
        attempt = spared = 0
        while attempt < self.attempts:
            attempt += 1
            try:
                return action()
            except LinkLost as exc:
                last = exc
                self._reconnect()
            except InstrumentTimeout as exc:
                last = exc
                if not self._resync(late=True):  # its reply may still come, late
                    raise                        # not even the sync query is answered
                if spared < self.attempts:       # the instrument answers: it was only late
                    spared += 1
                    attempt -= 1
            except ProtocolError as exc:
                last = exc
                # garbled, or a stray line (its own reply may follow): find the line
                if self._resync(late=True) and spared < self.attempts:
                    spared += 1
                    attempt -= 1
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

    def _count_line_fault(self) -> None:
        self.line_faults += 1

    def _resync(self, *, late: bool = False) -> bool:
        """After a lost or garbled reply: drain the line until it has been quiet for
        `resync_quiet_s` (at most `resync_max_s`).  `late`: a reply did not come in time and
        may still be on its way: send the model's sync query and read until its reply comes
        (the line is first in, first out, so whatever came before it answered earlier
        commands and is dropped).  True when the line is known to be in step; `late` and
        not in step leaves the line unsettled (the next command resynchronises first)."""
        self._count_line_fault()
        deadline_s = self.clock.now_s() + self.resync_max_s
        try:
            while self.clock.now_s() < deadline_s:
                self.port.timeout = self.resync_quiet_s
                if not self.port.read(65536):
                    break
            self.port.reset_input_buffer()
        except (SerialException, OSError):
            if late:
                self._unsettled = True
            return False
        if not (late and self.sync_command):
            return True
        in_step = self._sync()
        self._unsettled = not in_step
        return in_step

    def _sync(self) -> bool:
        """Send `sync_command` and read lines until one `is_sync_reply`, for at most the
        command timeout plus the late window; again (three queries at most) while lines come
        but not that one.  False when the instrument stays silent or out of step."""
        for _ in range(3):
            heard = False
            try:
                self._write(self.sync_command)
                deadline_s = self.clock.now_s() + self.command_timeout_s + self._late_window_s()
                while (remaining_s := deadline_s - self.clock.now_s()) > 1e-9:
                    line = self._read_line(remaining_s) or b""
                    heard = True
                    if self.is_sync_reply(line):
                        return True
            except ProtocolError:
                heard = True
            except InstrumentTimeout:
                pass
            except LinkLost:
                return False
            if not heard:
                return False
        return False

    def is_sync_reply(self, raw: bytes) -> bool:  # pragma: no cover - per model
        raise NotImplementedError

    def _guarded(self, action: Callable[[], None], busy_wait_s: float = 2.0) -> bool:
        """One pass of a data transfer: transport faults end the pass and make the line good
        again (reconnect; drain, waiting up to `late_window_s` for a reply still in flight);
        ER02 waits; ER00 (a power blip left the instrument in local mode) re-enters remote
        mode.  Other device errors (ER20: the buffer is gone) raise.  True when the line was
        drained."""
        try:
            action()
        except LinkLost:
            self._reconnect()
        except (InstrumentTimeout, ProtocolError):
            self._resync(late=True)
        except DeviceError as exc:
            if exc.code not in ("ER00", "ER02"):
                raise
            self.clock.sleep(busy_wait_s)
            if exc.code == "ER00":
                try:
                    self._enter_remote()
                except (InstrumentError, SerialException, OSError):
                    self._resync(late=True)
            return False
        else:
            return False
        return True

    def agreed_blocks(self, what: str, n_blocks: int,
                      read_pass: Callable[[list[int], Callable[[int, Any, bytes], None]], None],
                      ) -> list[tuple[Any, bytes]]:
        """(value, raw) of `n_blocks` data blocks, each read until two reads gave the same
        bytes.

        ``read_pass(pending, got)`` reads (at least) the blocks in `pending` and calls
        ``got(i, value, raw)`` for each block it read whole; a block whose content did not
        parse is simply not reported.  At most `block_reads` passes; then `ProtocolError`."""
        seen: list[dict[bytes, Any]] = [{} for _ in range(n_blocks)]
        agreed: list[tuple[Any, bytes] | None] = [None] * n_blocks
        disagreed = False

        def got(i: int, value: Any, raw: bytes) -> None:
            nonlocal disagreed
            if agreed[i] is None:
                if raw in seen[i]:
                    agreed[i] = (seen[i][raw], raw)
                else:
                    disagreed = disagreed or bool(seen[i])
                    seen[i][raw] = value

        unsettled = False
        for _ in range(self.block_reads):
            pending = [i for i, a in enumerate(agreed) if a is None]
            if not pending:
                break
            if disagreed or unsettled:
                # a line was stray, or a reply came late: the reply it displaced may still
                # be on its way; let it come and go before the next pass
                self._resync(late=True)
                disagreed = False
            faults = self.line_faults
            drained = self._guarded(functools.partial(read_pass, pending, got))
            unsettled = self.line_faults != faults and not drained
        missing = [i for i, a in enumerate(agreed) if a is None]
        if missing:
            self._count_line_fault()
            raw = next((r for i in missing for r in seen[i]), b"")
            raise self._protocol(f"{what}: no two of {self.block_reads} reads of block "
                                 f"{missing[0] + 1} agree (garbled, late or stray replies on "
                                 "the line)", raw[:200])
        return [a for a in agreed if a is not None]

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

    def parse_int(self, text: str, raw: bytes, lo: int = 0, hi: int = 10**12) -> int:
        """A plain decimal integer in [lo, hi] (no sign, at most 12 digits)."""
        if not _plain_digits(text) or not lo <= int(text) <= hi:
            raise self._protocol(f"expected an integer in {lo}…{hi}: {text[:40]!r}", raw)
        return int(text)


def pre_measurement_s(luminance_cd_m2: float) -> float:
    """The timing model's pre-measurement (auto-exposure) time of both models, s (assumed, as
    the emulators': docs/radiometers.md)."""
    return min(10.0, max(1.0, 1.0 + 2.0 * math.log10(100.0 / max(luminance_cd_m2, 1e-6))))


def _plain_digits(text: str) -> bool:
    return text.isascii() and text.isdigit() and len(text) <= 12


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


# --- plausibility (the wire has no checksum) -------------------------------------------------------

#: radiance above this (W·sr⁻¹·m⁻²·nm⁻¹) is beyond either model's range (CS-2000A: 5 000 000
#: cd/m² at 1° with the ND filter ≈ 30 W·sr⁻¹·m⁻²·nm⁻¹ for a flat white spectrum)
MAX_RADIANCE_W_SR_M2_NM = 100.0
#: an isolated band further than this fraction of the spectrum's peak from both neighbours'
#: mean is a corrupted value (the instruments' 5 nm bandwidth keeps 1 nm neighbours within a
#: few per cent of the peak even on the sharpest lamp line)
SPIKE_FRACTION_OF_PEAK = 0.2
#: a band further than this fraction of its own level (the larger of it and its neighbours)
#: from its neighbours' mean (or, at either end, from the line through the next two): the
#: instruments' 5 nm bandwidth makes a 1 nm step of more than a few per cent impossible, so
#: a lost digit (×0…0.5), a block of zeros or a byte lost on one band is no measurement
SPIKE_FRACTION_OF_LEVEL = 0.25
#: bands below this (W·sr⁻¹·m⁻²·nm⁻¹) are not judged relative to their level: the wire's
#: resolution (5 significant digits; values below 1e-9 are sent as 0)
SPIKE_FLOOR_W_SR_M2_NM = 1e-8
#: a stretch is "broad" where bands change by less than this (natural log per nm: 10 %)
BROAD_SLOPE = 0.1
#: a band at 0 beside one above this fraction of the peak, on a broad stretch, is a dropout
ZERO_EDGE_OF_PEAK = 1e-3
#: Lv reported vs 683·Σ L·ȳ of the reported spectrum (5 significant digits on the wire)
LV_RELATIVE_TOLERANCE = 0.02
LV_ABSOLUTE_TOLERANCE_CD_M2 = 1e-3
#: x, y reported vs the chromaticity of the reported spectrum (4 decimals on the wire; the
#: instrument integrates its internal, finer spectrum)
CHROMATICITY_TOLERANCE = 0.005
_CMFS: np.ndarray | None = None


def cmfs_1nm() -> np.ndarray:
    """(401, 3) CIE 1931 2° x̄ ȳ z̄ at 380–780 nm, 1 nm, from colour-science (lazy import)."""
    global _CMFS
    if _CMFS is None:
        import colour

        cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
        wl, values = np.asarray(cmfs.wavelengths, float), np.asarray(cmfs.values, float)
        _CMFS = np.stack([np.interp(RADIOMETER_WAVELENGTHS_NM, wl, values[:, i])
                          for i in range(3)], axis=1)
    return _CMFS


def ybar_1nm() -> np.ndarray:
    """CIE 1931 2° ȳ at 380–780 nm, 1 nm."""
    return cmfs_1nm()[:, 1]


def implausibility(spectrum: np.ndarray, luminance_cd_m2: float,
                   x_reported: float = math.nan, y_reported: float = math.nan) -> str:
    """Why this 380–780 nm radiance spectrum, with the Lv and x, y the instrument reported
    with it, cannot be a measurement, or "" when it can."""
    finite = spectrum[np.isfinite(spectrum)]
    if finite.size < spectrum.size // 2:
        return "more than half of the spectrum is undefined"
    peak = float(np.max(np.abs(finite))) if finite.size else 0.0
    if peak > MAX_RADIANCE_W_SR_M2_NM:
        return f"radiance {peak:.3g} W/sr/m²/nm is beyond the instrument's range"
    if float(np.min(finite)) < -0.05 * peak - 1e-6:
        return f"negative radiance {float(np.min(finite)):.3g} W/sr/m²/nm"
    x = np.nan_to_num(spectrum)
    deviation = np.abs(x[1:-1] - 0.5 * (x[:-2] + x[2:]))
    worst = int(np.argmax(deviation))
    if peak > 0 and deviation[worst] > SPIKE_FRACTION_OF_PEAK * peak:
        return (f"band {RADIOMETER_WAVELENGTHS_NM[worst + 1]:.0f} nm is "
                f"{x[worst + 1]:.4g}, its neighbours {x[worst]:.4g} and {x[worst + 2]:.4g}")
    step = _relative_step(x)
    if step:
        return step
    if math.isfinite(luminance_cd_m2):
        lv_spectrum = 683.0 * float(np.sum(x * ybar_1nm()))
        if abs(lv_spectrum - luminance_cd_m2) > max(
                LV_RELATIVE_TOLERANCE * abs(luminance_cd_m2), LV_ABSOLUTE_TOLERANCE_CD_M2):
            return (f"Lv {luminance_cd_m2:.5g} cd/m² disagrees with the spectrum's own "
                    f"{lv_spectrum:.5g} cd/m²")
    X, Y, Z = (x[:, None] * cmfs_1nm()).sum(axis=0)
    total = float(X + Y + Z)
    if total > 0 and math.isfinite(x_reported) and math.isfinite(y_reported):
        x_spectrum, y_spectrum = float(X) / total, float(Y) / total
        if max(abs(x_spectrum - x_reported), abs(y_spectrum - y_reported)) \
                > CHROMATICITY_TOLERANCE:
            return (f"x, y {x_reported:.4f}, {y_reported:.4f} disagree with the spectrum's "
                    f"own {x_spectrum:.4f}, {y_spectrum:.4f}")
    return ""


def _relative_step(x: np.ndarray) -> str:
    """Why a band of `x` (380–780 nm, 1 nm) cannot be a measurement on a 5 nm bandwidth, or ""
    when none is found.  Judged where the spectrum is locally broad: the two bands beyond each
    neighbour change by less than `BROAD_SLOPE` per nm (a lamp line's wings and the valley
    between two lines are not judged: their steep sides are real).  There a band further than
    `SPIKE_FRACTION_OF_LEVEL` of its level from its neighbours' mean (at either end: from the
    log-linear extension of the next two), or a 0 beside a band above `ZERO_EDGE_OF_PEAK` of
    the peak, is no measurement: a lost digit, a lost byte, a block of zeros."""
    n = x.size
    if n < 5:
        return ""
    peak = float(np.max(np.abs(x)))
    floor = max(SPIKE_FLOOR_W_SR_M2_NM, 1e-6 * peak)
    with np.errstate(divide="ignore", invalid="ignore"):
        logs = np.where(x > floor, np.log(np.maximum(x, floor)), np.nan)
        steady = np.abs(np.diff(logs)) < BROAD_SLOPE      # steady[j]: bands j, j+1 smooth
    steady = np.nan_to_num(steady.astype(float), nan=0.0).astype(bool)
    expected = np.full(n, np.nan)
    judged = np.zeros(n, dtype=bool)
    i = np.arange(2, n - 2)
    expected[i] = 0.5 * (x[i - 1] + x[i + 1])
    judged[i] = steady[i - 2] & steady[i + 1]
    for end, a, b, outer in ((0, 1, 2, 2), (1, 2, 3, 3), (n - 1, n - 2, n - 3, n - 4),
                             (n - 2, n - 3, n - 4, n - 5)):
        if x[a] > floor and x[b] > floor:                  # one side: log-linear extension
            expected[end] = x[a] * x[a] / x[b]
            judged[end] = bool(steady[min(a, b)]) and bool(steady[min(b, outer)])
    level = np.maximum(np.abs(x), np.abs(np.nan_to_num(expected)))
    off = judged & (level > floor) & (np.abs(x - np.nan_to_num(expected)) >
                                      SPIKE_FRACTION_OF_LEVEL * level)
    # a zero (or less) beside a band well above the wire's resolution, on a broad stretch
    edge = np.zeros(n, dtype=bool)
    big = x > max(ZERO_EDGE_OF_PEAK * peak, SPIKE_FLOOR_W_SR_M2_NM)
    edge[:-2] |= (x[:-2] <= 0) & big[1:-1] & steady[1:]
    edge[2:] |= (x[2:] <= 0) & big[1:-1] & steady[:-1]
    bad = np.flatnonzero(off | edge)
    if not bad.size:
        return ""
    k = int(bad[0])
    ref = expected[k] if np.isfinite(expected[k]) else (x[k - 1] if k else x[k + 1])
    return (f"band {RADIOMETER_WAVELENGTHS_NM[k]:.0f} nm is {x[k]:.4g} where its neighbours "
            f"give {ref:.4g}: not a 5 nm bandwidth")


@dataclass
class Transfer:
    """What one data transfer delivered: the spectrum, the 11-value colorimetric block and
    model-specific extras; `raw` keeps the bytes for error messages."""

    spectrum: np.ndarray
    colorimetry_values: list[float]
    extra: dict[str, Any] = field(default_factory=dict)
    raw: bytes = b""


class KonicaMinoltaRadiometer(SerialRadiometer):
    """The reply grammar, command retries, remote mode, abort and the measure skeleton that
    the CS-1000A and the CS-2000A share.  A model supplies `ok_head`, `errors`,
    `remote_prefix`, `cancel_command`, `_enter_remote`, `_run_measurement` (the trigger, returns
    what the reading needs from it), `_read_data` (one whole transfer, no retries) and
    `_reading` (trigger + transfer → `SpectralReading`)."""

    ok_head = "OK"
    errors: ClassVar[dict[str, str]] = {}
    remote_prefix = "RMT,"
    cancel_command = "MES,0"

    # --- replies --------------------------------------------------------------------------------
    def parse_reply(self, raw: bytes) -> list[str]:
        """``<ok_head>[,f1,…]`` → [f1, …]; ``ERnn`` → `DeviceError`; else `ProtocolError`."""
        try:
            text = raw.decode("ascii")
        except UnicodeDecodeError:
            raise self._protocol("reply is not ASCII", raw) from None
        head, *fields = text.split(",")
        if head == self.ok_head:
            return fields
        if len(head) == 4 and head.startswith("ER") and head[2:].isdigit() and not fields:
            raise DeviceError(head, self.errors.get(head, "unknown error code"),
                              instrument=self.instrument_id)
        raise self._protocol("unexpected reply", raw)

    def _no_fields(self, cmd: str, fields: list[str]) -> None:
        if fields:
            raise self._protocol(f"{cmd}: unexpected fields after {self.ok_head}",
                                 ",".join([self.ok_head, *fields]).encode())

    def command(self, cmd: str, timeout_s: float | None = None,
                parse: Callable[[list[str]], Any] | None = None) -> Any:
        """Send `cmd`, return the fields after the OK head (or `parse(fields)`, which raises
        `ProtocolError` for fields that make no sense: such a reply is asked again, like a
        garbled one).  Transport faults and ER02 (busy) are retried (bounded); ER00 to a
        command other than the remote command re-enters remote mode once (the instrument
        drops to local mode after a power blip) and repeats."""
        def once() -> Any:
            fields = self.parse_reply(self.exchange(cmd.encode("ascii"), timeout_s))
            return fields if parse is None else parse(fields)

        try:
            return self.with_retries(once, retry_device=("ER02",))
        except DeviceError as exc:
            if exc.code != "ER00" or cmd.startswith(self.remote_prefix):
                raise
            self._enter_remote()
            return self.with_retries(once, retry_device=("ER02",))

    # --- remote mode, abort, recovery, close -----------------------------------------------------
    def set_remote(self, on: bool) -> None:  # pragma: no cover - per model
        raise NotImplementedError

    def _ensure_remote(self) -> None:
        if not self.remote:
            self.set_remote(True)

    def abort(self) -> None:
        """Cancel a running measurement (from any thread); idle → cancel anyway (harmless)."""
        if self.request_abort():
            return
        with self._lock:
            try:
                self.command(self.cancel_command)
            except DeviceError:
                pass                              # nothing was running

    def _cancel_quietly(self) -> None:
        try:
            self._resync()
            self.exchange(self.cancel_command.encode("ascii"), timeout_s=3.0)
        except (InstrumentError, SerialException, OSError):
            pass
        self._resync()

    def recover(self) -> None:
        """Engine hook after a fault: drain, cancel whatever runs, re-enter remote mode."""
        with self._lock:
            self._cancel_quietly()
            self.remote = False
            self.set_remote(True)

    def close(self) -> None:
        try:
            if self.remote:
                self.set_remote(False)
        except InstrumentError:
            pass
        finally:
            try:
                self.port.close()
            except (SerialException, OSError):
                pass

    # --- measuring ---------------------------------------------------------------------------------
    def measure(self) -> SpectralReading:
        """Trigger, then transfer the data.  Transport faults are retried (bounded); a lost
        buffer (ER20) measures again; after a line fault the data are read until two
        consecutive transfers agree; an implausible transfer is read again, then refused."""
        with self._lock:
            self._measuring = True
            self._abort.clear()
            try:
                self._ensure_remote()
                return self.remeasure_on_lost_data(self._measure_once)
            finally:
                self._measuring = False

    def _measure_once(self) -> SpectralReading:
        trigger = self.with_retries(self._run_measurement, retry_device=("ER02",))
        return self._reading(trigger, self._checked_transfer())

    def _checked_transfer(self) -> Transfer:
        """The agreed transfer (`_read_data`), read again while it is implausible (bounded by
        `attempts`), then refused with `ImplausibleData`."""
        why = ""
        data: Transfer | None = None
        for _ in range(self.attempts):
            data = self._read_data()
            why = implausibility(data.spectrum, undefined_to_nan(data.colorimetry_values[1]),
                                 undefined_to_nan(data.colorimetry_values[5]),
                                 undefined_to_nan(data.colorimetry_values[6]))
            if not why:
                return data
            self._count_line_fault()
        assert data is not None
        raise ImplausibleData(f"implausible data: {why}", raw=data.raw[:200],
                              instrument=self.instrument_id)

    def _run_measurement(self) -> Any:  # pragma: no cover - per model
        raise NotImplementedError

    def _read_data(self) -> Transfer:  # pragma: no cover - per model
        raise NotImplementedError

    def _reading(self, trigger: Any, data: Transfer) -> SpectralReading:  # pragma: no cover
        raise NotImplementedError
