"""Hostile text into every subcommand that takes what a person types: run references, store,
lab, input and output paths, --param, renderer names, fault specs, numeric options.

Each input ends in one of two ways: the command does it (exit 0), or it refuses with exactly
one line on stderr and exit 2.  Never a traceback, never a hang or a read without end (a
device such as /dev/zero as a file), never a refusal of two lines (a newline, a terminal
escape or a lone surrogate in a typed path is written as an escape in the one line).  Exit 1
stays for what a command finds in the store (a run with no prediction to compare, no BRDF
to fit): those are named below.

The default run tries a seeded sample of the inputs on every command (about 400 inputs, a
few seconds); the slow one tries every input on every command (about 5000).  Both print the
number of inputs tried (run with -s).
"""

from __future__ import annotations

import contextlib
import io
import random
import resource
import signal

import pytest

from normbox_lab.cli import main

#: inputs nobody named: huge numbers, digits of other scripts, spaces of other kinds, NUL,
#: long text, empty text, paths that are directories or devices, negative zero, Python's
#: own number spellings, line breaks and terminal escapes, lone surrogates (undecodable
#: bytes in argv)
HOSTILE = ["", " ", "a\x00b", "9" * 5000, "9" * 309, "-0", "-0.0", "+0", "1_000", "0x10", "0b1",
           "1e-400", "1e400", "-1e400", "nan", "NaN", "inf", "-inf", "Infinity", "٣", "４５",
           "³", "½", "Ⅻ", "\u00a0", "1\u00a05", " 1 ", "\t1", "1\n", "\n", "1e", ".", "-",
           "..", "[", "[]", "[[1]]", "{}", "null", "true", "'", '"', "\\", "/", "/etc",
           "/dev/zero", "/dev/null", "~", "$HOME", "a" * 100_000, "💥", "\udcff", "--", "-1",
           "0", "2", "18446744073709551616", "-9223372036854775809", "1e308", "4.9e-324",
           "0.1", "1,2", "%s%n", "{0}", "a b", "\x1b[31mred", "\u202e1", "\ufeff1", "1\u200b",
           "X\nY"]
_rng = random.Random(36)
_ALPHABET = "0123456789.,-+eE[]{}\"' \t\n٣４\u00a0\u200b_xX/\\:=@;#%💥\udcff\x00"
HOSTILE += ["".join(_rng.choice(_ALPHABET) for _ in range(_rng.randint(1, 12)))
            for _ in range(25)]

