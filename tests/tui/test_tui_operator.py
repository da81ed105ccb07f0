"""Pilot tests of the operator console's traps and status lines: tab keys work from every
tab, the rating colours are distinct, and the remaining-time line tells the truth (measured
wall-clock rate in a simulated lab, nothing after an abort)."""

from __future__ import annotations

import asyncio

from pilot import (
    answer_prompt,
    new_session,
    screen_text,
    set_reduced_parameters,
    until,
)
from textual.widgets import Static, TabbedContent

from normbox_lab.tui.app import NormboxConsole, PromptScreen
from normbox_lab.tui.tabs.instruments import INSTRUMENT_COLUMNS
from normbox_lab.tui.views import RATING_STYLES


async def start_and_wait_for_the_second_prompt(pilot, app, parameters: bool = True) -> None:
    """Reduced sweep started, the first patch placed: the run waits at the second prompt
    with one reading committed."""
    if parameters:
        await set_reduced_parameters(pilot, app)
    await pilot.press("s")
    await answer_prompt(pilot, app, "patch 1 ")
    await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 2")


def test_tab_keys_work_from_the_runs_tab_also_after_tab_focus(lab_env):
    """The Runs tab used to trap 2, 3 and 6: focus stayed on its hidden table and the tabbed
    container switched back to the pane holding the focused widget."""
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            tabs = app.query_one(TabbedContent)
            for key, pane in (("2", "run"), ("3", "spectrum"), ("6", "images"),
                              ("1", "instruments"), ("5", "results")):
                await pilot.press("4")
                await until(pilot, lambda: tabs.active == "runs", "the Runs tab")
                await pilot.press("tab")
                await pilot.press(key)
                await pilot.pause(0.2)
                assert tabs.active == pane, (key, tabs.active)
    asyncio.run(scenario())
    app.session.close()


def test_rating_colours_are_four_distinct_colour_blind_safe_colours():
    backgrounds = [style.split(" on ")[1] for style, _ in RATING_STYLES]
    assert len(set(backgrounds)) == 4
    # the Okabe–Ito colours of the report, not two near-identical oranges
    assert backgrounds == ["#0072B2", "#56B4E9", "#E69F00", "#D55E00"]
    import colour
    import numpy as np

    rgb = np.array([[int(c[i:i + 2], 16) / 255 for i in (1, 3, 5)] for c in backgrounds])
    lab = colour.XYZ_to_Lab(colour.sRGB_to_XYZ(rgb))
    pairs = [colour.delta_E(lab[i], lab[j], method="CIE 2000")
             for i in range(4) for j in range(i + 1, 4)]
    assert min(pairs) > 15, pairs            # the old two oranges were ΔE00 4.6 apart


def test_remaining_time_is_measured_and_gone_after_an_abort(lab_env):
    """The console's clock is injected: the remaining time is the observed rate (40 s for the
    first of 6 readings → 5 × 40 s left), a first `a` asks, a second `a` after the 5 s window
    asks again (the window expired), a second `a` within it aborts; no estimate afterwards."""
    import datetime

    from normbox_lab.core.clock import VirtualClock

    clock = VirtualClock(epoch_s=1_767_225_600.0)          # 2026-01-01T00:00:00Z
    session = new_session(lab_env)
    app = NormboxConsole(session, clock=clock)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("d")
            await until(pilot, lambda: "lab time" in str(
                app.query_one("#run-info", Static).render()), "the dry run")
            dry = str(app.query_one("#run-info", Static).render())
            assert "ETA" not in dry
            assert "in a simulated lab the remaining time is measured once the run goes" in dry
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 1")
            clock.advance(40.0)                  # the first reading takes 40 s of wall time
            await answer_prompt(pilot, app, "patch 1 ")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen)
                        and app.progress_done == 1, "prompt 2")
            log = [line.text for line in app.query_one("#events").lines]
            assert any(line.startswith("starting reference-sweep angles_deg=[30, 90] "
                                       "patches=[1, 9, 19] ") for line in log), log
            finish = datetime.datetime.fromtimestamp(clock.wall_time_s() + 200.0)
            assert app.remaining_text() == f"remaining 3:20 · done ≈ {finish:%H:%M}"

            def aborts_asked() -> int:
                return sum("abort the run?" in t for t in app.toasts_shown)
            await pilot.press("a")
            await until(pilot, lambda: aborts_asked() == 1, "the question")
            clock.advance(app.ABORT_CONFIRM_S + 1.0)                   # too late
            await pilot.press("a")
            await until(pilot, lambda: aborts_asked() == 2, "the question again")
            assert app.session.busy and app.run_status != "aborted"    # asked, not done
            clock.advance(app.ABORT_CONFIRM_S - 1.0)                   # within the window
            await pilot.press("a")                                      # confirmed
            await until(pilot, lambda: app.run_status == "aborted", "the abort")
            assert aborts_asked() == 2
            assert app.remaining_text() == ""
            assert "remaining" not in str(app.query_one("#run-info", Static).render())
    asyncio.run(scenario())
    session.wait(5.0)
    session.close()


