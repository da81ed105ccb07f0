"""The one parser of numbers and lists (normbox_lab.acquire.params), driven with random text.

Every entry point — `run --param K=V`, every numeric option of every subcommand, the console's
form and dialogs, the lab config's protocol defaults — answers a value of its kind within its
limits, or one line (`ParameterError`, exit 2): never another exception, never a traceback.
"""

from __future__ import annotations

import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from normbox_lab.acquire import params as P
from normbox_lab.acquire.params import ParameterError

#: text an operator or a script may give: digits of several scripts, signs, brackets, commas,
#: exponents, the words JSON and Python read as numbers, and anything else
ALPHABET = st.sampled_from(list("0123456789+-.eE,[] \"x_") + ["٣", "４", "०", "NaN", "Infinity",
                                                               "inf", "1e400", "9" * 320,
                                                               "\n", "\x00", "−", "½", "wall"])
TEXT = st.one_of(st.text(max_size=60), st.lists(ALPHABET, max_size=30).map("".join))

KINDS = {
    "angles": P.Angles(),
    "angle": P.Angles(many=False),
    "patches": P.Patches(),
    "materials": P.Patches(names=True),
    "count": P.Count(maximum=50),
    "positive": P.Positive("s"),
    "time-scale": P.TIME_SCALE,
    "seed": P.SEED,
    "fraction": P.PROBABILITY,
}
TRIED = {"n": 0}


def _one_line(exc: ParameterError) -> None:
    text = str(exc)
    assert text and "\n" not in text and "\r" not in text and len(text) < 240, text
    assert exc.exit_code == 2


def _within(kind: P.Limit, value: object) -> None:
    values = value if kind.many else [value]
    assert isinstance(values, list) and values
    for v in values:
        if isinstance(v, str):
            assert kind.names and v.isascii()
            continue
        assert isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
        if kind.whole:
            assert isinstance(v, int)
    if kind.many:
        keys = [P.material_key(v) if isinstance(kind, P.Patches) else P.angle_key(v)
                for v in values]
        assert len(keys) == len(set(keys)), values


