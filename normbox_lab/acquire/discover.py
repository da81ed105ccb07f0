"""Find the lab's instruments: `normbox-lab lab discover`.

    findings = discover(["socket://127.0.0.1:4001", "/dev/pts/7"], usb_backend="cseabreeze")
    print(format_table(findings))
    write_lab_config(findings, "lab.toml")

Candidates are the serial ports pyserial lists (`serial.tools.list_ports.comports`, with the
USB VID:PID and serial number of their adapter), the endpoints given (a device path, a pty,
``socket://host:port``, ``rfc2217://…``), and the USB spectrometers seabreeze lists.

Each serial candidate is asked only the identification exchanges the driver registry declares
(`registry.Identification`: the exact bytes, at the driver's baud rates), binary framings first,
with a short timeout.  The port is wrapped in `GuardedPort`, which refuses to write anything
that is not one of those declared exchanges, so a bug here cannot send a command that moves,
switches a lamp or measures.  A port that answers nobody's identification is ``unknown``; one
that is busy or not permitted says so in one line (``busy``, ``denied``: the dialout group).

The lab config written from the findings names each serial instrument by a stable key: the USB
serial number of its adapter through pyserial's ``hwgrep://`` URL (``/dev/ttyUSB0`` changes
between boots and plug orders; ``hwgrep://SER=FT4XYZ\\b`` does not), the QE Pro by its own
serial number (``usb:SERIAL``); a pty or TCP endpoint is kept as given.
"""

from __future__ import annotations

import errno
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from normbox_lab.acquire import registry
from normbox_lab.core.capabilities import InstrumentIdentity
from normbox_lab.core.errors import ConfigError, InstrumentError, NormboxError

#: seconds to wait for one identification reply (real instruments answer in milliseconds)
DEFAULT_TIMEOUT_S = 0.3
#: a drain ends after this long without a byte
QUIET_S = 0.05
#: a drain never reads more than this (a port that streams garbage)
DRAIN_MAX_BYTES = 4096

#: the soft limits a written config starts with, per role (the simulated lab's; check them)
ROLE_OPTIONS: dict[str, dict[str, Any]] = {
    "rotator": {"min_angle_deg": 0.0, "max_angle_deg": 95.0},
    "gonio_light_arm": {"min_angle_deg": -90.0, "max_angle_deg": 90.0},
    "gonio_detector_arm": {"min_angle_deg": -90.0, "max_angle_deg": 90.0},
}


@dataclass(frozen=True)
class Candidate:
    """A port to probe: `url` for pyserial, and what list_ports knows of its USB adapter."""

    url: str
    vid: int | None = None
    pid: int | None = None
    usb_serial: str = ""
    location: str = ""
    description: str = ""

    @property
    def usb_id(self) -> str:
        return "" if self.vid is None else f"{self.vid:04X}:{self.pid or 0:04X}"


@dataclass
class Finding:
    """What one candidate turned out to be."""

    port: str                          # where it was found
    status: str                        # found | unknown | silent | busy | denied | error
    driver: str = ""
    identity: InstrumentIdentity | None = None
    baud: int | None = None
    stable_port: str = ""              # what a lab config should name (see the module doc)
    note: str = ""
    candidate: Candidate | None = None
    options: dict[str, Any] = field(default_factory=dict)   # driver options the config needs

    @property
    def serial_number(self) -> str:
        return self.identity.serial_number if self.identity is not None else ""


class ProbeRefused(NormboxError):
    """Discover tried to write bytes no registered identification declares (a bug, caught)."""


class GuardedPort:
    """A serial port whose `write` accepts only the declared identification bytes."""

    def __init__(self, port: Any, allowed: Iterable[bytes]) -> None:
        self._port = port
        self._allowed = frozenset(allowed)

    def write(self, data: bytes) -> int | None:
        if bytes(data) not in self._allowed:
            raise ProbeRefused(f"refused to send {bytes(data)!r}: not a declared identification")
        return self._port.write(data)

    def read(self, size: int = 1) -> bytes:
        return bytes(self._port.read(size))

    def read_until(self, expected: bytes, size: int | None = None) -> bytes:
        return bytes(self._port.read_until(expected, size))

    def reset_input_buffer(self) -> None:
        self._port.reset_input_buffer()

    def close(self) -> None:
        self._port.close()


def allowed_bytes() -> frozenset[bytes]:
    """Every byte string any registered identification may send."""
    return frozenset(ex.send for e in registry.DRIVERS.values() if e.identification
                     for ex in e.identification.exchanges)


