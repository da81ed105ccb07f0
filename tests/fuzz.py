"""Seeded byte mutation and a one-shot fake port for parser fuzzing (tests/instruments/test_fuzz.py).

`mutate(rng, data)` applies one to three of: bit flips, deletions, insertions of random or
"interesting" bytes (separators, signs, exponents, NaN/inf spellings, non-ASCII), duplicated
chunks, very long digit runs, truncation, swapped fields, blanks inside a field that keep its
length (a hex value ``12 34 56`` still has 8 characters), or wholly random bytes.  The same
seed gives the same inputs, so a failure reproduces.

`ReplyPort` answers each write with the next queued reply (then nothing), so a parser is
driven through the driver's real read path; waits move the virtual clock.
"""

from __future__ import annotations

import random

from normbox_lab.core.clock import VirtualClock

INTERESTING = [b",", b"-", b"+", b"e", b"E", b".", b" ", b"\r", b"\n", b"\x00", b"\xff",
               b"\xc3\xa9", b"nan", b"inf", b"-inf", b"1e999", b"-9.9999e9", b"0x1F", b"OK",
               b"OK00", b"ER", b"ER99", b"#", b"@", b"/", b"\t", b"9" * 40, b"_", b"\xe2\x80\x8b"]


def mutate(rng: random.Random, data: bytes) -> bytes:
    buf = bytearray(data)
    for _ in range(rng.randint(1, 3)):
        op = rng.randrange(11)
        i = rng.randrange(len(buf) + 1)
        if op == 0 and buf:                                   # bit flip
            j = min(i, len(buf) - 1)
            buf[j] ^= 1 << rng.randrange(8)
        elif op == 1 and buf:                                 # delete a range
            del buf[i:i + rng.randint(1, 8)]
        elif op == 2:                                         # insert random bytes
            buf[i:i] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 6)))
        elif op == 3:                                         # insert an interesting token
            buf[i:i] = rng.choice(INTERESTING)
        elif op == 4 and buf:                                 # duplicate a chunk
            j = rng.randrange(len(buf))
            buf[i:i] = buf[j:j + rng.randint(1, 40)]
        elif op == 5:                                         # a very long digit run
            buf[i:i] = b"7" * rng.choice((310, 5000, 20000))
        elif op == 6:                                         # truncate
            del buf[i:]
        elif op == 7 and b"," in buf:                         # swap two fields
            parts = bytes(buf).split(b",")
            a, b = rng.randrange(len(parts)), rng.randrange(len(parts))
            parts[a], parts[b] = parts[b], parts[a]
            buf = bytearray(b",".join(parts))
        elif op == 8:                                         # replace a byte by a token
            if buf:
                j = min(i, len(buf) - 1)
                buf[j:j + 1] = rng.choice(INTERESTING)
        elif op == 9 and b"," in buf:                         # blanks inside a field,
            parts = bytes(buf).split(b",")                    # its length kept ("12 34 56")
            k = rng.randrange(len(parts))
            field = bytearray(parts[k])
            for _ in range(rng.randint(1, 3)):
                if field:
                    field[rng.randrange(len(field))] = rng.choice(b" \t\x0b\x0c")
            parts[k] = bytes(field)
            buf = bytearray(b",".join(parts))
        else:                                                 # random garbage
            buf = bytearray(rng.randrange(256) for _ in range(rng.randint(0, 60)))
    return bytes(buf)


class ReplyPort:
    """pyserial-like: each write makes the next queued reply arrive; reads wait on the
    virtual clock (to the timeout) when nothing more will come."""

    def __init__(self, replies: list[bytes], clock: VirtualClock | None = None) -> None:
        self.replies = list(replies)
        self.clock = clock if clock is not None else VirtualClock()
        self.timeout: float | None = 1.0
        self.rx = bytearray()
        self.is_open = True
        self.port = "fuzz://"

    def write(self, data: bytes) -> int:
        if self.replies:
            self.rx += self.replies.pop(0)
        return len(data)

    def feed(self, data: bytes) -> None:
        self.rx += data

    def _take(self, n: int) -> bytes:
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out

    def read_until(self, expected: bytes = b"\n", size: int | None = None) -> bytes:
        i = self.rx.find(expected)
        if i >= 0:
            return self._take(i + len(expected))
        self.clock.sleep(self.timeout or 0.05)
        return self._take(len(self.rx))

    def read(self, size: int = 1) -> bytes:
        if len(self.rx) < size:
            self.clock.sleep(self.timeout or 0.05)
        return self._take(min(size, len(self.rx)))

    @property
    def in_waiting(self) -> int:
        return len(self.rx)

    def reset_input_buffer(self) -> None:
        self.rx.clear()

    def close(self) -> None:
        self.is_open = False

    def open(self) -> None:
        self.is_open = True
