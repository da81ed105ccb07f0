"""`normbox-lab lab check`: the self-test protocol on the virtual lab — every check passes on a
healthy lab and is stored with its limit and source; a fault injected into each instrument is
caught by the check meant for it; a sweep can require a recent passing check."""

from __future__ import annotations

import datetime
import time

import pytest

from normbox_lab import cli
from normbox_lab.acquire import trust
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, load_config
from normbox_lab.acquire.session import open_run
from normbox_lab.acquire.store import Store
from normbox_lab.core.errors import NotReady
from normbox_lab.protocols import lab_check
from normbox_lab.sim.labsim import build_lab

ALL_CHECKS = [
    "rotator/identity", "rotator/home", "rotator/soft-limits", "rotator/move-readback",
    "rotator/backlash", "gonio_light_arm/identity", "gonio_light_arm/home",
    "gonio_light_arm/soft-limits", "gonio_light_arm/travel", "gonio_detector_arm/identity",
    "gonio_detector_arm/home", "gonio_detector_arm/soft-limits", "gonio_detector_arm/travel", "sphere/identity", "sphere/warm-up",
    "radiometer/identity", "radiometer/level", "radiometer/repeatability", "radiometer/dark",
    "spectrometer/identity", "spectrometer/tec", "spectrometer/dark-current",
    "spectrometer/nonlinearity"]


def lab_toml(tmp_path, *replacements: tuple[str, str], name: str = "lab.toml"):
    text = SIM_CONFIG_TEMPLATE
    for old, new in replacements:
        assert old in text, old
        text = text.replace(old, new, 1)
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return load_config(path)


def check(config, store_path, **overrides):
    return lab_check.run_check(config, str(store_path), overrides, make_lab=build_lab,
                               world="analytic")


def keyed(report):
    return {f"{r['role']}/{r['check']}": r for r in report.results}


def test_every_check_passes_on_the_virtual_lab_and_is_stored_with_limit_and_source(tmp_path):
    report = check(lab_toml(tmp_path), tmp_path / "s.sqlite")
    assert report.status == "done" and report.passed, report.lines()
    results = keyed(report)
    assert list(results) == ALL_CHECKS
    measured = {k: r for k, r in results.items() if r["value"] is not None}
    for key, r in measured.items():
        assert r["limit"] and r["source"], key          # every limit names its source
    assert results["rotator/move-readback"]["value"] == pytest.approx(45.0, abs=0.05)
    assert results["spectrometer/tec"]["value"] == pytest.approx(-10.0, abs=0.5)
    assert results["radiometer/dark"]["value"] < 0.05 < results["radiometer/level"]["value"]
    with Store(tmp_path / "s.sqlite", read_only=True) as store:
        run = store.get_run(report.run_id)
        assert (run.protocol, run.status, run.done) == ("lab-check", "done", len(ALL_CHECKS))
        stored = store.reading(report.run_id, "radiometer/repeatability")
        assert stored.kind == "check" and len(stored.arrays["samples"]) == 3
    assert report.lines()[-1].endswith(f"done, {len(ALL_CHECKS)}/{len(ALL_CHECKS)} checks passed")


@pytest.mark.parametrize(("old", "new", "roles", "caught"), [
    ('port = "sim://cs1000a"', 'port = "sim://cs1000a?faults=over-range"',
     ["radiometer"], "radiometer/level"),
    ('port = "sim://rotator-apt"', 'port = "sim://rotator-apt?faults=stall"',
     ["rotator"], "rotator/move-readback"),
    ('port = "sim://sphere"', 'port = "sim://sphere?faults=lamp-fail"',
     ["sphere"], "sphere/warm-up"),
    ('port = "sim://qepro"', 'port = "sim://qepro?faults=tec-drift"',
     ["spectrometer"], "spectrometer/tec"),
    ('port = "sim://rotator-zaber?key=gonio-light"',
     'port = "sim://rotator-zaber?key=gonio-light&faults=stall"',
     ["gonio_light_arm"], "gonio_light_arm/travel"),
])
def test_a_fault_in_each_instrument_is_caught_by_its_check(tmp_path, old, new, roles, caught):
    report = check(lab_toml(tmp_path, (old, new)), tmp_path / "s.sqlite", roles=roles)
    assert not report.passed
    failed = [k for k, r in keyed(report).items() if not r["passed"]]
    assert failed[0] == caught, report.lines()
    # the same checks on the healthy instrument pass
    healthy = check(lab_toml(tmp_path, name="ok.toml"), tmp_path / "ok.sqlite", roles=roles)
    assert healthy.passed, healthy.lines()


