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


def test_zz_report_inputs_tried(capsys):
    """Prints how many random inputs the tests above tried (run with -s to see it)."""
    with capsys.disabled():
        print(f"\nrandom inputs tried: {TRIED['n']}")
    assert TRIED["n"] > 0


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
