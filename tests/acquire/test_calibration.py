"""Calibration records: the lab config states each instrument's certificate, a run stores the
calibrations in force with the instruments, the report's Methods shows them, and an expired one
is a quality warning of every run that rests on it (an error under --strict)."""

from __future__ import annotations

import datetime
import hashlib

import pytest

from normbox_lab import cli
from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, format_config, load_config, parse_config
from normbox_lab.acquire.session import open_run
from normbox_lab.acquire.store import Store
from normbox_lab.analyze.report import build_html
from normbox_lab.analyze.report_data import ReportData
from normbox_lab.analyze.report_store import campaign_instruments
from normbox_lab.core.errors import ConfigError
from normbox_lab.sim.labsim import build_lab

TODAY = datetime.date.today()


def with_calibration(body: str, *, role: str = "radiometer", before: str = "[instruments.rotator]"
                     ) -> str:
    return SIM_CONFIG_TEMPLATE.replace(before, f"[instruments.{role}.calibration]\n{body}\n"
                                       f"{before}", 1)


def cal_body(date: datetime.date, due: datetime.date, extra: str = "") -> str:
    return (f'certificate = "KM-2024-0815"\ndate = {date}\ndue = {due}\n'
            f'laboratory = "Konica Minolta Sensing Europe"\nuncertainty_percent = 2.0\n{extra}')


def test_config_reads_a_calibration_and_writes_it_back(tmp_path):
    (tmp_path / "cal").mkdir()
    csv = tmp_path / "cal" / "cs1000a.csv"
    csv.write_text("wavelength_nm,factor\n380,1.02\n780,0.99\n", encoding="utf-8")
    text = with_calibration(cal_body(datetime.date(2026, 3, 2), datetime.date(2027, 3, 2),
                                     'coverage_k = 2.0\nresponsivity_file = "cal/cs1000a.csv"\n'))
    path = tmp_path / "lab.toml"
    path.write_text(text, encoding="utf-8")
    cal = load_config(path).instruments["radiometer"].calibration
    assert (cal.certificate, cal.date, cal.due, cal.uncertainty_percent, cal.responsivity_file) \
        == ("KM-2024-0815", datetime.date(2026, 3, 2), datetime.date(2027, 3, 2), 2.0,
            "cal/cs1000a.csv")
    assert cal.responsivity_sha256 == hashlib.sha256(csv.read_bytes()).hexdigest()
    again = tmp_path / "again.toml"
    again.write_text(format_config(load_config(path)), encoding="utf-8")
    assert load_config(again).instruments["radiometer"].calibration == cal


@pytest.mark.parametrize(("body", "message"), [
    (cal_body(datetime.date(2026, 3, 2), datetime.date(2026, 3, 1)),
     "lab.toml:18: instruments.radiometer.calibration.due: must be after the calibration date"),
    ('certificate = "X"\ndate = 2026-03-02\ndue = 2027-03-02\nuncertainty_percent = 2.0',
     "lab.toml:15: instruments.radiometer.calibration: laboratory missing"),
    (cal_body(datetime.date(2026, 3, 2), datetime.date(2027, 3, 2)).replace(
        "due = 2027-03-02", 'due = "next year"'),
     "lab.toml:18: instruments.radiometer.calibration.due: must be a date (2026-03-02), got 'next"),
    (cal_body(datetime.date(2026, 3, 2), datetime.date(2027, 3, 2),
              'responsivity_file = "no.csv"'),
     "lab.toml:21: instruments.radiometer.calibration.responsivity_file: cannot read"),
    (cal_body(datetime.date(2026, 3, 2), datetime.date(2027, 3, 2), "expires = 2027-01-01"),
     "lab.toml:21: instruments.radiometer.calibration.expires: unknown field"),
])
def test_a_bad_calibration_is_refused_with_file_line_and_field(tmp_path, body, message):
    with pytest.raises(ConfigError) as info:
        parse_config(with_calibration(body), str(tmp_path / "lab.toml"))
    assert str(info.value).startswith(str(tmp_path / "lab.toml") + message.removeprefix(
        "lab.toml")), str(info.value)


def run_sweep(config, store_path):
    with Store(store_path) as store, open_run(
            "reference-sweep", store=store, config=config, make_lab=build_lab, world="analytic",
            params={"angles_deg": [30], "patches": [1]}) as opened:
        return opened.run().run_id


def test_a_run_records_the_calibration_in_force_and_warns_when_it_expired(tmp_path):
    expired = parse_config(with_calibration(cal_body(TODAY - datetime.timedelta(days=400),
                                                     TODAY - datetime.timedelta(days=35))),
                           str(tmp_path / "lab.toml"))
    run_id = run_sweep(expired, tmp_path / "s.sqlite")
    with Store(tmp_path / "s.sqlite", read_only=True) as store:
        rows = {i["role"]: i["calibration"] for i in store.instruments(run_id)}
        assert rows["radiometer"]["certificate"] == "KM-2024-0815"
        assert rows["radiometer"]["due"] == str(TODAY - datetime.timedelta(days=35))
        assert rows["rotator"] == {} and rows["sphere"] == {}
        flags = store.flag_rows(run_id=run_id)
        assert [(f["key"], f["gate"], f["severity"]) for f in flags] == [
            ("calibration/radiometer", "calibration", "warning")]
        assert "expired on" in flags[0]["message"] and "35 days before this run" in \
            flags[0]["message"]
        instruments = campaign_instruments(store, [run_id])
    html, *_ = build_html(ReportData(instruments=instruments))
    methods = html[html.index('<section id="methods">'):]
    table = methods[methods.index('id="tab-calibrations"'):]
    assert "<h3>Calibrations</h3>" in table and "KM-2024-0815" in table
    assert "Konica Minolta Sensing Europe" in table and "±2.0 % (k=2.0)" in table
    assert f"EXPIRED in run {run_id} ({TODAY}" in table


def test_a_calibration_in_force_gives_no_flag(tmp_path):
    fresh = parse_config(with_calibration(cal_body(TODAY - datetime.timedelta(days=30),
                                                   TODAY + datetime.timedelta(days=335))))
    run_id = run_sweep(fresh, tmp_path / "s.sqlite")
    with Store(tmp_path / "s.sqlite", read_only=True) as store:
        assert store.flag_rows(run_id=run_id) == []
        rows = campaign_instruments(store, [run_id])
    record = next(r for r in rows if r["role"] == "radiometer")["calibration_record"]
    assert record["expired_in_runs"] == []
    html, *_ = build_html(ReportData(instruments=rows))
    assert ">in force<" in html


def test_lab_calibrations_lists_them_and_strict_fails_on_an_expired_one(tmp_path, capsys):
    path = tmp_path / "lab.toml"
    path.write_text(with_calibration(cal_body(TODAY - datetime.timedelta(days=400),
                                              TODAY - datetime.timedelta(days=2))),
                    encoding="utf-8")
    assert cli.main(["lab", "calibrations", "--lab", str(path)]) == 0
    out = capsys.readouterr()
    assert "radiometer: certificate KM-2024-0815" in out.out and "EXPIRED 2 days ago" in out.out
    assert "rotator: no calibration recorded" in out.out
    assert "warning: 1 expired calibration(s)" in out.err
    assert cli.main(["lab", "calibrations", "--lab", str(path), "--strict"]) == 1
    assert "error: 1 expired calibration(s)" in capsys.readouterr().err