def test_ctrl_q_at_a_prompt_pauses_the_run_and_leaves_at_once(lab_env):
    """Ctrl+Q while the operator is asked: no hang, the prompt is withdrawn, the run ends
    paused (resumable), never left `running`."""
    import time

    from normbox_lab.acquire.store import Store

    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await start_and_wait_for_the_second_prompt(pilot, app)
            await pilot.press("ctrl+q")
            await until(pilot, lambda: not session.busy, "the run to stop", timeout_s=10.0)
    t0 = time.monotonic()
    asyncio.run(scenario())
    assert time.monotonic() - t0 < 60.0
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "paused" and s.keys(run.id) == {"a30/p01"}


def test_runs_tab_shows_flag_counts_and_completed_with_flags(lab_env):
    from normbox_lab.acquire.store import Store
    from normbox_lab.analyze import qa

    with Store(lab_env / "tui.sqlite") as s:
        run = s.create_run("reference-sweep", status="running")
        s.set_run_status(run.id, "done")
        qa.record(s, "lamp-drift", "warning", "lamp drifted 1.2 %", run=run.id, key="a30/p01",
                  value=1.2, limit=1.0)
        qa.record(s, "radiometer-range", "error", "Lv above range", run=run.id,
                  key="a30/p09", value=9e4, limit=8e4)
    app = NormboxConsole(new_session(lab_env), offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(120, 30)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("4")
            table = app.query_one("#runs-table")
            await until(pilot, lambda: table.row_count == 1, "the run row")
            row = [str(c) for c in table.get_row_at(0)]
            assert "completed with flags" in row and "1E 1W" in row, row
    asyncio.run(scenario())
    app.session.close()


def test_dead_radiometer_is_a_red_row_not_connected(lab_env):
    """Health is real: the poll asks each instrument a cheap question through its driver; a
    radiometer that never answers is shown in red with 'no answer', and `i` says so."""
    from dataclasses import replace

    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.tui.controller import Session

    config = parse_config(SIM_CONFIG_TEMPLATE, "<sim>")
    dead = replace(config.instruments["radiometer"], port="sim://cs1000a?faults=no-reply=1.0")
    config = replace(config, instruments={**config.instruments, "radiometer": dead})
    session = Session(config, lab_env / "tui.sqlite", world="analytic", time_scale=0.0)
    app = NormboxConsole(session, offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(120, 30)) as pilot:
            await until(pilot, lambda: app.lab_ready or getattr(app, "lab_error", ""),
                        "the lab")
            rows = session.poll_instruments()
            by_role = {r["role"]: r for r in rows}
            assert by_role["radiometer"]["ok"] is False
            assert by_role["radiometer"]["state"].startswith("no answer")
            assert by_role["rotator"]["ok"] is True and by_role["rotator"]["last_seen"]
            await pilot.press("1")
            await pilot.press("i")
            table = app.query_one("#inst-table")
            await until(pilot, lambda: table.row_count > 0, "the instruments table")
            cells = dict(zip(INSTRUMENT_COLUMNS, table.get_row("radiometer"), strict=True))
            assert "no answer" in str(cells["state"])
            assert "D55E00" in str(cells["role"].style).upper()
            assert str(cells["last seen"]) == "never"
    asyncio.run(scenario())
    session.close()


def _real_sim_session(tmp_path):
    """Every instrument its real driver against its wire-level emulator (no fakes)."""
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.tui.controller import Session

    return Session(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), tmp_path / "tui.sqlite",
                   world="analytic", time_scale=0.0)


