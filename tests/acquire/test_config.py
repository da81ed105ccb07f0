import math

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from normbox_lab.acquire.config import (
    SIM_CONFIG_TEMPLATE,
    load_config,
    parse_config,
    write_sim_config,
)
from normbox_lab.core.errors import ConfigError


def test_template_is_a_complete_simulated_lab(tmp_path):
    path = write_sim_config(tmp_path / "lab.toml")
    cfg = load_config(path)
    assert cfg.simulated and cfg.time_scale == 0.0
    assert set(cfg.instruments) == {"radiometer", "rotator", "sphere", "gonio_light_arm",
                                    "gonio_detector_arm", "spectrometer"}
    assert all(i.simulated for i in cfg.instruments.values())
    assert cfg.geometry.box_inner_mm == 600.0 and cfg.geometry.aperture_x_mm == 220.0
    assert cfg.protocol_defaults("reference-sweep")["angles_deg"][0] == 30
    assert cfg.text == SIM_CONFIG_TEMPLATE
    with pytest.raises(ConfigError, match="exists already"):
        write_sim_config(path)


@pytest.mark.parametrize("old,new,field", [
    ('baud = 9600', 'baud = 1234', "instruments.radiometer.baud"),
    ('driver = "sphere-scpi"', 'driver = "lamp9000"', "instruments.sphere.driver"),
    ('patch_size_mm = 50.0', 'patch_size_mm = "big"', "geometry.patch_size_mm"),
    ('box_inner_mm = 600.0', 'box_inner_mm = -600.0', "geometry.box_inner_mm"),
    ('max_angle_deg = 95.0', 'max_angle_deg = -5.0', "instruments.rotator.max_angle_deg"),
    ('quality = "default"', 'quality = "ultra"', "render.quality"),
    ('seed = 1', 'seed = "one"', "lab.seed"),
])
def test_errors_name_file_line_and_field(old, new, field):
    assert old in SIM_CONFIG_TEMPLATE
    text = SIM_CONFIG_TEMPLATE.replace(old, new, 1)
    with pytest.raises(ConfigError) as info:
        parse_config(text, "lab.toml")
    err = info.value
    assert (err.file, err.field) == ("lab.toml", field)
    line = next(i for i, t in enumerate(text.splitlines(), 1) if t.strip().startswith(new))
    assert err.line == line
    assert str(err).startswith(f"lab.toml:{line}: {field}:")


def test_cs2000a_has_a_fixed_baud_rate():
    text = SIM_CONFIG_TEMPLATE.replace('driver = "cs1000a"', 'driver = "cs2000a"', 1)
    with pytest.raises(ConfigError, match="115200 baud only"):
        parse_config(text, "lab.toml")
    assert parse_config(text.replace("baud = 9600", "baud = 115200")).instruments[
        "radiometer"].options["baud"] == 115200


def test_syntax_error_has_its_line():
    with pytest.raises(ConfigError) as info:
        parse_config("[lab]\nname = \"x\"\nseed = = 3\n", "bad.toml")
    assert info.value.line == 3 and info.value.field == "(syntax)"


def test_missing_role_and_missing_file(tmp_path):
    text = SIM_CONFIG_TEMPLATE.replace("[instruments.sphere]", "[instruments.spherex]")
    with pytest.raises(ConfigError, match="instruments.spherex"):
        parse_config(text, "lab.toml")
    with pytest.raises(ConfigError, match="no such file"):
        load_config(tmp_path / "nope.toml")


_values = st.one_of(st.integers(-10**6, 10**6), st.floats(allow_nan=True), st.text(max_size=8),
                    st.booleans(), st.lists(st.integers(), max_size=3))


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v == float("inf") else
                                     "-inf" if v == float("-inf") else repr(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'
    return repr(v)


@settings(max_examples=150, suppress_health_check=[HealthCheck.too_slow], deadline=None)
@given(line_no=st.integers(0, SIM_CONFIG_TEMPLATE.count("\n") - 1), value=_values)
def test_any_field_with_any_value_gives_a_typed_error_or_a_config(line_no, value):
    lines = SIM_CONFIG_TEMPLATE.splitlines()
    if "=" in lines[line_no] and not lines[line_no].lstrip().startswith("#"):
        key = lines[line_no].split("=")[0]
        lines[line_no] = f"{key}= {_toml_value(value)}"
    try:
        parse_config("\n".join(lines), "fuzz.toml")
    except ConfigError as err:
        assert err.file == "fuzz.toml" and err.field and 0 <= err.line <= len(lines)


@settings(max_examples=200, deadline=None)
@given(st.text(max_size=300))
def test_arbitrary_text_gives_only_config_errors(text):
    try:
        parse_config(text, "junk.toml")
    except ConfigError as err:
        assert err.file == "junk.toml"


def test_format_config_round_trips_the_dataclasses():
    """A config changed with dataclasses.replace and written by format_config reads back equal."""
    from dataclasses import replace

    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, format_config, parse_config

    base = parse_config(SIM_CONFIG_TEMPLATE)
    radiometer = replace(base.instruments["radiometer"], port='sim://cs1000a?noise=off')
    changed = replace(base, seed=7, name='Lab "B"',
                      instruments={**base.instruments, "radiometer": radiometer},
                      render={**base.render, "quality": "quick", "cache_dir": "C:\\cache"})
    back = parse_config(format_config(changed))
    assert base.quality.lamp_reference_cd_m2 == 2000.0     # the template's lamp reference
    for f in ("name", "simulated", "time_scale", "seed", "instruments", "geometry",
              "protocols", "render", "quality"):
        assert getattr(back, f) == getattr(changed, f), f


def test_demo_config_is_built_from_the_dataclasses(tmp_path):
    from normbox_lab.acquire.config import format_config, parse_config
    from normbox_lab.demo import DemoOptions, demo_config

    cfg = demo_config(DemoOptions(noise=False, seed=3), "quick", tmp_path)
    back = parse_config(format_config(cfg))
    assert back.seed == 3 and back.render["quality"] == "quick"
    assert back.instruments["radiometer"].port == "sim://cs1000a?noise=off"
    assert back.instruments["gonio_light_arm"].port == "sim://rotator-zaber?key=gonio-light"