def test_dark_current_is_judged_against_the_labs_history(tmp_path):
    store = tmp_path / "s.sqlite"
    first = check(lab_toml(tmp_path), store, roles=["spectrometer"])
    assert first.passed
    drifted = check(lab_toml(tmp_path, ('port = "sim://qepro"',
                                        'port = "sim://qepro?faults=dark-drift"')),
                    store, roles=["spectrometer"])
    r = keyed(drifted)["spectrometer/dark-current"]
    assert not r["passed"] and f"run {first.run_id}" in r["source"]
    assert r["value"] > 2 * keyed(first)["spectrometer/dark-current"]["value"]
    # a run with a failure is no reference: the next check still compares with the first
    again = check(lab_toml(tmp_path), store, roles=["spectrometer"])
    assert again.passed and f"run {first.run_id}:" in \
        keyed(again)["spectrometer/dark-current"]["source"]


def test_an_instrument_with_another_serial_number_fails_its_identity(tmp_path):
    config = lab_toml(tmp_path, ('port = "sim://rotator-apt"',
                                 'port = "sim://rotator-apt"\nserial_number = "55999999"'))
    r = keyed(check(config, tmp_path / "s.sqlite", roles=["rotator"]))["rotator/identity"]
    assert not r["passed"] and "'55123456' is not the configured '55999999'" in r["message"]


CALIBRATION = """
[instruments.radiometer.calibration]
certificate = "KM-2024-0815"
date = {date}
due = {due}
laboratory = "Konica Minolta Sensing Europe"
uncertainty_percent = 2.0
"""


def calibrated(tmp_path, due: datetime.date, name: str = "lab.toml"):
    block = CALIBRATION.format(date=due - datetime.timedelta(days=365), due=due)
    return lab_toml(tmp_path, ("[instruments.rotator]", block + "\n[instruments.rotator]"),
                    name=name)


def test_an_expired_calibration_is_a_warning_and_fails_under_strict(tmp_path):
    expired = calibrated(tmp_path, datetime.date.today() - datetime.timedelta(days=10))
    report = check(expired, tmp_path / "s.sqlite", roles=["radiometer"])
    r = keyed(report)["radiometer/calibration"]
    assert r["passed"] and "EXPIRED 10 days ago" in r["warning"] and report.passed
    assert "PASS (warning) radiometer/calibration" in "\n".join(report.lines())
    with Store(tmp_path / "s.sqlite", read_only=True) as store:
        flags = {(f["key"], f["gate"], f["severity"])
                 for f in store.flag_rows(run_id=report.run_id)}
    # the check's own warning, and the one every run gets from the calibration it rests on
    assert flags == {("radiometer/calibration", "calibration", "warning"),
                     ("calibration/radiometer", "calibration", "warning")}
    strict = check(expired, tmp_path / "s.sqlite", roles=["radiometer"], strict=True)
    assert not strict.passed and not keyed(strict)["radiometer/calibration"]["passed"]
    fresh = calibrated(tmp_path, datetime.date.today() + datetime.timedelta(days=30), "b.toml")
    r = keyed(check(fresh, tmp_path / "b.sqlite", roles=["radiometer"]))["radiometer/calibration"]
    assert r["passed"] and not r["warning"] and r["value"] == 30.0


def test_a_sweep_can_require_a_recent_passing_check(tmp_path):
    config = lab_toml(tmp_path, ("seed = 1", "seed = 1\nrequire_check_h = 24"))
    store_path = tmp_path / "s.sqlite"
    with Store(store_path) as store, pytest.raises(NotReady, match="has none"):
        open_run("reference-sweep", store=store, config=config, make_lab=build_lab,
                 world="analytic")
    assert check(config, store_path, roles=["rotator"]).passed
    with Store(store_path) as store:
        with open_run("reference-sweep", store=store, config=config, make_lab=build_lab,
                      world="analytic", params={"angles_deg": [30], "patches": [1]}) as opened:
            assert opened.run().status == "done"
        _, at_s = trust.last_passing_check(store)
        trust.require_recent_check(store, 24.0, at_s + 23.9 * 3600)
        with pytest.raises(NotReady, match="is 25.0 h old"):
            trust.require_recent_check(store, 24.0, at_s + 25.0 * 3600)
    assert abs(at_s - time.time()) < 600


def test_cli_prints_pass_fail_per_check_and_exits_nonzero_on_a_failure(tmp_path, capsys):
    lab_toml(tmp_path, ('port = "sim://rotator-apt"', 'port = "sim://rotator-apt?faults=stall"'))
    rc = cli.main(["lab", "check", "--lab", str(tmp_path / "lab.toml"), "--store",
                   str(tmp_path / "s.sqlite"), "--roles", "rotator"])
    out = capsys.readouterr().out.splitlines()
    assert rc == 1
    assert [line.split(":")[0] for line in out[:5]] == [
        "PASS rotator/identity", "PASS rotator/home", "PASS rotator/soft-limits",
        "FAIL rotator/move-readback", "FAIL rotator/backlash"]
    assert "POSITION" in out[3] and out[-1].endswith("3/5 checks passed, 2 FAILED")