# --- candidates ----------------------------------------------------------------------------------

def serial_candidates() -> list[Candidate]:
    """The serial ports pyserial lists, with their USB adapter's VID:PID and serial number."""
    from serial.tools import list_ports

    out = []
    for info in sorted(list_ports.comports(), key=lambda i: i.device):
        out.append(Candidate(info.device, info.vid, info.pid, info.serial_number or "",
                             info.location or "", info.description or ""))
    return out


def _is_url(port: str) -> bool:
    return "://" in port


def port_problem(exc: BaseException, port: str) -> tuple[str, str]:
    """(status, one line) for a port that cannot be opened: busy, not permitted, missing."""
    code = getattr(exc, "errno", None)
    text = str(exc)
    if code in (errno.EACCES, errno.EPERM) or "Permission denied" in text:
        return "denied", (f"not permitted to open {port}: add your user to the dialout group "
                          "(sudo usermod -aG dialout $USER, then log out and in)")
    if code in (errno.EBUSY, errno.EAGAIN) or "exclusively lock" in text \
            or "Device or resource busy" in text:
        return "busy", (f"busy: another program holds {port} open (a terminal program, "
                        "ModemManager, another normbox-lab); close it and discover again")
    if code == errno.ENOENT or "No such file" in text:
        return "error", f"no such port {port}"
    if code == errno.ECONNREFUSED or "Connection refused" in text:
        return "error", f"nothing listens at {port}"
    return "error", f"cannot open {port}: {text.splitlines()[0] if text else type(exc).__name__}"


def _open(url: str, baud: int, rtscts: bool, timeout_s: float) -> Any:
    import serial

    kwargs: dict[str, Any] = {"baudrate": baud, "bytesize": 8, "parity": "N", "stopbits": 1,
                              "timeout": timeout_s, "write_timeout": max(timeout_s, 1.0)}
    if not _is_url(url):
        kwargs["exclusive"] = True        # a port another program holds is busy, not shared
        kwargs["rtscts"] = rtscts
    return serial.serial_for_url(url, **kwargs)


# --- probing --------------------------------------------------------------------------------------

def _drain(port: GuardedPort) -> bytes:
    got = bytearray()
    while len(got) < DRAIN_MAX_BYTES:
        chunk = port.read(256)
        if not chunk:
            break
        got += chunk
    return bytes(got)


def _exchange(port: GuardedPort, ex: registry.Exchange) -> bytes:
    port.write(ex.send)
    if ex.reply_end is None:
        return _drain(port)
    if isinstance(ex.reply_end, int):
        return port.read(ex.reply_end)
    raw = port.read_until(ex.reply_end, 4096)
    return raw.rstrip(b"\r\n") if raw.endswith(ex.reply_end) else raw


def _probe_order() -> list[str]:
    """Drivers with a serial identification, binary framings first, else registry order."""
    names = [n for n, e in registry.DRIVERS.items()
             if e.identification is not None and e.identification.exchanges]
    return sorted(names, key=lambda n: not registry.DRIVERS[n].identification.binary)  # type: ignore[union-attr]


def probe(candidate: Candidate, *, timeout_s: float = DEFAULT_TIMEOUT_S) -> Finding:
    """Ask `candidate` every registered identification until one recognises the replies."""
    heard = b""
    allowed = allowed_bytes()
    for name in _probe_order():
        ident = registry.DRIVERS[name].identification
        assert ident is not None
        # on a pty or a TCP endpoint the baud rate means nothing: one is enough
        bauds = ident.bauds[:1] if _is_url(candidate.url) or not ident.bauds else ident.bauds
        for baud in bauds or (9600,):
            try:
                raw = _open(candidate.url, baud, ident.rtscts, timeout_s)
            except (OSError, ValueError) as exc:      # SerialException is an OSError
                status, line = port_problem(exc, candidate.url)
                return Finding(candidate.url, status, note=line, candidate=candidate)
            port = GuardedPort(raw, allowed)
            try:
                raw.timeout = QUIET_S
                heard += _drain(port)                  # what was there before we spoke
                replies: list[bytes] = []
                for ex in ident.exchanges:
                    raw.timeout = QUIET_S if ex.reply_end is None else timeout_s
                    reply = _exchange(port, ex)
                    replies.append(reply)
                    heard += reply
                    if ex.reply_end is not None and (
                            not reply or (ex.expect and not reply.startswith(ex.expect))):
                        break
                identity = registry.identification_parser(name)(replies)
            except OSError as exc:                     # the link went away mid-probe
                status, line = port_problem(exc, candidate.url)
                return Finding(candidate.url, status, note=line, candidate=candidate)
            finally:
                port.close()
            if identity is not None:
                return Finding(candidate.url, "found", name, identity, baud,
                               candidate=candidate)
    if heard.strip():
        return Finding(candidate.url, "unknown", candidate=candidate,
                       note=f"answers, but to no registered identification "
                            f"(first bytes {heard[:24]!r})")
    return Finding(candidate.url, "silent", candidate=candidate, note="no reply")