BAD = "--no-such-option-z"      # after an option under test: its own check comes first
S = ["--store", "s.sqlite"]
#: every command and the place of the hostile text ({X}; {OUT}: an output path, only
#: relative values are tried); commands that would run long on a valid value end with BAD
COMMANDS: list[list[str]] = [
    ["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab", "lab.toml", *S,
     "--param", "angles_deg={X}"],
    ["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab", "lab.toml", *S,
     "--param", "{X}"],
    ["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab", "{X}", *S],
    ["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab", "lab.toml",
     "--store", "{X}"],
    ["run", "--resume", "{X}", "--dry-run", "--lab", "lab.toml", *S],
    ["run", "{X}", "--dry-run", "--world", "analytic", "--lab", "lab.toml", *S],
    ["run", "reference-sweep", "--dry-run", "--lab", "lab.toml", *S, "--time-scale", "{X}"],
    ["runs", "--store", "{X}"],
    ["qa", "{X}", *S], ["qa", "1", "--store", "{X}"],
    ["export", "{X}", "--format", "json", "-o", "out.json", *S],
    ["export", "1", "--format", "csv", "-o", "{OUT}", *S],
    ["import", "prediction", "{X}", "--ref-run", "1", "--renderer", "r", *S],
    ["import", "prediction", "pred.csv", "--ref-run", "{X}", "--renderer", "r", *S],
    ["import", "prediction", "pred.csv", "--ref-run", "1", "--renderer", "{X}", *S],
    ["import", "brdf-json", "{X}", *S],
    ["import", "brdf-json", "brdf.json", "--tilt-deg", "{X}", BAD],
    ["fit", "{X}", *S], ["fit", "1", "-w", "{X}", BAD],
    ["predict", "{X}", *S], ["predict", "1", "--target-se", "{X}", BAD],
    ["predict", "1", "--workers", "{X}", BAD],
    ["compare", "{X}", *S], ["compare", "1", "--brdf-run", "{X}", *S],
    ["compare", "1", "--renderer", "{X}", *S],
    ["report", "{X}", *S], ["report", "1", "--brdf-run", "{X}", *S],
    ["budget", "{X}", *S], ["budget", "1", "--sources", "{X}", *S],
    ["budget", "1", "--paths", "{X}", BAD], ["budget", "1", "--draws", "{X}", BAD],
    ["budget", "1", "--renderer", "{X}", *S],
    ["scene", "export", "{X}", "--out", "scene-out", *S],
    ["image", "exr-info", "{X}"],
    ["image", "camera", "--patch", "{X}", BAD], ["image", "camera", "--size", "{X}", BAD],
    ["image", "camera", "--w", "{X}", BAD], ["image", "camera", "--angle", "{X}", BAD],
    ["image", "triplet", "--false-alarm", "{X}", BAD],
    ["image", "whitebalance", "--lamp-k", "{X}", BAD],
    ["lab", "calibrations", "--lab", "{X}"],
    ["lab", "discover", "--no-scan", "--no-usb", "--timeout-s", "{X}", BAD],
    ["sim", "faults", "{X}"],
    ["sim", "serve", "{X}", "--pty", "--faults", "no-such-kind"],
    ["sim", "serve", "cs1000a", "--pty", "--faults", "{X}", "--seed", "-1"],
    ["sim", "serve", "cs1000a", "--pty", "--seed", "{X}", BAD],
    ["sim", "campaign", "--scenarios", "{X}", BAD],
    ["sim", "campaign", "--normbox-share", "{X}", BAD],
    ["sim", "campaign", "--replay", "{X}", "--scenarios", "1", "--max-faults", "-5"],
    ["bench", "engine", "--repeat", "{X}", BAD], ["bench", "predict", "--target", "{X}", BAD],
    ["tui", "--time-scale", "{X}", BAD],
    ["init", "{OUT}", "--sim"],
    ["{X}"],
]
#: what a command finds in the store, not a refusal of what was typed: exit 1 (the run
#: named is a reference sweep without BRDFs, fits, prediction or comparison; or done)
FOUND = ("no BRDF readings to fit", "no fits for", "no artifact", "has no prediction",
         "is already done; nothing to resume")

TRIED = {"default": 0, "slow": 0}


@pytest.fixture(scope="module")
def workdir(tmp_path_factory):
    """A simulated lab config and a store with one done run (one reading)."""
    import os

    path = tmp_path_factory.mktemp("hostile")
    old = os.getcwd()
    os.chdir(path)
    try:
        assert main(["init", "lab.toml", "--sim"]) == 0
        assert main(["run", "reference-sweep", "--world", "analytic", "--time-scale", "0",
                     "--lab", "lab.toml", *S, "--param", "angles_deg=[30]", "--param",
                     "patches=[1]", "--plain"]) == 0
    finally:
        os.chdir(old)
    (path / "pred.csv").write_text("patch,angle_deg,wavelength_nm,radiance_W_sr_m2_nm\n")
    (path / "brdf.json").write_text("[]")
    return path


class _Timeout(Exception):
    pass


def _run(argv: list[str]) -> tuple[int, str]:
    """(exit status, stderr) of the command line in this process, within 20 s and 4 GiB."""
    err = io.StringIO()

    def alarm(*_: object) -> None:
        raise _Timeout(" ".join(argv)[:80])

    previous = signal.signal(signal.SIGALRM, alarm)
    limit = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (4 << 30, limit[1]))
    signal.alarm(20)
    try:
        with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 2
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, previous)
        resource.setrlimit(resource.RLIMIT_AS, limit)
    return code, err.getvalue()


def _check(workdir, monkeypatch, command: list[str], text: str) -> bool:
    """Run one command with one input; False when the input does not apply (an absolute
    output path: the test writes only inside its folder)."""
    if "{OUT}" in command and (text.lstrip().startswith(("/", "~")) or text in (
            "lab.toml", "s.sqlite", "pred.csv", "brdf.json")):
        return False
    monkeypatch.chdir(workdir)
    argv = [a.replace("{X}", text).replace("{OUT}", text) for a in command]
    code, err = _run(argv)
    lines = err.splitlines()
    where = f"{' '.join(command)[:60]!r} with {text[:40]!r}"
    assert "Traceback" not in err, where
    if code == 1:
        assert len(lines) == 1 and any(f in lines[0] for f in FOUND), (where, err[:300])
    else:
        assert code in (0, 2), (where, code, err[:300])
    if code == 2:
        assert len(lines) == 1 and lines[0].startswith("normbox-lab: "), (where, err[:300])
        assert lines[0].isprintable(), (where, lines[0][:200])
    return True