def test_emergency_stop_during_a_run_switches_the_lamp_off_and_pauses(tmp_path, monkeypatch):
    """x during a run (lamp warmed up, the operator asked to place the next patch): the
    emulators report the lamp off and the rotator not moving, the run ends paused and
    resumable, the reading under way is not committed."""
    from normbox_lab.acquire.store import Store
    from normbox_lab.core.capabilities import Movable, Switchable

    monkeypatch.chdir(tmp_path)
    session = _real_sim_session(tmp_path)
    app = NormboxConsole(session, offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await start_and_wait_for_the_second_prompt(pilot, app)
            sphere = session.lab.instrument("sphere")
            assert isinstance(sphere, Switchable) and sphere.state() != "off"
            await pilot.press("x")
            await until(pilot, lambda: not session.busy, "the run to stop", timeout_s=10.0)
            await until(pilot, lambda: app.run_status == "paused", "the run's end")
            assert app.remaining_text() == ""         # the segment has ended: no estimate
            info = str(app.query_one("#run-info", Static).render())
            assert "remaining" not in info
            assert "step: stopped at a30/p09/place · r resumes" in info, info
            assert sphere.state() == "off"                       # asked over the wire
            # the table tells the truth after the stop: the poll after the run (which waits
            # for the engine thread to end) reads the lamp off, not "on, stable"
            await pilot.press("1")
            await until(pilot, lambda: "sphere" in screen_text(app) and any(
                "sphere" in line and " off " in line + " " and "stable" not in line
                for line in screen_text(app).splitlines()), "the table to show the lamp off",
                timeout_s=10.0)
            rotator = session.lab.instrument("rotator")
            assert isinstance(rotator, Movable)
            p1 = rotator.position_deg()
            assert rotator.position_deg() == p1                  # not moving
    asyncio.run(scenario())
    session.close()
    with Store(tmp_path / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "paused" and s.keys(run.id) == {"a30/p01"}
        (stop,) = [data for _, k, data in s.events(run.id) if k == "emergency-stop"]
        assert stop["reason"] == "emergency stop at a30/p09/place", stop


def test_emergency_stop_without_a_run_halts_the_lab(tmp_path, monkeypatch):
    from normbox_lab.core.capabilities import Switchable

    monkeypatch.chdir(tmp_path)
    session = _real_sim_session(tmp_path)
    app = NormboxConsole(session, offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            sphere = session.lab.instrument("sphere")
            assert isinstance(sphere, Switchable)
            sphere.set_output(True)
            assert sphere.state() != "off"
            await pilot.press("x")
            await pilot.pause(0.2)
            assert sphere.state() == "off"
            footer = " ".join(str(b.description) for b in app.BINDINGS if b.show)
            assert "E-STOP" in footer
    asyncio.run(scenario())
    session.close()


def test_fault_prompt_names_the_role_once_and_says_what_to_check():
    from normbox_lab.acquire.runner import Engine
    from normbox_lab.core.errors import InstrumentTimeout

    asked = []

    class Probe:
        retry = type("R", (), {"persistent": "ask"})()
        _prompt_ids = iter(range(1, 10))

        def _ask(self, req):
            asked.append(req)
            return "retry"

    exc = InstrumentTimeout("radiometer: no reply")
    assert Engine._fault_decision(Probe(), "a30/p01", "radiometer", exc, 3) == "retry"
    message = asked[0].message
    assert message.count("radiometer") == 1, message
    assert "cable" in message and "powered on" in message


def test_instruments_table_follows_the_run(lab_env):
    """During a run the engine owns the ports (no polling), so the Instruments table shows what
    the run's events say: the rotator at the sweep angle, the sphere stable, the radiometer's
    last reading — not the stale '0.00° unhomed' / 'off' of the poll before the run."""
    from textual.widgets import DataTable

    app = NormboxConsole(new_session(lab_env))

    def state(role: str) -> str:
        table = app.query_one("#inst-table", DataTable)
        return str(table.get_row(role)[INSTRUMENT_COLUMNS.index("state")])

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await until(pilot, lambda: app.query_one("#inst-table", DataTable).row_count >= 3,
                        "the first poll")
            before = state("rotator")
            await start_and_wait_for_the_second_prompt(pilot, app)
            await pilot.press("1")
            await until(pilot, lambda: state("radiometer") == "measured a30/p01",
                        "the table to follow the run")
            assert state("rotator") == "30.00° (homed)", (before, state("rotator"))
            assert state("sphere") == "on, stable"
            live = str(app.query_one("#live", Static).render())
            assert "last reading a30/p01: Lv " in live and "e+" not in live, live
            # the state column is in view at 80 columns, whole
            await pilot.pause(0.6)
            shown = screen_text(app)
            for role, text in (("radiometer", "measured a30/p01"),
                               ("rotator", "30.00° (homed)"), ("sphere", "on, stable")):
                assert any(line.split()[:1] == [role] and text in line
                           for line in shown.splitlines()), (role, shown)
            assert app.waiting_prompt is not None             # the prompt still waits
    asyncio.run(scenario())
    app.session.close()


def test_parameter_form_names_the_bad_field_and_shows_whole_labels(lab_env):
    from textual.widgets import Input, Label, Select

    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            app.set_parameter("angles_deg", "[30,")
            await pilot.pause(0.4)                  # checked 0.15 s after the last key
            error = str(app.query_one("#param-error", Static).render())
            assert error.startswith("angles_deg: '[30,' has an unbalanced bracket"), error
            assert app.query_one("#param-angles_deg", Input).has_class("-invalid")
            await pilot.press("s")
            await pilot.pause(0.2)
            assert not app.session.busy                        # nothing started
            log = " ".join(str(line) for line in app.query_one("#events").lines)
            assert "angles_deg" in log
            app.set_parameter("angles_deg", "[30, 60]")
            await pilot.pause(0.4)
            assert not app.query_one("#param-error", Static).display
            # a long name is not cut: repeatability's threshold_percent
            app.query_one("#protocol", Select).value = "repeatability"
            await until(pilot, lambda: bool(app.query("#param-threshold_percent")), "its form")
            labels = [str(w.render()) for w in app.query(".param Label").results(Label)]
            assert "threshold_percent" in labels, labels
            label = next(w for w in app.query(".param Label").results(Label)
                         if str(w.render()) == "threshold_percent")
            await until(pilot, lambda: label.size.width > 0, "the layout")
            assert label.size.width >= len("threshold_percent")
    asyncio.run(scenario())
    app.session.close()


def test_a_waiting_prompt_steps_aside_and_never_covers_the_progress_line(lab_env):
    """80×24: the prompt sits at the bottom, the Run tab's progress line stays in view; 4
    shows the Runs tab while the prompt keeps waiting (the run line says so), 2 brings it
    back; p at the prompt is acknowledged."""
    from textual.widgets import TabbedContent

    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("i")                          # a toast…
            await until(pilot, lambda: len(app._notifications) > 0, "the poll's toast")
            await start_and_wait_for_the_second_prompt(pilot, app)
            await pilot.pause(0.1)                          # the prompt laid out
            prompt = app.screen
            assert len(app._notifications) == 0             # …is not drawn over the prompt
            box = prompt.query_one("Vertical").region
            main = app.screen_stack[0]
            for wid in ("#progress", "#run-info"):
                region = main.query_one(wid).region
                assert not region.overlaps(box), (wid, region, box)
            message = str(prompt.query_one("#prompt-message").render())
            assert message.startswith("Place patch 9 (moderate red) on the holder")
            shown = screen_text(app)
            # what to do and which keys, whole (the hint wraps, it is not cut at 80 columns)
            assert "on the holder — then Enter" in shown
            inside = [line[line.index("█") + 1:line.rindex("█")] for line in
                      shown.splitlines() if line.count("█") >= 2]    # the prompt box
            flat = " ".join(" ".join(inside).split())
            assert "a abort · 1–6 look (w back)" in flat, shown
            lines = shown.splitlines()
            assert any(line.lstrip().startswith("━") and "%" in line for line in lines), shown
            await pilot.press("4")
            await until(pilot, lambda: app.screen is not prompt, "the prompt to step aside")
            await until(pilot, lambda: app.query_one(TabbedContent).active == "runs",
                        "the Runs tab")
            assert app.waiting_prompt is not None and app.session.busy
            assert "prompt waiting: w" in str(app.query_one("#run-info", Static).render())
            # on the Runs tab too: the top line says a prompt waits
            assert screen_text(app).splitlines()[0].startswith(" prompt waiting: w")
            await pilot.press("2")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "the prompt back")
            assert app.screen.request.key == prompt.request.key
            # p at the prompt pauses there (no one more patch to place first)
            await pilot.press("p")
            await until(pilot, lambda: app.run_status == "paused" and not app.session.busy,
                        "the pause")
            assert any(t == f"paused before {prompt.request.key}: r resumes"
                       for t in app.toasts_shown), app.toasts_shown
            assert app.waiting_prompt is None
    asyncio.run(scenario())
    app.session.close()


def test_repeatability_summary_event_log_and_a_readings_spectrum(lab_env):
    """A repeatability run ends with σ / CV / flags; in the Runs tab Enter on the run shows
    its event log, Enter on a reading its spectrum with geometry, Lv and flags."""
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.tui.controller import Session
    from normbox_lab.tui.screens import DrillScreen, SpectrumScreen

    session = Session(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), lab_env / "tui.sqlite",
                      world="analytic", time_scale=0.0, virtual_operator=True)
    app = NormboxConsole(session, protocol="repeatability", prefill={"repeats": "3"})

    async def scenario() -> None:
        async with app.run_test(size=(100, 30)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("s")
            await until(pilot, lambda: app.run_status == "done", "the end of the run")
            await until(pilot, lambda: any("repeatability: 3 readings" in t
                                           for t in app.toasts_shown), "the summary")
            summary = next(t for t in app.toasts_shown if "repeatability:" in t)
            assert "σ " in summary and "CV " in summary and "flags " in summary, summary
            await pilot.press("4")
            await until(pilot, lambda: app.query_one("#readings-table").row_count == 3,
                        "the readings")
            row = [str(c) for c in app.query_one("#readings-table").get_row("rep01")]
            assert row[1] == "90.0°" and "e+" not in row[3] and row[7] in ("—", "0E 1W"), row
            await pilot.press("enter")                      # on the run
            await until(pilot, lambda: isinstance(app.screen, DrillScreen), "the event log")
            log = str(app.screen.query_one("#drill-text").render())
            assert "event log" in log and "status:done" in log, log[:300]
            await pilot.press("escape")
            await until(pilot, lambda: not isinstance(app.screen, DrillScreen), "closed")
            app.query_one("#readings-table").focus()
            await pilot.press("enter")                      # on reading rep01
            await until(pilot, lambda: isinstance(app.screen, SpectrumScreen), "the spectrum")
            head = str(app.screen.query_one("#reading-head").render())
            assert "rep01" in head and "90.0°" in head and "Lv" in head, head
    asyncio.run(scenario())
    session.close()


def test_reading_rows_format_luminance_and_brdf_geometry():
    from types import SimpleNamespace

    from normbox_lab.tui.views import luminance_text, reading_row

    assert luminance_text(2990.46) == "2990.5" and luminance_text(3000.0) == "3000.0"
    assert luminance_text(0.71234) == "0.712" and luminance_text(None) == "-"
    brdf = SimpleNamespace(key="p07/i-30/o10", metadata={"theta_i_deg": -30.0,
                                                         "theta_o_deg": 10.0, "material": "p07",
                                                         "integration_time_s": 0.1})
    flag = SimpleNamespace(severity="warning")
    row = reading_row(brdf, [flag])
    assert row[1] == "θi -30 θo 10" and row[2] == "p07" and row[7] == "0E 1W"
    from normbox_lab.tui.views import xy_text
    assert xy_text(0.56981, 0.40312) == "x 0.5698 y 0.4031"
    assert xy_text(float("nan"), float("nan")) == "x — y — (no light)"     # a dark reading


def test_manual_control_on_the_instruments_tab_and_refused_during_a_run(lab_env):
    """h homes, g asks an angle and goes there, k jogs +5°, o / f switch the lamp, m takes a
    single reading (shown, not stored) — each through the instrument's capabilities; while a
    run owns the instruments each is refused with the reason."""
    from normbox_lab.tui.screens import NumberScreen

    session = new_session(lab_env)
    app = NormboxConsole(session)

    def toasts() -> list[str]:
        return app.toasts_shown

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            rot, lamp = (session.lab.instrument(r) for r in ("rotator", "sphere"))
            await pilot.press("1")
            await pilot.press("h")
            await until(pilot, lambda: any("rotator homed" in t for t in toasts()), "homing")
            assert rot.is_homed()
            await pilot.press("g")
            await until(pilot, lambda: isinstance(app.screen, NumberScreen), "the question")
            await pilot.press("4", "5", "enter")
            await until(pilot, lambda: any("rotator at 45.00°" in t for t in toasts()), "goto")
            await pilot.press("k")
            await until(pilot, lambda: any("rotator at 50.00°" in t for t in toasts()), "jog")
            assert rot.position_deg() == 50.0
            await pilot.press("o")
            await until(pilot, lambda: lamp.state() != "off", "lamp on")
            await pilot.press("f")
            await until(pilot, lambda: lamp.state() == "off", "lamp off")
            await pilot.press("m")
            await until(pilot, lambda: any("single reading taken" in t and "Lv" in t
                                           for t in toasts()), "the reading")
            assert app.latest[0] == "manual"
            assert not any("nan" in t for t in toasts()), toasts()
            # seven toasts so far, two on screen (at 80×24 each covers half the width)
            assert len(toasts()) >= 7 and len(list(app._notifications)) <= app.MAX_TOASTS
            # one toast per action: the poll after it refreshes the table silently
            assert sum("instruments polled" in t for t in toasts()) == 1, toasts()
            # a run owns the instruments: refused, with the reason
            await pilot.press("2")
            await start_and_wait_for_the_second_prompt(pilot, app)
            await pilot.press("1")                          # the prompt steps aside
            await until(pilot, lambda: not isinstance(app.screen, PromptScreen), "aside")
            app.query_one("#inst-table").focus()
            before = rot.position_deg()
            await pilot.press("h")
            # named, and it says what frees them (a pause does not: the run waits to go on)
            await until(pilot, lambda: any(
                "home refused: the run owns the instruments until it ends" in t
                for t in toasts()), "the refusal")
            assert rot.position_deg() == before
    asyncio.run(scenario())
    session.close()


def test_the_first_paint_is_the_complete_screen_with_the_footer(lab_env):
    app = NormboxConsole(new_session(lab_env), exit_after_paint=True)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.first_paint_wall_s is not None, "the first paint")
    asyncio.run(scenario())
    assert app.first_paint_footer_keys >= 5          # x E-STOP, q quit, s start, d, p, …
    app.session.close()


def test_the_e_stop_key_is_on_screen_on_every_tab_at_80x24(lab_env):
    """The footer's first key is x E-STOP on every tab (the Instruments tab's manual keys
    are listed in the pane, not in front of it), so it is never cut at 80 columns."""
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            for key in "123456":
                await pilot.press(key)
                await pilot.pause(0.1)
                lines = screen_text(app).splitlines()
                assert lines[-1].lstrip().startswith("x E-STOP"), (key, lines[-1])
                if key == "1":
                    assert any("h home · g go to · j/k jog" in line for line in lines), lines
    asyncio.run(scenario())
    app.session.close()


def test_a_silent_radiometer_is_retried_and_logged_naming_the_role_once(lab_env):
    """The radiometer's emulator stops answering: each engine retry shows in the Run tab's log
    as a warning that names the role once ('radiometer: no reply …', not 'radiometer:
    radiometer:'), then the fault prompt; it answers again, r retries, the reading is stored."""
    session = new_session(lab_env)
    app = NormboxConsole(session)

    def warnings() -> list[str]:
        lines = [line.text for line in app.query_one("#events").lines]     # wrapped lines
        return [line for line in lines if line.startswith("warning ") and "— retry" in line]

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await start_and_wait_for_the_second_prompt(pilot, app)
            faults = session.lab.instrument("radiometer").port.emulator.faults
            faults.add("no-reply", probability=1.0)
            await answer_prompt(pilot, app, "patch 9")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen)
                        and app.screen.request.key == "a30/p09", "the fault prompt")
            faults.clear("no-reply")
            assert len(warnings()) >= 1
            assert all(w.count("radiometer") == 1 and "radiometer: no reply" in w
                       for w in warnings()), warnings()
            await pilot.press("r")
            await until(pilot, lambda: "a30/p09" in session.store.keys(session.engine.run_id),
                        "the reading after the retry")
    asyncio.run(scenario())
    session.close()