def probe_usb(backend: str = "cseabreeze", pyusb_backend: str | None = None) -> list[Finding]:
    """The USB instruments of the registry (those with `usb` ids), through their driver."""
    out: list[Finding] = []
    for name, e in registry.DRIVERS.items():
        if e.identification is None or not e.identification.usb:
            continue
        try:
            found = registry.identification_parser(name)(backend, pyusb_backend)
        except InstrumentError as exc:
            out.append(Finding("usb", "error", driver=name, note=str(exc)))
            continue
        for target, identity in found:
            options: dict[str, Any] = {}
            used = identity.extra.get("seabreeze_backend", backend)
            if used != "cseabreeze":
                options["backend"] = used
            if pyusb_backend:
                options["pyusb_backend"] = pyusb_backend
            out.append(Finding(target, "found", name, identity, stable_port=target,
                               options=options))
    return out


def _stable_ports(findings: Sequence[Finding]) -> None:
    """Fill `stable_port`: ``hwgrep://SER=…`` for a USB adapter with a serial number (and its
    interface when several ports share one), else the port as found."""
    serials: dict[str, int] = {}
    for f in findings:
        if f.candidate is not None and f.candidate.usb_serial:
            serials[f.candidate.usb_serial] = serials.get(f.candidate.usb_serial, 0) + 1
    for f in findings:
        c = f.candidate
        if f.stable_port or c is None:
            continue
        if c.usb_serial and re.fullmatch(r"[A-Za-z0-9._-]+", c.usb_serial):
            key = f"SER={re.escape(c.usb_serial)}\\b"
            if serials[c.usb_serial] > 1 and ":" in c.location:
                key += f".*LOCATION=[^ ]*:{re.escape(c.location.rsplit(':', 1)[1])}\\b"
            f.stable_port = f"hwgrep://{key}"
        else:
            f.stable_port = c.url


def discover(endpoints: Sequence[str] = (), *, scan_serial: bool = True,
             usb: bool = True, usb_backend: str = "cseabreeze",
             pyusb_backend: str | None = None,
             timeout_s: float = DEFAULT_TIMEOUT_S) -> list[Finding]:
    """Probe the listed serial ports (when `scan_serial`), the `endpoints`, and USB."""
    candidates = serial_candidates() if scan_serial else []
    listed = {c.url for c in candidates}
    candidates += [Candidate(e) for e in endpoints if e not in listed]
    from concurrent.futures import ThreadPoolExecutor

    # ports are independent: probe them side by side (each port's probes stay in order)
    with ThreadPoolExecutor(max_workers=min(8, max(1, len(candidates)))) as pool:
        findings = list(pool.map(lambda c: probe(c, timeout_s=timeout_s), candidates))
    if usb:
        findings += probe_usb(usb_backend, pyusb_backend)
    _stable_ports(findings)
    return findings


# --- output ---------------------------------------------------------------------------------------

COLUMNS = ("PORT", "INSTRUMENT", "MODEL", "SERIAL", "FIRMWARE", "DRIVER")


def table_rows(findings: Sequence[Finding]) -> list[tuple[str, ...]]:
    rows = []
    for f in findings:
        port = f.port
        if f.candidate is not None and f.candidate.usb_id:
            port += f" (USB {f.candidate.usb_id}"
            port += f" SER={f.candidate.usb_serial})" if f.candidate.usb_serial else ")"
        if f.status == "found" and f.identity is not None:
            i = f.identity
            rows.append((port, i.kind, i.model, i.serial_number or "-", i.firmware or "-",
                         f.driver + (f" @{f.baud}" if f.baud and f.driver == "cs1000a" else "")))
        elif f.status == "unknown":
            rows.append((port, "unknown", "-", "-", "-", "-"))
    return rows


