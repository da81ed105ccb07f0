"""`ScriptedPort`: a pyserial-like fake port for wire-level driver tests.

Import it as ``from wire import Exchange, ScriptedPort`` (pytest puts tests/ on sys.path, as
for ``engine_fakes``).  Pass it to a driver's constructor in place of a serial port.

The script is a list of exchanges: the exact bytes the driver must write, and the bytes the
"instrument" answers (after an optional delay on the test's clock).  A write that differs from
the script fails the test at once with both byte strings.  Every expected exchange must have
happened, as in pymeasure's ``expected_protocol``: a ``with ScriptedPort(...) as port:`` block
checks it when it ends, and every port a test made is checked when the test ends (the
autouse fixture in conftest.py calls `assert_done()`), so no test can forget it.  A test that
stops a driver half-way on purpose says so with `leave_unfinished()`.

    with ScriptedPort([
        Exchange(b"RMT,1\\n", b"OK\\n"),
        Exchange(b"MES,1\\n", [(1.5, b"OK,2.00\\n"), (4.0, b"OK\\n")]),  # two timed replies
        Exchange(b"MES,1\\n", raises=SerialException("unplugged")),      # the write fails
    ], clock=VirtualClock()) as port:
        ...

Reads behave like pyserial with `timeout`: they return what has arrived by then; on a
`VirtualClock` the wait moves the clock (to the next reply or to the timeout), so tests never
sleep.  `reset_input_buffer()` drops only bytes that have already arrived.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Self

from normbox_lab.core.clock import VirtualClock

Reply = bytes | list[tuple[float, bytes]]

#: the ports made since the current test began (conftest checks each when the test ends)
LIVE: list[ScriptedPort] = []


@dataclass
class Exchange:
    expect: bytes
    reply: Reply = b""
    raises: BaseException | None = None
    delay_s: float = 0.0          # for a plain-bytes reply


@dataclass
class ScriptedPort:
    script: list[Exchange]
    clock: VirtualClock = field(default_factory=VirtualClock)
    timeout: float | None = 1.0
    port: str = "scripted://"
    is_open: bool = True
    written: list[bytes] = field(default_factory=list)

    def __post_init__(self) -> None:
        self._pending: list[tuple[float, bytes]] = []    # (due_s, bytes), sorted by due
        self._rx = bytearray()
        self._partial = bytearray()
        self._step = 0
        self.unfinished_ok = False
        LIVE.append(self)

    def __enter__(self) -> Self:
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        if exc_type is None:          # (an exception from the block is the failure to show)
            self.assert_done()

    def leave_unfinished(self) -> Self:
        """This test stops before the script's end on purpose (a fault, an abort): the end-of-
        test check is waived for this port."""
        self.unfinished_ok = True
        return self

    # --- writing ------------------------------------------------------------------------------
    def write(self, data: bytes) -> int:
        if not self.is_open:
            raise AssertionError("write on a closed port")
        self._partial += bytes(data)
        while self._partial:
            if self._step >= len(self.script):
                raise AssertionError(f"unexpected write {bytes(self._partial)!r}: script done")
            ex = self.script[self._step]
            if len(self._partial) < len(ex.expect):
                if not ex.expect.startswith(bytes(self._partial)):
                    raise AssertionError(f"wrote {bytes(self._partial)!r}, "
                                         f"expected {ex.expect!r} (step {self._step})")
                return len(data)
            got = bytes(self._partial[:len(ex.expect)])
            if got != ex.expect:
                raise AssertionError(f"wrote {got!r}, expected {ex.expect!r} (step {self._step})")
            del self._partial[:len(ex.expect)]
            self._step += 1
            self.written.append(got)
            if ex.raises is not None:
                raise ex.raises
            now = self.clock.now_s()
            replies = [(ex.delay_s, ex.reply)] if isinstance(ex.reply, bytes) else ex.reply
            for delay_s, data_out in replies:
                if data_out:
                    self._pending.append((now + delay_s, data_out))
            self._pending.sort(key=lambda p: p[0])
        return len(data)

    # --- reading ------------------------------------------------------------------------------
    def _arrive(self) -> None:
        now = self.clock.now_s()
        while self._pending and self._pending[0][0] <= now:
            self._rx += self._pending.pop(0)[1]

    @property
    def in_waiting(self) -> int:
        self._arrive()
        return len(self._rx)

    def _read(self, done, cut) -> bytes:
        deadline = None if self.timeout is None else self.clock.now_s() + self.timeout
        while True:
            self._arrive()
            if done(self._rx):
                break
            nxt = self._pending[0][0] if self._pending else None
            if nxt is None or (deadline is not None and nxt > deadline):
                if deadline is not None:
                    self.clock.sleep_until(deadline)
                break
            self.clock.sleep_until(nxt)
        n = cut(self._rx)
        out = bytes(self._rx[:n])
        del self._rx[:n]
        return out

    def read(self, size: int = 1) -> bytes:
        return self._read(lambda b: len(b) >= size, lambda b: min(size, len(b)))

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        def cut(b: bytearray) -> int:
            i = b.find(expected)
            n = i + len(expected) if i >= 0 else len(b)
            return min(n, size) if size is not None else n

        return self._read(lambda b: expected in b or (size is not None and len(b) >= size), cut)

    def readline(self) -> bytes:
        return self.read_until(b"\n")

    def reset_input_buffer(self) -> None:
        self._arrive()
        self._rx.clear()

    def reset_output_buffer(self) -> None: ...
    def flush(self) -> None: ...

    def close(self) -> None:
        self.is_open = False

    def open(self) -> None:
        self.is_open = True

    # --- checks -------------------------------------------------------------------------------
    @property
    def done(self) -> bool:
        return self._step >= len(self.script) and not self._partial

    def assert_done(self) -> None:
        left = [ex.expect for ex in self.script[self._step:]]
        assert not left, f"script not finished; still expected: {left!r}"
        assert not self._partial, f"partial write left: {bytes(self._partial)!r}"