def test_hostile_text_into_every_command_is_done_or_one_line(workdir, monkeypatch):
    rng = random.Random(2026)
    for command in COMMANDS:
        for text in rng.sample(HOSTILE, 8):
            TRIED["default"] += _check(workdir, monkeypatch, command, text)


@pytest.mark.slow
def test_every_hostile_text_into_every_command_is_done_or_one_line(workdir, monkeypatch):
    for command in COMMANDS:
        for text in HOSTILE:
            TRIED["slow"] += _check(workdir, monkeypatch, command, text)


def test_a_device_or_a_fifo_named_as_a_file_is_one_line_never_read(workdir, monkeypatch,
                                                                   capsys):
    """/dev/zero as the lab config or an import file was read without end (24 GB before the
    kernel killed it); a FIFO waited for a writer.  Now: one line, exit 2, nothing read."""
    import os

    monkeypatch.chdir(workdir)
    fifo = workdir / "fifo.toml"
    if not fifo.exists():
        os.mkfifo(fifo)
    for argv, expect in (
            (["run", "reference-sweep", "--dry-run", "--lab", "/dev/zero", *S],
             "/dev/zero:0: (file): not a regular file"),
            (["run", "reference-sweep", "--dry-run", "--lab", str(fifo), *S],
             f"{fifo}:0: (file): not a regular file"),
            (["lab", "calibrations", "--lab", ""], "'':0: (file): an empty path names no file"),
            (["import", "brdf-json", "/dev/zero", *S], "/dev/zero: not a regular file"),
            (["import", "prediction", "/dev/zero", "--ref-run", "1", "--renderer", "r", *S],
             "/dev/zero: not a regular file or directory"),
            (["image", "exr-info", "/dev/zero"], "/dev/zero: not a regular file"),
            (["image", "exr-info", "lab.toml"], "lab.toml: not an EXR image")):
        code, err = _run(argv)
        assert code == 2 and err.startswith(f"normbox-lab: error: {expect}"), (argv, err)
        assert err.count("\n") == 1, err


def test_a_typed_path_with_a_line_break_or_an_escape_stays_one_printable_line(workdir,
                                                                             monkeypatch):
    monkeypatch.chdir(workdir)
    for store in ("x\ny.sqlite", "\x1b[2Jz.sqlite", "\udcff.sqlite"):
        (workdir / store).write_text("not a store\n" * 10)
        code, err = _run(["runs", "--store", store])
        escaped = store.encode("unicode_escape").decode("ascii") if store.isascii() else \
            store.replace("\udcff", "\\udcff")
        assert code == 2 and err == (f"normbox-lab: error: {escaped}: not a normbox-lab store "
                                     "(not an SQLite file); refusing to touch it (the file "
                                     "was not changed)\n"), err


def test_numbers_and_names_the_system_refuses_are_one_line(workdir, monkeypatch):
    """A 5000-digit run reference hit Python's 4300-digit limit; a 5000-character store or
    output name raised ENAMETOOLONG; a NUL byte raised ValueError; a lone surrogate in a
    renderer name failed in SQLite's encoder; `lab discover --timeout-s` was float()
    (NaN, ٣ and -1 accepted); `sim serve --tcp` read the port with int(), `--option` its
    numbers with the emulator's float()."""
    monkeypatch.chdir(workdir)
    for argv, expect in (
            (["qa", "9" * 5000, *S], "no run matches"),
            (["runs", "--store", "9" * 5000], "cannot be a store"),
            (["run", "reference-sweep", "--dry-run", "--lab", "lab.toml", "--store", "a\x00b"],
             "cannot be a store"),
            (["export", "1", "--format", "csv", "-o", "a\x00b", *S], "a file name has no NUL"),
            (["export", "1", "--format", "csv", "-o", "9" * 5000, *S], "over 255 bytes"),
            (["export", "1", "--format", "csv", "-o", "no/such/dir/x.csv", *S], "no folder"),
            (["init", "no/such/dir/lab.toml", "--sim"], "no folder"),
            (["compare", "1", "--renderer", "\udcff", *S], "is not a renderer name"),
            (["lab", "discover", "--no-scan", "--no-usb", "--timeout-s", "NaN"],
             "NaN is not a finite number"),
            (["lab", "discover", "--no-scan", "--no-usb", "--timeout-s", "٣"],
             "digits of another script"),
            # int() read "٣" as 3: sim serve listened on port 3
            (["sim", "serve", "cs1000a", "--tcp", "127.0.0.1:٣"], "port must be 0..65535"),
            (["sim", "serve", "cs1000a", "--tcp", "127.0.0.1:" + "9" * 5000],
             "port must be 0..65535"),
            # the emulators' float() took these, and served
            (["sim", "serve", "cs1000a", "--pty", "--option", "time_factor=NaN"],
             "--option time_factor: NaN is not a finite number"),
            (["sim", "serve", "cs1000a", "--pty", "--option", "time_factor=٣"],
             "--option time_factor: '٣' has digits of another script"),
            (["sim", "serve", "cs1000a", "--pty", "--option", "time_factor=-1"],
             "--option time_factor: -1 must be ≥ 0"),
            (["sim", "serve", "cs1000a", "--pty", "--option", "baud=1e400"],
             "--option baud: 1e400 is not a finite number"),
            # lab check --roles was split on commas: an empty item dropped, "" meant every one
            (["lab", "check", "--lab", "lab.toml", "--roles", "radiometer,,rotator", *S],
             "--roles: 'radiometer,,rotator' has an empty item"),
            (["lab", "check", "--lab", "lab.toml", "--roles", "rotator,rotator", *S],
             "--roles: 'rotator' is given twice"),
            (["lab", "check", "--lab", "lab.toml", "--roles", "", *S], "--roles: empty")):
        code, err = _run(argv)
        assert code == 2 and expect in err and err.count("\n") == 1, (argv[:3], err[:300])