def format_table(findings: Sequence[Finding]) -> str:
    """The table of what answered, then one line per port that could not be asked."""
    rows = table_rows(findings)
    widths = [max(len(str(r[i])) for r in [COLUMNS, *rows]) for i in range(len(COLUMNS))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip()
             for r in [COLUMNS, *rows]]
    for f in findings:
        if f.status == "unknown":
            lines.append(f"{f.port}: unknown: {f.note}")
        elif f.status in ("busy", "denied", "error"):
            lines.append(f"{f.port}: {f.note}")
    silent = [f.port for f in findings if f.status == "silent"]
    if silent:
        lines.append(f"no reply from {len(silent)} port(s): {', '.join(silent)}")
    return "\n".join(lines)


def assign_roles(findings: Sequence[Finding]) -> tuple[dict[str, Finding], list[Finding]]:
    """Role → finding, in the registry's role order; the stages by driver (registry order)
    then serial number.  Returns also what found no role."""
    order = list(registry.DRIVERS)
    found = sorted((f for f in findings if f.status == "found"),
                   key=lambda f: (order.index(f.driver), f.serial_number, f.port))
    roles: dict[str, Finding] = {}
    used: set[int] = set()
    for role in registry.ROLES:
        for i, f in enumerate(found):
            if i not in used and role in registry.entry(f.driver).roles:
                roles[role] = f
                used.add(i)
                break
    return roles, [f for i, f in enumerate(found) if i not in used]


def _toml(value: Any) -> str:
    from normbox_lab.acquire.config import _toml_value

    return _toml_value(value)


def lab_config_text(findings: Sequence[Finding], *, name: str = "Normbox") -> str:
    """A lab config naming every found instrument by its stable key (raises ConfigError when a
    required role was not found)."""
    roles, extra = assign_roles(findings)
    missing = [r for r in registry.REQUIRED_ROLES if r not in roles]
    if missing:
        raise ConfigError("<discover>", 0, "instruments",
                          f"not found: {', '.join(missing)} (every lab needs a radiometer, a "
                          "rotator and a sphere); nothing written")
    lines = ["# normbox-lab lab config written by `normbox-lab lab discover`.",
             "# Ports are stable keys: hwgrep://SER=… finds a USB-serial adapter by its serial",
             "# number wherever it is plugged; usb:SERIAL is the spectrometer's own.  The stages'",
             "# roles follow driver and serial order: check them (`normbox-lab lab check`) and",
             "# swap the ports if the arms are the other way round.  Add each instrument's",
             "# calibration certificate under [instruments.ROLE.calibration] (docs/first-contact.md).",
             "", "[lab]", f"name = {_toml(name)}", "simulated = false", ""]
    for role in registry.ROLES:
        f = roles.get(role)
        if f is None:
            continue
        i = f.identity
        assert i is not None
        where = f.port
        if f.candidate is not None and f.candidate.usb_id:
            where += f", USB {f.candidate.usb_id}"
        lines.append(f"[instruments.{role}]   # {i.model}"
                     f"{' serial ' + i.serial_number if i.serial_number else ''}"
                     f"{' firmware ' + i.firmware if i.firmware else ''}; found on {where}")
        lines.append(f"driver = {_toml(f.driver)}")
        lines.append(f"port = {_toml(f.stable_port or f.port)}")
        if i.serial_number:
            lines.append(f"serial_number = {_toml(i.serial_number)}   # lab check compares")
        options = dict(f.options)
        if f.driver == "cs1000a" and f.baud:
            options["baud"] = f.baud
        options.update(ROLE_OPTIONS.get(role, {}))
        lines += [f"{k} = {_toml(v)}" for k, v in options.items()]
        lines.append("")
    for f in extra:
        i = f.identity
        lines.append(f"# also found, no role: {f.driver} {i.model if i else ''} "
                     f"{i.serial_number if i else ''} at {f.stable_port or f.port}")
    return "\n".join(lines).rstrip() + "\n"


def write_lab_config(findings: Sequence[Finding], path: str | Path, *,
                     overwrite: bool = False) -> Path:
    from normbox_lab.acquire.config import parse_config

    path = Path(path)
    if path.exists() and not overwrite:
        raise ConfigError(str(path), 0, "(file)", "exists already; pass --force to overwrite")
    text = lab_config_text(findings)
    parse_config(text, str(path))               # what we write must load
    path.write_text(text, encoding="utf-8")
    return path


__all__ = ["Candidate", "Finding", "GuardedPort", "ProbeRefused", "allowed_bytes", "assign_roles",
           "discover", "format_table", "lab_config_text", "port_problem", "probe", "probe_usb",
           "serial_candidates", "write_lab_config"]
