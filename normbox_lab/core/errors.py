"""The one error hierarchy of normbox-lab (DESIGN §4).

    NormboxError
    ├── InstrumentError
    │   ├── InstrumentTimeout   no (complete) reply in time
    │   ├── ProtocolError       bytes that make no sense; carries the raw bytes
    │   │   └── ImplausibleData well-formed bytes whose values cannot be a measurement
    │   ├── DeviceError         the device said no; carries its code and meaning
    │   └── NotReady            the device cannot do this now (not homed, lamp warming, ...)
    ├── ConfigError             a lab config problem; names file, line and field
    ├── DataError               an imported data file is malformed; names file and location
    ├── StoreError              the measurement store cannot do what was asked
    │   ├── UnknownRun          a run reference names no run, or several (exit 2)
    │   └── BadPath             a store or output path that cannot be one (exit 2)
    ├── PlanError               a protocol's plan cannot be built (acquire.steps)
    │   └── ParameterError      a value outside its kind or limits (acquire.params; exit 2)
    └── OperatorAbort           the operator (or an abort request) stopped the run
"""

from __future__ import annotations


def one_line(text: str) -> str:
    """`text` as one printable line: line breaks, terminal escapes, other control and
    invisible characters (and lone surrogates of undecodable bytes) written as escapes, so a
    path or a name a person typed cannot break the one line of a refusal or drive the
    terminal."""
    return "".join(ch if ch == " " or ch.isprintable() else repr(ch)[1:-1] for ch in text)


class NormboxError(Exception):
    """Base of every error normbox-lab raises on purpose."""

    #: the command line's exit status for it (2: a bad value on the command line)
    exit_code: int = 1


class InstrumentError(NormboxError):
    """Something went wrong talking to, or inside, an instrument."""

    def __init__(self, message: str, *, instrument: str = "") -> None:
        self.instrument = instrument
        super().__init__(f"{instrument}: {message}" if instrument else message)


class InstrumentTimeout(InstrumentError):
    """The instrument did not answer (completely) within the allowed time."""


class ProtocolError(InstrumentError):
    """The instrument's bytes make no sense for the command sent."""

    def __init__(self, message: str, *, raw: bytes = b"", instrument: str = "") -> None:
        self.raw = bytes(raw)
        super().__init__(f"{message} (raw={self.raw!r})", instrument=instrument)


class ImplausibleData(ProtocolError):
    """Well-formed data that cannot be a measurement (out of range, an isolated band far off
    its neighbours, Lv inconsistent with the spectrum): corrupted on a wire without checksum."""


class DeviceError(InstrumentError):
    """The device refused or failed a command and said why."""

    def __init__(self, code: str | int, meaning: str, *, instrument: str = "") -> None:
        self.code = code
        self.meaning = meaning
        super().__init__(f"device error {code}: {meaning}", instrument=instrument)


class NotReady(InstrumentError):
    """The device is not in a state where the request can be carried out."""


class ConfigError(NormboxError):
    """A lab config error; always names the file, the line (0 when unknown) and the field.
    A refusal of what a person wrote: the command line exits 2."""

    exit_code = 2

    def __init__(self, file: str, line: int, field: str, message: str) -> None:
        self.file = str(file)
        self.line = int(line)
        self.field = field
        super().__init__(f"{self.file}:{self.line}: {field}: {message}")


class DataError(NormboxError):
    """An input data file is malformed; names the file and where in it."""

    def __init__(self, file: str, location: str, message: str) -> None:
        self.file = str(file)
        self.location = location
        self.message = message
        super().__init__(f"{self.file}: {location}: {message}")


class BadInputFile(DataError):
    """A file a person named for import that is not what the command reads (malformed, of
    another kind): a refusal of what was given, exit 2 (as `import prediction`'s file)."""

    exit_code = 2


class StoreError(NormboxError):
    """The store refused an operation (unknown run, duplicate key, newer schema...)."""


class UnknownRun(StoreError):
    """A run reference (id or uuid prefix) that names no run of the store, or more than one: a
    refusal of what a person typed, so the command line exits 2 (1 stays for what a command
    found, such as `qa`'s error flags)."""

    exit_code = 2


class BadPath(StoreError):
    """A path a person gave for the store, an input or an output that cannot be one (a
    directory, not a regular file, not a store, a name the system refuses): a refusal of what
    was typed, exit 2."""

    exit_code = 2


class OperatorAbort(NormboxError):
    """The operator aborted (or an abort was requested programmatically)."""


class PlanError(NormboxError):
    """A protocol declared an inconsistent plan (duplicate keys, unsatisfiable requirements,
    or a step an instrument has no capability for).  Here (not in `acquire.steps`) so that the
    parameter parser (`acquire.params`) stays importable without numpy for the command line.
    A plan is built from what a person gave (the protocol's name or file, its parameters, the
    lab config), before anything moves: a refusal of user input, so the command line exits 2."""

    exit_code = 2


class RenderError(NormboxError):
    """A renderer met a value that is not a number (NaN or ±inf) in a lane's radiance, or
    could not render at all.  The estimate is never returned: a NaN averaged into a spectrum
    would be stored as data.  Names the renderer and where (configuration, lanes, bands)."""