def test_zz_report_inputs_tried(capsys):
    """How many inputs the tests above tried (run with -s to see it)."""
    with capsys.disabled():
        print(f"\nhostile CLI inputs tried: {TRIED['default']} (default), {TRIED['slow']} "
              "(slow)")
    assert TRIED["default"] > 0


def test_a_lab_configs_emulator_option_goes_through_the_one_parser(workdir, monkeypatch):
    """``sim://cs1000a?time_factor=٣`` in the lab config ran the radiometer at ×3."""
    monkeypatch.chdir(workdir)
    text = (workdir / "lab.toml").read_text()
    for value, expect in (("٣", "'٣' has digits of another script"),
                          ("NaN", "NaN is not a finite number"), ("-2", "-2 must be ≥ 0")):
        bad = workdir / "emulator-option.toml"
        bad.write_text(text.replace('"sim://cs1000a"', f'"sim://cs1000a?time_factor={value}"'))
        code, err = _run(["run", "reference-sweep", "--dry-run", "--lab", str(bad), *S])
        assert code == 2 and err.count("\n") == 1, err
        assert err.startswith(f"normbox-lab: error: {bad}:") and "radiometer.port: " in err
        assert f"option time_factor: {expect}" in err, err


@pytest.mark.parametrize("replay, expect", [
    ("[" * 100_000, "maximum recursion depth exceeded"),
    ('{"seed": "x", "index": 0, "protocol": "reference-sweep", "params": {}}',
     "seed: 'x' is not a whole number"),
    ('{"seed": 0, "index": 0, "protocol": "../x.py", "params": {}}',
     "protocol: '../x.py' is not one of reference-sweep"),
    ('{"seed": 0, "index": 0, "protocol": "reference-sweep", "params": "x"}',
     "params and extra: expected JSON objects"),
    (('{"seed": 0, "index": 0, "protocol": "reference-sweep", "params": {"angles_deg": '
     '[1e400]}}'), "angles_deg: Infinity is not a finite number"),
    ('{"seed": 0, "index": 0, "protocol": "reference-sweep", "params": {}, "world": 5}',
     "world: 5 is not one of analytic"),
])
def test_a_replayed_scenario_of_any_shape_is_one_line(replay, expect):
    """A replay is JSON a person pastes: nested 100 000 deep it was a RecursionError
    traceback; params "x" a traceback in `describe`; a seed "x", a protocol path or NaN
    angles ran as a scenario."""
    code, err = _run(["sim", "campaign", "--replay", replay, "--scenarios", "1"])
    assert code == 2 and err.count("\n") == 1 and expect in err, err


def test_every_drawn_scenario_passes_the_replay_check():
    """What a campaign prints, it replays: 300 drawn scenarios pass the shape check."""
    from normbox_lab.campaign.scenario import Scenario, draw
    from normbox_lab.commands.sim import check_replay_faults, check_replay_scenario

    for index in range(300):
        scenario = Scenario.from_json(draw(7, index, normbox_share=0.2).to_json())
        check_replay_scenario(scenario)
        check_replay_faults(scenario)