@settings(max_examples=600, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(text=TEXT, kind=st.sampled_from(sorted(KINDS)))
def test_random_text_is_a_value_of_its_kind_or_one_line(text, kind):
    TRIED["n"] += 1
    try:
        value = P.read(text, KINDS[kind], kind)
    except ParameterError as exc:
        _one_line(exc)
        return
    _within(KINDS[kind], value)
    assert all(ch.isascii() for ch in text if ch.isdigit())


DEFAULTS = [[30, 35, 40], list(range(1, 25)), [*range(1, 25), "wall"], 10, 3600.0, True,
            "sphere"]


@settings(max_examples=600, deadline=None)
@given(text=TEXT, default=st.sampled_from(DEFAULTS))
def test_random_text_as_a_protocol_parameter_is_a_value_or_one_line(text, default):
    TRIED["n"] += 1
    try:
        value = P.parse_param(default, text, "field")
    except ParameterError as exc:
        _one_line(exc)
        return
    if isinstance(default, list):
        assert isinstance(value, list)
        for v in value:
            assert isinstance(v, str) or math.isfinite(v)
    elif isinstance(default, bool):
        assert isinstance(value, bool)
    elif isinstance(default, (int, float)):
        assert math.isfinite(value)


@settings(max_examples=300, deadline=None)
@given(items=st.lists(TEXT.filter(lambda t: "[" not in t and "]" not in t), max_size=5))
def test_a_list_reads_the_same_with_and_without_brackets(items):
    """`30,,60` became [30, 60] while `[30,,60]` was refused: one reading now."""
    TRIED["n"] += 1
    body = ",".join(items)
    if not body.strip():
        return
    results = []
    for text in (body, f"[{body}]"):
        try:
            results.append(P.parse_param([30, 60], text, "angles_deg"))
        except ParameterError as exc:
            results.append(str(exc).replace(f"[{body}]", body).replace(repr(f"[{body}]"),
                                                                       repr(body)))
    if all(isinstance(r, list) for r in results):
        assert results[0] == results[1]
    else:
        assert all(isinstance(r, str) for r in results), results


@pytest.mark.parametrize("digit", ["٣", "３", "३", "৩", "𝟑", "³"])
def test_digits_of_other_scripts_are_refused_in_every_entry(digit):
    """The go-to dialog moved to 45° for `٤٥` while the form refused `[٣]`: one rule now."""
    for call in (lambda: P.parse_number(digit + "0", "a"),
                 lambda: P.read(f"[{digit}0]", P.Angles(), "a"),
                 lambda: P.read(digit, P.Number(0, 100), "a"),
                 lambda: P.parse_param(10, digit, "a"),
                 lambda: P.parse_param([1, "wall"], f"{digit}, wall", "a")):
        with pytest.raises(ParameterError) as exc:
            call()
        _one_line(exc.value)


@pytest.mark.parametrize("digits", [309, 4300, 4301, 5000, 100_000])
def test_huge_integers_are_refused_by_length_before_conversion(digits):
    text = "9" * digits
    for kind in (P.Count(), P.Positive("s"), P.Angles(), P.Patches(), P.SEED):
        with pytest.raises(ParameterError) as exc:
            P.read(text if not kind.many else f"[{text}]", kind, "f")
        _one_line(exc.value)
        assert "too long" in str(exc.value)


def test_huge_python_integers_from_a_script_or_toml_are_refused_without_overflow():
    """Values that arrive as Python objects (TOML, a script) go through the same kinds."""
    huge = 10 ** 400
    for kind, value in ((P.Count(), huge), (P.Positive("s"), huge), (P.Angles(), [huge]),
                        (P.Patches(), [huge]), (P.Angles(many=False), -huge)):
        with pytest.raises(ParameterError) as exc:
            kind.check("f", value, {}, None)
        _one_line(exc.value)


@pytest.mark.parametrize("kind, text, expect", [
    (P.Angles(), "[30, 30]", "f: 30 is given twice"),
    (P.Angles(), "[30, 30.0]", "f: 30 is given twice"),
    (P.Patches(), "7, 7", "f: 7 is given twice"),
    (P.Patches(names=True), '[7, "p07"]',
     "f: 'p07' is given next to 7 (both are reading key p07)"),
    (P.Patches(names=True), "wall, wall", "f: 'wall' is given twice"),
])
def test_duplicates_that_would_share_a_reading_key_are_refused(kind, text, expect):
    with pytest.raises(ParameterError) as exc:
        P.read(text, kind, "f")
    assert str(exc.value).startswith(expect), str(exc.value)


def test_values_that_parse():
    assert P.read("[30, 45.5]", P.Angles(), "a") == [30, 45.5]
    assert P.read("30,45.5", P.Angles(), "a") == [30, 45.5]
    assert P.read(" 7 ", P.Count(), "n") == 7 and isinstance(P.read("7.0", P.Count(), "n"), int)
    assert P.read("1e3", P.Count(), "n") == 1000
    assert P.read("[3, wall]", P.Patches(names=True), "m") == [3, "wall"]
    assert P.read('[3, "wall"]', P.Patches(names=True), "m") == [3, "wall"]
    assert P.read("0", P.TIME_SCALE, "t") == 0 and P.read(".5", P.TIME_SCALE, "t") == 0.5
    assert P.parse_param(True, "false", "b") is False
    assert P.parse_param(3600.0, "60", "t") == 60.0 and isinstance(
        P.parse_param(3600.0, "60", "t"), float)


# --- the command line, with random text ----------------------------------------------------------

@pytest.fixture(scope="module")
def lab_dir(tmp_path_factory):
    from normbox_lab.cli import main

    d = tmp_path_factory.mktemp("lab")
    assert main(["init", str(d / "lab.toml"), "--sim"]) == 0
    return d


PARAMS = ["angles_deg", "patches", "lamp_timeout_s"]
#: every parameter of every shipped protocol (roles included), and a name no protocol has
PROTOCOL_PARAMS = [("reference-sweep", k) for k in ("angles_deg", "patches", "lamp_timeout_s",
                                                    "rotator", "radiometer", "lamp", "bogus")] \
    + [("repeatability", k) for k in ("repeats", "threshold_percent", "angle_deg", "patch",
                                      "rotator", "radiometer", "lamp")] \
    + [("light-map", k) for k in ("rows", "columns", "panel_x_mm", "panel_y_mm", "margin_mm",
                                  "radiometer", "lamp")]
#: the lab's roles and names near them: a role of the wrong kind must be refused as a value
ROLE_TEXT = st.sampled_from(["rotator", "radiometer", "sphere", "spectrometer", "gonio",
                             "gonio_light_arm", "gonio_detector_arm", "lamp", "Radiometer",
                             " rotator", "rotator\t", "ｒotator", ""])


@settings(max_examples=120, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(text=TEXT, key=st.sampled_from(PARAMS))
def test_random_text_into_run_param_is_exit_0_or_2_and_one_line(lab_dir, capsys, text, key):
    """`run reference-sweep --dry-run --param K=<random>`: a dry run (0) or one line (2)."""
    from normbox_lab.cli import main

    TRIED["n"] += 1
    if "\x00" in text:
        text = text.replace("\x00", "")      # argv cannot carry NUL
    capsys.readouterr()
    code = main(["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab",
                 str(lab_dir / "lab.toml"), "--store", str(lab_dir / "dry.sqlite"),
                 "--param", f"{key}={text}"])
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    if code == 2:
        assert out.err.startswith("normbox-lab: error: ") and out.err.count("\n") == 1, out.err
    else:
        assert code == 0, out.err


def _refusal_or_run(code: int, err: str) -> None:
    assert "Traceback" not in err, err
    if code == 2:
        lines = [line for line in err.splitlines() if line.startswith("normbox-lab: error: ")]
        assert err == lines[0] + "\n", err          # the one line, no note before it
    else:
        assert code == 0, err


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(text=st.one_of(TEXT, ROLE_TEXT), which=st.sampled_from(range(len(PROTOCOL_PARAMS))))
def test_random_text_into_every_protocol_parameter_roles_included(lab_dir, capsys, text, which):
    """Every parameter of every shipped protocol, roles included (``radiometer=rotator``
    exited 1 from a step's capability check), with random text: a dry run (0) or exit 2 with
    one line naming the refusal, never a traceback."""
    from normbox_lab.cli import main

    TRIED["n"] += 1
    protocol, key = PROTOCOL_PARAMS[which]
    text = text.replace("\x00", "")
    capsys.readouterr()
    code = main(["run", protocol, "--dry-run", "--world", "analytic", "--lab",
                 str(lab_dir / "lab.toml"), "--store", str(lab_dir / "dry.sqlite"),
                 "--param", f"{key}={text}"])
    _refusal_or_run(code, capsys.readouterr().err)


@pytest.mark.parametrize("protocol, param, expect", [
    ("reference-sweep", "radiometer=rotator",
     "radiometer: 'rotator' (apt-k10cr1) is not SpectrumReadable; this lab's: radiometer"),
    ("reference-sweep", "rotator=radiometer", "rotator: 'radiometer' (cs1000a) is not Movable"),
    ("reference-sweep", "lamp=radiometer",
     "lamp: 'radiometer' (cs1000a) is not Settling; this lab's: sphere"),
    ("repeatability", "radiometer=spectrometer",
     "radiometer: 'spectrometer' (qepro) is not SpectrumReadable"),
    ("light-map", "lamp=rotator", "lamp: 'rotator' (apt-k10cr1) is not Settling"),
    ("reference-sweep", "radiometer=wizard", ("radiometer: 'wizard' is not an instrument of "
                                             "this lab")),
])
def test_a_role_of_the_wrong_kind_is_refused_as_a_parameter(lab_dir, capsys, protocol, param,
                                                            expect):
    from normbox_lab.cli import main

    capsys.readouterr()
    assert main(["run", protocol, "--dry-run", "--world", "analytic", "--lab",
                 str(lab_dir / "lab.toml"), "--store", str(lab_dir / "dry.sqlite"),
                 "--param", param]) == 2
    err = capsys.readouterr().err
    assert err == f"normbox-lab: error: {expect}" + err[len(f"normbox-lab: error: {expect}"):]
    assert err.count("\n") == 1, err


OPTIONS = [(["run", "reference-sweep", "--dry-run"], "--time-scale"),
           (["tui"], "--time-scale"),
           (["sim", "campaign"], "--max-faults"),
           (["sim", "campaign"], "--scenarios"),
           (["sim", "campaign"], "--normbox-share"),
           (["sim", "serve", "cs1000a", "--pty"], "--seed"),
           (["fit", "1"], "--weight-exponent"),
           (["predict", "1"], "--workers"),
           (["budget", "1"], "--draws"),
           (["image", "camera"], "--angle"),
           (["image", "whitebalance"], "--size"),
           (["image", "whitebalance"], "--w"),
           (["import", "brdf-json", "f.json"], "--tilt-deg"),
           (["bench", "predict"], "--target")]


@settings(max_examples=400, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=TEXT, which=st.sampled_from(range(len(OPTIONS))))
def test_random_text_into_every_numeric_option_is_a_value_or_one_line(capsys, text, which):
    """Parsing only (nothing runs): the option's value, or exit 2 and one line."""
    from normbox_lab.cli import build_parser

    TRIED["n"] += 1
    head, flag = OPTIONS[which]
    capsys.readouterr()
    try:
        args = build_parser().parse_args([*head, f"{flag}={text}"])
    except SystemExit as exc:
        assert exc.code == 2
        err = capsys.readouterr().err
        assert err.startswith("normbox-lab: error: ") and err.count("\n") == 1, err
        return
    value = getattr(args, flag.lstrip("-").replace("-", "_"))
    assert value is not None
    for v in value if isinstance(value, tuple) else (value,):
        assert math.isfinite(v)


@pytest.mark.parametrize("line, expect", [
    ("angles_deg = [30, 30]", "protocols.reference-sweep.angles_deg: 30 is given twice"),
    ("patches = [7, 7]", "protocols.reference-sweep.patches: 7 is given twice"),
    ("angles_deg = [30, nan]", "protocols.reference-sweep.angles_deg: must be a finite number"),
    ("lamp_timeout_s = -1.0", "protocols.reference-sweep.lamp_timeout_s: -1 s must be > 0"),
])
def test_the_lab_configs_protocol_defaults_go_through_the_same_kinds(tmp_path, capsys, line,
                                                                     expect):
    """The lab config's [protocols.NAME] defaults: the same kinds and limits as --param, one
    line naming file:line:field, exit 2 (a config is what a person wrote)."""
    import re

    from normbox_lab.cli import main

    assert main(["init", str(tmp_path / "lab.toml"), "--sim"]) == 0
    text = (tmp_path / "lab.toml").read_text()
    key = line.split(" = ")[0]
    text = re.sub(rf"^{key} = [^\n]*\n", "", text, flags=re.MULTILINE)   # (only this table)
    text = text.replace("[protocols.reference-sweep]\n", f"[protocols.reference-sweep]\n{line}\n")
    (tmp_path / "bad.toml").write_text(text)
    capsys.readouterr()
    assert main(["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab",
                 str(tmp_path / "bad.toml")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("normbox-lab: error: ") and expect in err, err
    assert err.count("\n") == 1


# --- the lab config and protocol files, with random text ----------------------------------------

#: (table line, key) of the simulated lab config whose value the random text replaces
#: (a port is opened, not parsed: its fault spec has its own test below)
CONFIG_KEYS = [("[lab]", "time_scale"), ("[lab]", "seed"), ("[instruments.radiometer]", "driver"),
               ("[instruments.rotator]", "min_angle_deg"), ("[geometry]", None),
               ("[protocols.reference-sweep]", "angles_deg"),
               ("[protocols.reference-sweep]", "patches"), ("[quality]", None)]


def _with_value(config: str, table: str, key: str | None, value: str) -> str:
    """`config` with `key = value` set under `table` (added when the key is not there)."""
    lines = config.splitlines()
    start = next(i for i, line in enumerate(lines) if line.split("#")[0].strip() == table)
    end = next((i for i in range(start + 1, len(lines)) if lines[i].startswith("[")), len(lines))
    key = key or "extra_key"
    for i in range(start + 1, end):
        if lines[i].split("=", 1)[0].strip() == key:
            lines[i] = f"{key} = {value}"
            break
    else:
        lines.insert(start + 1, f"{key} = {value}")
    return "\n".join(lines) + "\n"


VALUE_TEXT = st.one_of(
    TEXT,                                                          # raw TOML text
    TEXT.map(lambda t: '"' + t.replace("\\", "").replace('"', "") + '"'),      # a string
    st.lists(ALPHABET, max_size=12).map(lambda xs: "[" + ",".join(xs) + "]"),  # a list
    st.sampled_from(["nan", "inf", "-inf", "1e400", "9" * 400, "true", "{}", "[[1]]"]))


@settings(max_examples=300, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(value=VALUE_TEXT, which=st.sampled_from(range(len(CONFIG_KEYS))))
def test_random_text_into_the_lab_config_is_a_lab_or_one_line(lab_dir, capsys, value, which):
    """A value of the lab config replaced by random text: `run --dry-run` plans (0) or
    refuses with one line naming file:line: field (2)."""
    from normbox_lab.cli import main

    TRIED["n"] += 1
    table, key = CONFIG_KEYS[which]
    text = _with_value((lab_dir / "lab.toml").read_text(), table, key, value.replace("\x00", ""))
    (lab_dir / "fuzzed.toml").write_text(text, encoding="utf-8")
    capsys.readouterr()
    code = main(["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab",
                 str(lab_dir / "fuzzed.toml"), "--store", str(lab_dir / "dry.sqlite"),
                 "--param", "angles_deg=[30]"])
    err = capsys.readouterr().err
    _refusal_or_run(code, err)
    if code == 2:
        assert "fuzzed.toml:" in err, err


FAULT_ALPHABET = st.sampled_from(["garble", "late-reply", "disconnect", "bogus", "=", "@", ":",
                                  ",", "0", "1", "3", ".5", "e9", "-", "NaN", "٣", "１",
                                  "9" * 30, " ", "&", "%40", "seed=", "key="])


@settings(max_examples=300, deadline=None)
@given(spec=st.one_of(TEXT, st.lists(FAULT_ALPHABET, max_size=12).map("".join)))
def test_random_fault_specs_are_rules_or_one_line(spec):
    TRIED["n"] += 1
    try:
        rules = P.parse_fault_spec(spec, "faults")
    except ParameterError as exc:
        _one_line(exc)
        return
    assert len({r.kind for r in rules}) == len(rules)
    for r in rules:
        assert r.mode in "=@" and math.isfinite(r.value)
        assert 0 <= r.value <= 1 if r.mode == "=" else isinstance(r.value, int) and r.value >= 1
        assert r.param is None or math.isfinite(r.param)
    assert all(ch.isascii() for ch in spec if ch.isdigit())


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(spec=st.lists(FAULT_ALPHABET, max_size=10).map("".join))
def test_random_fault_specs_in_the_lab_config_ports_are_checked_before_a_run(lab_dir, capsys,
                                                                              spec):
    """``sim://cs1000a?faults=SPEC`` in the lab config: read by the one parser and checked
    against the emulator's kinds before any run starts (``garble@٣`` was read by float()
    as 3; an unknown kind failed at the first open, after the run had started, exit 1)."""
    from normbox_lab.cli import main

    TRIED["n"] += 1
    text = (lab_dir / "lab.toml").read_text().replace(
        'port = "sim://cs1000a"', f'port = "sim://cs1000a?faults={spec}"')
    (lab_dir / "faulty.toml").write_text(text, encoding="utf-8")
    capsys.readouterr()
    code = main(["run", "reference-sweep", "--dry-run", "--world", "analytic", "--lab",
                 str(lab_dir / "faulty.toml"), "--store", str(lab_dir / "dry.sqlite"),
                 "--param", "angles_deg=[30]"])
    err = capsys.readouterr().err
    _refusal_or_run(code, err)
    if code == 2:
        assert "faulty.toml:" in err and "instruments.radiometer.port" in err, err


@pytest.mark.parametrize("spec, expect", [
    ("garble@٣", "faults 'garble@٣': N: '٣' has digits of another script; use the digits 0-9"),
    ("garble=NaN", "faults 'garble=NaN': P: NaN is not a finite number"),
    ("garble@" + "9" * 30, "N: a 30-digit number is above 1e+09"),
    ("garble,garble=0.1", "garble is given twice; one rule per kind"),
    ("bogus@3", "unknown fault kind 'bogus'; known: no-reply, late-reply"),
    ("late-reply=0.5:1e9", "the parameter of late-reply (s) lies in 0.05 … 600"),
])
def test_fault_specs_of_the_lab_config_exit_2_with_one_line(lab_dir, capsys, spec, expect):
    from normbox_lab.cli import main

    text = (lab_dir / "lab.toml").read_text().replace(
        'port = "sim://cs1000a"', f'port = "sim://cs1000a?faults={spec}"')
    (lab_dir / "faulty.toml").write_text(text, encoding="utf-8")
    capsys.readouterr()
    assert main(["run", "reference-sweep", "--world", "analytic", "--plain", "--lab",
                 str(lab_dir / "faulty.toml"), "--store", str(lab_dir / "never.sqlite"),
                 "--param", "angles_deg=[30]", "--param", "patches=[1]"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("normbox-lab: error: ") and err.count("\n") == 1, err
    assert "instruments.radiometer.port: " in err and expect in err, err
    assert "run " not in capsys.readouterr().out            # refused before a run started


@pytest.mark.parametrize("replay, expect", [
    ('["radiometer","garble","=",NaN,null]', "garble: NaN is not a finite number"),
    ('["radiometer","garble","@",1e400,null]', "garble: Infinity is not a finite number"),
    ('["radiometer","bogus","@",3,null]', "unknown fault kind 'bogus'"),
    ('["wizard","garble","@",3,null]', "'wizard': not a role of a campaign's lab"),
])
def test_a_replays_faults_go_through_the_same_kinds(capsys, replay, expect):
    from normbox_lab.cli import main

    scenario = ('{"seed":1,"index":0,"protocol":"reference-sweep","params":{},'
                f'"faults":[{replay}]}}')
    capsys.readouterr()
    assert main(["sim", "campaign", "--replay", scenario]) == 2
    err = capsys.readouterr().err
    assert err.startswith("normbox-lab: --replay: ") and err.count("\n") == 1, err
    assert expect in err, err


PROTOCOL_TEXT = st.one_of(
    TEXT,
    TEXT.map(lambda t: f"PARAMETERS = {t}\ndef steps(params, lab=None):\n    return []\n"),
    TEXT.map(lambda t: "PARAMETERS = {}\ndef steps(params, lab=None):\n"
                       f"    return {t}\n"),
    TEXT.map(lambda t: f"from normbox_lab.acquire.engine import measure\n"
                       f"PARAMETERS = {{'a': 1}}\ndef steps(params, lab=None):\n"
                       f"    return [measure({t!r}, 'radiometer')]\n"))


@settings(max_examples=150, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(source=PROTOCOL_TEXT)
def test_random_protocol_files_are_a_plan_or_one_line(lab_dir, capsys, source):
    """A protocol file of random text (a syntax error, PARAMETERS of another type, steps()
    that raises or returns no steps): exit 2 with one error line naming the file and line,
    never a traceback (the notice that the file is Python code run with your rights comes
    only once the run is accepted)."""
    import hashlib

    from normbox_lab.cli import main

    TRIED["n"] += 1
    path = lab_dir / f"p{hashlib.sha1(source.encode('utf-8', 'replace')).hexdigest()[:10]}.py"
    path.write_text(source, encoding="utf-8", errors="replace")
    capsys.readouterr()
    code = main(["run", str(path), "--dry-run", "--world", "analytic", "--lab",
                 str(lab_dir / "lab.toml"), "--store", str(lab_dir / "dry.sqlite")])
    err = capsys.readouterr().err
    _refusal_or_run(code, err)
    if code == 2:
        assert str(path) in err.splitlines()[-1], err


@pytest.mark.parametrize("source, expect", [
    ('PARAMETERS = {"x": 1\n', ":1: cannot be loaded: SyntaxError: '{' was never closed"),
    ("PARAMETERS = {}\nimport no_such_module_here\ndef steps(p, lab=None): return []\n",
     ":2: cannot be loaded: ModuleNotFoundError: No module named 'no_such_module_here'"),
    ("PARAMETERS = [1]\ndef steps(p, lab=None): return []\n",
     ": PARAMETERS must be a dict of names to defaults, not list"),
    ("PARAMETERS = {}\ndef steps(p, lab=None):\n    return 1 / 0\n",
     ":3: steps() failed: ZeroDivisionError: division by zero"),
    ("PARAMETERS = {}\ndef steps(p, lab=None): return 5\n",
     ": steps() must return a list of steps, not int"),
])
def test_a_broken_protocol_file_is_one_line_naming_its_line(tmp_path, capsys, source, expect):
    from normbox_lab.cli import main

    path = tmp_path / "mine.py"
    path.write_text(source)
    assert main(["init", str(tmp_path / "lab.toml"), "--sim"]) == 0
    capsys.readouterr()
    assert main(["run", str(path), "--dry-run", "--world", "analytic", "--lab",
                 str(tmp_path / "lab.toml"), "--store", str(tmp_path / "s.sqlite")]) == 2
    last = capsys.readouterr().err.splitlines()[-1]
    assert last == f"normbox-lab: error: protocol file {path}{expect}", last


def test_zz_report_inputs_tried(capsys):
    """Prints how many random inputs the tests above tried (run with -s to see it)."""
    with capsys.disabled():
        print(f"\nrandom inputs tried: {TRIED['n']}")
    assert TRIED["n"] > 0