def test_emergency_stop_during_a_move_and_a_lamp_warm_up(tmp_path, monkeypatch):
    """Every instrument its real driver against its emulator: the rotator on its way to 90°
    and both gonio arms moving, the sphere's lamp warming up; x halts every axis short of its
    target and switches the lamp off, within 1 s of lab time (the emulators' own state)."""
    from normbox_lab.core.capabilities import Homeable, Movable, Settling, Switchable

    monkeypatch.chdir(tmp_path)
    session = _real_sim_session(tmp_path)
    app = NormboxConsole(session, offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            lab = session.lab
            axes = {role: lab.instrument(role) for role in lab.roles()
                    if isinstance(lab.instrument(role), Movable)}
            assert {"rotator", "gonio_light_arm", "gonio_detector_arm"} <= set(axes)
            for axis in axes.values():
                if isinstance(axis, Homeable) and not axis.is_homed():
                    axis.home()
                axis.move_to(90.0, wait=False)
            sphere = lab.instrument("sphere")
            assert isinstance(sphere, Switchable) and isinstance(sphere, Settling)
            sphere.set_output(True)
            assert all(axis.is_moving() for axis in axes.values())
            assert sphere.state() != "off" and not sphere.is_stable()      # warming up
            t0 = lab.clock.now_s()
            await pilot.press("x")
            await until(pilot, lambda: any("EMERGENCY STOP" in t
                                           for t in app.toasts_shown), "the stop")
            # halted within 1 s of lab time (the poll that follows the stop talks to every
            # instrument and moves the virtual clock on)
            assert session.halted_at_s is not None and session.halted_at_s - t0 < 1.0
            for role, axis in axes.items():
                assert not axis.is_moving(), role
                assert abs(axis.position_deg() - 90.0) > 1.0, (role, axis.position_deg())
            assert sphere.state() == "off"
    asyncio.run(scenario())
    session.close()


def test_instruments_table_fits_80_columns_state_and_last_seen_whole(tmp_path, monkeypatch):
    """At 80×24 the seven instruments of the simulated lab (long identities) fit: role, state
    and last seen are whole on screen, the identity gives up width first (…); at 160 columns
    nothing is cut."""
    from pilot import screen_text

    from normbox_lab.tui.tabs.instruments import INSTRUMENT_MIN_WIDTHS, fit_widths

    assert fit_widths([18, 17, 50, 17, 9], INSTRUMENT_MIN_WIDTHS, 66) == [18, 14, 8, 17, 9]
    assert fit_widths([18, 17, 50, 17, 9], INSTRUMENT_MIN_WIDTHS, 200) == [18, 17, 50, 17, 9]
    monkeypatch.chdir(tmp_path)
    session = _real_sim_session(tmp_path)
    app = NormboxConsole(session, offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("1")
            await until(pilot, lambda: app.query_one("#inst-table").row_count == 7, "the poll")
            await pilot.pause(0.1)
            lines = screen_text(app).splitlines()
            header = next(line for line in lines if line.lstrip().startswith("role"))
            assert header.rstrip().endswith("last seen"), header
            row = next(line for line in lines if line.lstrip().startswith("rotator "))
            assert "0.00° unhomed" in row and row.rstrip()[-8:].count(":") == 2, row
            assert any("in-plane" in line and "…" in line for line in lines)
            # longer states later (a run): the columns shrink again, last seen stays whole
            from normbox_lab.tui.tabs import InstrumentsPane

            rows = [dict(r, state="in use by the run") for r in session.instrument_rows()]
            app.pane(InstrumentsPane).show_instruments(rows, 80)
            await pilot.pause(0.1)
            lines = screen_text(app).splitlines()
            header = next(line for line in lines if line.lstrip().startswith("role"))
            assert header.rstrip().endswith("last seen"), header
            row = next(line for line in lines if line.lstrip().startswith("gonio_detector"))
            assert "in use by the run" in row and row.rstrip()[-8:].count(":") == 2, row
            await pilot.resize_terminal(160, 45)
            await pilot.press("i")
            await until(pilot, lambda: sum("instruments polled" in t
                                           for t in app.toasts_shown) >= 2, "the poll")
            await pilot.pause(0.1)
            assert "in-plane gonioreflectometer (QE Pro) QEP-SIM-0001" in screen_text(app)
    asyncio.run(scenario())
    session.close()


def test_run_progress_remaining_time_on_a_real_and_a_virtual_lab_clock():
    """RunProgress (the Run tab's state, no Textual): on a real lab clock the remaining time
    is the engine's timing model; on a virtual one the observed rate on the console's clock;
    nothing before a start, after an abort or at the end."""
    import datetime

    from normbox_lab.core.clock import VirtualClock
    from normbox_lab.tui.tabs.run import RunProgress

    clock = VirtualClock()
    progress = RunProgress(clock)
    assert progress.remaining_text(None) == ""                          # idle
    progress.started(done=0, planned=10, lab_remaining_s=600.0)
    assert progress.remaining_text(0.0) == "remaining: measuring…"     # nothing taken yet
    clock.advance(30.0)
    progress.progressed(done=2, lab_remaining_s=480.0)
    finish = datetime.datetime.fromtimestamp(clock.wall_time_s() + 480.0)
    assert progress.remaining_text(None) == f"remaining 8:00 · done ≈ {finish:%H:%M}"
    finish = datetime.datetime.fromtimestamp(clock.wall_time_s() + 120.0)   # 15 s × 8
    assert progress.remaining_text(0.0) == f"remaining 2:00 · done ≈ {finish:%H:%M}"
    info = progress.info_markup(0.0, prompt_waiting=True)
    assert info.startswith("[b]running[/b] · 2/10 readings · remaining 2:00") \
        and "prompt waiting: w" in info
    progress.status = "aborted"
    assert progress.remaining_text(None) == "" and "remaining" not in progress.info_markup(
        None, prompt_waiting=False)


def test_the_footer_fits_80_columns_from_e_stop_to_poll(lab_env):
    from pilot import screen_text

    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.pause(0.1)
            footer = screen_text(app).splitlines()[-1].strip()
            assert footer.startswith("x E-STOP") and footer.endswith("i poll"), footer
    asyncio.run(scenario())
    app.session.close()


def test_a_prompt_over_the_runs_tab_steps_aside_to_another_tab(lab_env):
    """The prompt came back (w) over the Runs tab, whose table had the focus; at the next
    prompt 1 must show the Instruments tab (the focus given back to the Runs table when the
    prompt closed used to switch the tabs back to Runs)."""
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 1")
            tabs = app.query_one(TabbedContent)
            await pilot.press("4")
            await until(pilot, lambda: tabs.active == "runs" and app.prompt_screen is None,
                        "the Runs tab")
            await pilot.pause(0.6)            # the Runs tab refreshed (its table has rows)
            await pilot.press("w")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 1 back")
            await answer_prompt(pilot, app, "patch 1 ")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 2")
            await pilot.pause(0.6)
            await pilot.press("1")
            await until(pilot, lambda: app.prompt_screen is None, "the prompt to step aside")
            seen = []
            for _ in range(10):                   # and it stays there (no back and forth)
                await pilot.pause(0.05)
                seen.append(tabs.active)
            assert set(seen) == {"instruments"}, seen
            assert screen_text(app).splitlines()[3].split()[:2] == ["role", "connection"]
    asyncio.run(scenario())
    app.session.close()


def test_event_lines_leave_no_blank_key_column():
    import time

    from normbox_lab.tui.views import event_lines

    t = time.mktime((2026, 11, 24, 2, 20, 3, 0, 0, -1))
    lines = event_lines([(t, "status:paused", {"done": 2, "taken": 0}),
                         (t, "emergency-stop", {"key": "a60/p07/place", "reason": "x"}),
                         (t, "fault", {"key": "a30/p01", "message": "no reply", "try": 3})])
    assert lines == ["11-24 02:20:03 status:paused  done=2, taken=0",
                     "11-24 02:20:03 emergency-stop a60/p07/place · reason=x",
                     "11-24 02:20:03 fault          a30/p01 · no reply · try=3"]


def test_e_exports_the_selected_run_as_csv(lab_env):
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.tui.controller import Session

    session = Session(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), lab_env / "tui.sqlite",
                      world="analytic", time_scale=0.0, virtual_operator=True)
    app = NormboxConsole(session, protocol="repeatability", prefill={"repeats": "2"})

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("e")                              # nothing selected yet
            await until(pilot, lambda: any("select a run" in t for t in app.toasts_shown),
                        "the hint")
            await pilot.press("s")
            await until(pilot, lambda: app.run_status == "done", "the end of the run")
            await pilot.press("4")
            await until(pilot, lambda: app.query_one("#runs-table").row_count == 1, "the run")
            await pilot.press("e")
            await until(pilot, lambda: any(t.startswith("exported run 1 → ")
                                           for t in app.toasts_shown), "the export")
    asyncio.run(scenario())
    session.close()
    (path,) = list(lab_env.glob("run-1-*.csv"))
    lines = path.read_text().splitlines()
    assert len(lines) >= 3 and "rep01" in "\n".join(lines) and "rep02" in "\n".join(lines), \
        lines[:3]


def test_keys_typed_into_a_field_belong_to_the_field_and_ctrl_x_stops_from_it(lab_env):
    """Reported: pasting 2000 x into a field queued 2000 emergency stops and froze the screen
    for 65 s.  Keys typed into a text field are the field's (x too); Ctrl+X stops from a
    field, and a burst of stops is one stop."""
    from textual.widgets import Input

    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            field = app.query_one("#param-rotator", Input)
            field.focus()
            await pilot.pause(0.1)
            field.cursor_position = len(field.value)
            await pilot.press("s", "x")
            await pilot.pause(0.1)
            assert field.value == "rotatorsx"                # s and x typed
            assert not app.session.busy and app.estops_started == 0
            await pilot.press("ctrl+x", "ctrl+x", "ctrl+x")
            await until(pilot, lambda: any("EMERGENCY STOP" in t for t in app.toasts_shown),
                        "the stop")
            assert field.value == "rotatorsx"
            assert app.estops_started == 1 and app.estops_coalesced == 2
    asyncio.run(scenario())
    app.session.close()


def test_stop_during_a_lamp_warm_up_ends_the_segment_paused_and_resumable(tmp_path):
    """`Engine.stop()` (quitting the console) no longer waits for the warm-up (up to 5 min
    at time scale 1): the wait ends at its next poll, the run is paused, and a resume warms
    the lamp up and completes it."""
    from engine_fakes import FakeLab

    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.store import Store

    with Store(tmp_path / "w.sqlite") as store:
        lab = FakeLab()
        plan = eng.build_plan("reference-sweep", {"angles_deg": [30], "patches": [7, 9]}, lab)
        engine = eng.Engine(lab, store, plan, wait_when_paused=True)
        polls: list[float] = []

        def on_event(ev) -> None:
            if ev.kind == "step-started" and ev.data.get("kind") == "wait-stable":
                polls.append(lab.clock.now_s())
                engine.stop()
        engine.subscribe(on_event)
        result = engine.run()
        assert result.status == "paused" and result.done == 0
        assert lab.clock.now_s() - polls[0] <= engine.poll_s          # one poll at most
        assert lab.sphere.is_stable() is False                        # it was still warming
        reasons = [d.get("reason") for _, k, d in store.events(result.run_id) if k == "stop"]
        assert reasons == ["stopped at the sphere warm-up of lamp"]
        assert store.get_run(result.run_id).status == "paused"
        again = eng.Engine(lab, store, plan).run(resume=result.run_id)
        assert again.status == "done" and again.done == 2


def test_ctrl_q_in_the_lamp_warm_up_leaves_at_once_and_the_run_resumes(lab_env, monkeypatch):
    """The console's Ctrl+Q during the lamp warm-up: the console is gone within 2 s (it used
    to wait for the warm-up), the run is paused with nothing measured, and it resumes."""
    import threading
    import time

    from engine_fakes import FakeLamp

    from normbox_lab.acquire.store import Store
    from normbox_lab.tui.controller import Session

    never = threading.Event()
    # a lamp that takes 10 ms to answer and never gets stable while the console is up
    monkeypatch.setattr(FakeLamp, "is_stable", lambda self: never.wait(0.01))
    session = new_session(lab_env)
    app = NormboxConsole(session)
    left: list[float] = []

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await until(pilot, lambda: "remaining: measuring… (lamp warming up)" in str(
                app.query_one("#run-info", Static).render()), "the warm-up")
            t0 = time.monotonic()
            await pilot.press("ctrl+q")
            await until(pilot, lambda: not app.is_running, "the console to leave",
                        timeout_s=10.0)
            left.append(time.monotonic() - t0)
    asyncio.run(scenario())
    assert left and left[0] < 2.0, left
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "paused" and s.keys(run.id) == set()
    never.set()                                   # the lamp is stable now
    again = Session(session.config, lab_env / "tui.sqlite", world="analytic", time_scale=0.0,
                    virtual_operator=True)
    again.resume_run(run.id)
    assert again.wait(30.0)
    assert again.result.status == "done" and again.result.done == 6
    again.close()


def test_a_running_run_without_a_live_owner_is_shown_interrupted(lab_env):
    """A closed terminal or a kill leaves a run stored as `running`: the run lock tells
    whether a process still executes it; without one the console shows it interrupted (and
    offers to resume it), with one it stays running."""
    session = new_session(lab_env)
    store = session.open_store()
    dead = store.create_run("reference-sweep", parameters={}, planned=6, status="running")
    alive = store.create_run("reference-sweep", parameters={}, planned=6, status="running")
    lock = store.lock_run(alive.id)              # a live owner (this process)
    try:
        shown = {r.id: r.status for r in session.runs()}
        assert shown == {dead.id: "interrupted", alive.id: "running"}
        assert [r.id for r in session.unfinished_runs()] == [dead.id, alive.id]
    finally:
        lock.release()
    assert {r.id: r.status for r in session.runs()}[alive.id] == "interrupted"
    session.close()
