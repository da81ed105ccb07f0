"""A run resumes in the world and lab it was measured in, with a complete printed command.

Reported: a run quit in `tui --world analytic` and resumed with the printed
`run --resume <uuid> --store …` ran on the Mitsuba world (the console never recorded its
world), and the printed line lacked `--lab`.  Now every segment records its world, lab
config, time scale and seed; a resume under another world or lab config is one line and
exit 2 unless `--force`; the printed command, run as it is, finishes the run.
"""

from __future__ import annotations

import shlex
from pathlib import Path

import pytest

from normbox_lab.acquire import engine as eng
from normbox_lab.acquire.store import Store
from normbox_lab.cli import main

SMALL = ["--param", "angles_deg=[30,90]", "--param", "patches=[1,19]"]


def _pause_after(key: str):
    """Engine.run that pauses after `key` is stored (what Ctrl-C does)."""
    original = eng.Engine.run

    def run_and_pause(self, resume=None):
        self.subscribe(lambda ev: self.pause() if ev.kind == "reading-stored"
                       and ev.key == key else None)
        return original(self, resume)
    return original, run_and_pause


def _paused_run(capsys, *argv: str) -> str:
    original, patched = _pause_after("a30/p19")
    eng.Engine.run = patched
    try:
        assert main(["run", "reference-sweep", "--plain", *argv, *SMALL]) == 3
    finally:
        eng.Engine.run = original
    out = capsys.readouterr().out
    return out.splitlines()[-1]


def _one_line_exit_2(capsys, argv: list[str], expect: str) -> None:
    assert main(argv) == 2
    err = capsys.readouterr().err
    errors = [ln for ln in err.splitlines() if "error" in ln]   # (a note may precede it)
    assert len(errors) == 1 and errors[0].startswith(f"normbox-lab: error: {expect}"), err
    assert "Traceback" not in err


def test_cli_resume_under_another_world_or_lab_is_refused_and_the_printed_command_finishes(
        tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "lab.toml", "--sim"]) == 0
    capsys.readouterr()
    line = _paused_run(capsys, "--lab", "lab.toml", "--store", "s.sqlite", "--world",
                       "analytic", "--time-scale", "0")
    command = line.split("resume with: ")[1]
    assert command == ("normbox-lab run reference-sweep --resume 1 --store s.sqlite --lab "
                       "lab.toml --world analytic --time-scale 0")
    with Store("s.sqlite") as s:
        (seg,) = [d for _, k, d in s.events(1) if k == "segment"]
    assert seg["world"] == "analytic" and seg["lab"].endswith("lab.toml")
    assert seg["time_scale"] == 0 and seg["seed"] == 1

    # another world: refused before any world is built (the Mitsuba one took 73 s)
    _one_line_exit_2(capsys, ["run", "--resume", "1", "--store", "s.sqlite", "--lab", "lab.toml",
                              "--world", "normbox"],
                     "run ")
    # another lab config (another seed: another simulated truth)
    other = Path("other.toml")
    other.write_text(Path("lab.toml").read_text().replace("seed = 1", "seed = 5"))
    assert "seed = 5" in other.read_text()
    _one_line_exit_2(capsys, ["run", "--resume", "1", "--store", "s.sqlite", "--lab",
                              "other.toml", "--world", "analytic"], "run ")
    with Store("s.sqlite") as s:
        assert s.get_run(1).status == "paused" and len(s.keys(1)) == 2

    # the printed command, as it is
    argv = shlex.split(command)
    assert argv[0] == "normbox-lab"
    assert main([*argv[1:], "--plain"]) == 0
    out = capsys.readouterr().out
    assert "done, 4/4 readings (2 taken now)" in out
    with Store("s.sqlite") as s:
        worlds = [d["world"] for _, k, d in s.events(1) if k == "segment"]
    assert worlds == ["analytic", "analytic"]


def test_the_refusals_name_the_world_and_the_lab(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["init", "lab.toml", "--sim"]) == 0
    capsys.readouterr()
    _paused_run(capsys, "--store", "s.sqlite", "--world", "analytic")
    with Store("s.sqlite") as s:
        uuid = s.get_run(1).uuid
    _one_line_exit_2(capsys, ["run", "--resume", "1", "--store", "s.sqlite", "--world",
                              "normbox"],
                     f"run {uuid} was measured in the 'analytic' world, not 'normbox': resume "
                     "it with --world analytic")
    Path("other.toml").write_text(Path("lab.toml").read_text().replace("seed = 1",
                                                                       "seed = 5"))
    _one_line_exit_2(capsys, ["run", "--resume", "1", "--store", "s.sqlite", "--lab",
                              "other.toml"],
                     f"run {uuid} was measured with another lab config (seed differ in "
                     "other.toml)")
    # --force: resumed anyway (the operator's decision, recorded with the segment)
    assert main(["run", "--resume", "1", "--store", "s.sqlite", "--lab", "other.toml",
                 "--force", "--plain"]) == 0
    assert "done, 4/4 readings (2 taken now)" in capsys.readouterr().out


def test_the_console_records_its_world_and_a_resume_elsewhere_is_refused(tmp_path, capsys,
                                                                         monkeypatch):
    """A run started in the console (`tui --world analytic`) records its world; the printed
    `run --resume` without --world resumes it there, and --world normbox is refused."""
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.tui.controller import Session

    monkeypatch.chdir(tmp_path)
    config = parse_config(SIM_CONFIG_TEMPLATE, "<simulated template>")
    session = Session(config, tmp_path / "c.sqlite", world="analytic", virtual_operator=True,
                      time_scale=0.0)
    try:
        engine = session.make_engine("reference-sweep",
                                     {"angles_deg": [30, 90], "patches": [1, 19]})
        engine.subscribe(lambda ev: engine.stop() if ev.kind == "reading-stored" else None)
        result = engine.run()
        assert result.status == "paused" and result.done == 1
    finally:
        session.close()
    with Store(tmp_path / "c.sqlite") as s:
        (seg,) = [d for _, k, d in s.events(result.run_id) if k == "segment"]
    assert seg["world"] == "analytic" and seg["time_scale"] == 0.0
    _one_line_exit_2(capsys, ["run", "--resume", str(result.run_id), "--store", "c.sqlite",
                              "--world", "normbox"], f"run {result.uuid} was measured in the "
                     "'analytic' world")
    assert main(["run", "--resume", str(result.run_id), "--store", "c.sqlite", "--plain"]) == 0
    assert "done, 4/4 readings (3 taken now)" in capsys.readouterr().out


@pytest.mark.parametrize("world", ["normbox", "analytic"])
def test_resume_command_is_quoted_for_the_shell(world):
    from normbox_lab.commands.run import resume_command

    cmd = resume_command("/tmp/my protocols/sweep.py", "ab12", store="my store.sqlite",
                         lab="lab dir/lab.toml", world=world, time_scale=0.2)
    assert shlex.split(cmd) == ["normbox-lab", "run", "/tmp/my protocols/sweep.py", "--resume",
                                "ab12", "--store", "my store.sqlite", "--lab",
                                "lab dir/lab.toml", "--world", world, "--time-scale", "0.2"]
