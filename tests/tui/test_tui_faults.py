"""Pilot tests of the console's smaller faults an operator met: each is pressed as an operator
would and the screen read back."""

from __future__ import annotations

import asyncio
from dataclasses import replace

from pilot import answer_prompt, new_session, screen_text, set_reduced_parameters, until
from textual.widgets import DataTable, Input, RichLog, Static

from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.store import Store
from normbox_lab.tui.app import NormboxConsole, PromptScreen
from normbox_lab.tui.controller import Session, fault_text, poll_failure
from normbox_lab.tui.tabs.spectrum import SpectrumPane


def info(app) -> str:
    return str(app.query_one("#run-info", Static).render())


async def enter_at_prompt(pilot, app) -> None:
    """Wait for a composed prompt, press Enter, wait for it to go."""
    await until(pilot, lambda: isinstance(app.screen, PromptScreen)
                and bool(app.screen.query("#prompt-message"))
                and app.session.operator is not None
                and app.session.operator.pending is not None, "a prompt")
    screen = app.screen
    await pilot.press("enter")
    await until(pilot, lambda: app.screen is not screen, "the prompt to close")


def test_p_at_a_prompt_pauses_before_that_reading_and_r_asks_it_again(lab_env):
    """Reported: p while a prompt waited still asked the operator to place one more patch
    before pausing.  Nothing is being measured at a prompt: p pauses there (the prompt is
    withdrawn, no reading is taken); r resumes and asks the same prompt again."""
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 1")
            first = app.screen.request.key
            await pilot.press("p")
            await until(pilot, lambda: not session.busy and app.run_status == "paused",
                        "paused at the prompt")
            assert not isinstance(app.screen, PromptScreen)
            assert app.progress_done == 0 and "reading-stored" not in app.events_seen
            assert f"paused before {first}: r resumes" in app.toasts_shown
            await pilot.press("r")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt again")
            assert app.screen.request.key == first
            for _ in range(6):
                await enter_at_prompt(pilot, app)
                assert app.query_one("#tabs").active == "run"
            await until(pilot, lambda: app.run_status == "done", "the end")
    asyncio.run(scenario())
    session.wait(5.0)
    session.close()


def test_toasts_never_cover_a_prompt_and_the_focus_is_seen(lab_env):
    """With a prompt at the bottom, toasts are drawn at the top; Tab reaches the protocol
    list and the first parameter field without invisible stops, and the focused field looks
    different from the others."""
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24), notifications=True) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            app.set_focus(None)
            await pilot.press("tab")
            assert app.focused.id == "protocol"
            await pilot.press("tab")
            assert app.focused.id == "param-angles_deg"
            focused = app.query_one("#param-angles_deg", Input)
            other = app.query_one("#param-patches", Input)
            assert focused.styles.background != other.styles.background
            app.set_focus(None)
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "the prompt")
            app.notify("a toast during the prompt")
            app.notify("another one", severity="warning")
            await pilot.pause(0.3)
            box = app.screen.query_one("PromptScreen > Vertical").region
            toasts = [t.region for t in app.screen.query("Toast")]
            assert toasts and all(not t.overlaps(box) for t in toasts), (toasts, box)
            message = str(app.screen.query_one("#prompt-message", Static).render())
            assert message in screen_text(app)
            await pilot.press("x")
    asyncio.run(scenario())
    session.wait(5.0)
    session.close()


def test_resize_keeps_the_run_log_at_its_end_and_fits_80x24(lab_env):
    """160×45 → 80×24: the Run log is scrolled to its last line; the top line keeps the store
    name when a prompt waits aside; the Runs table's created column stays on screen."""
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(160, 45)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            for i in range(60):
                app._log("", f"line {i}")
            await pilot.resize_terminal(80, 24)
            await pilot.pause(0.3)
            log = app.query_one("#events", RichLog)
            assert log.scroll_offset.y == log.max_scroll_y > 0
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "the prompt")
            await pilot.press("4")                   # the prompt steps aside
            await until(pilot, lambda: not isinstance(app.screen, PromptScreen), "aside")
            await until(pilot, lambda: app.query_one("#runs-table", DataTable).row_count == 1,
                        "the run row")
            top = screen_text(app).splitlines()[0]
            assert "prompt waiting: w" in top and "store tui.sqlite" in top, top
            text = screen_text(app)
            assert "created" in text and "reference-sweep" in text, text
            await pilot.press("x")
    asyncio.run(scenario())
    session.wait(5.0)
    session.close()


def test_a_garbled_reply_is_not_no_answer_and_fault_lines_are_words():
    from normbox_lab.core.errors import DeviceError, InstrumentTimeout, ProtocolError

    assert poll_failure(ProtocolError("x", raw=b"\x00")) == "garbled reply"
    assert poll_failure(InstrumentTimeout("x")) == "no answer"
    assert poll_failure(DeviceError(3, "lamp failure")) == "device error"
    line = fault_text({"role": "radiometer", "error":
                       "InstrumentTimeout('radiometer: no answer to MES within 5 s')"})
    assert line == "no answer to MES within 5 s (InstrumentTimeout)"
    assert "{" not in fault_text({"role": "sphere", "message": "sphere: lamp off"})


def test_garbled_radiometer_row_lamp_at_time_scale_0_and_m_warns(lab_env, tmp_path):
    """A radiometer whose every reply is garbled: its row says "garbled reply", not "no
    answer".  A real sphere emulator at time scale 0: on, it is "stable" at the next poll
    (not "settling" for ever).  m with the lamp off warns that the reading is not
    representative; two manual readings are "previous: manual" and "latest: manual"."""
    config = parse_config(SIM_CONFIG_TEMPLATE, "<sim>")
    rad = config.instruments["radiometer"]
    garbled = replace(config, instruments={**config.instruments, "radiometer": replace(
        rad, port="sim://cs1000a?faults=garble=1.0")})
    session = Session(garbled, tmp_path / "g.sqlite", world="analytic", time_scale=0.0)
    rows = {r["role"]: r for r in session.poll_instruments()}
    assert rows["radiometer"]["state"].startswith("garbled reply"), rows["radiometer"]
    session.close()

    from normbox_lab.acquire import registry

    real = Session(config, tmp_path / "r.sqlite", world="analytic", time_scale=0.0)
    real.ensure_lab()
    assert type(real.lab.instrument("sphere")).__module__.endswith("drivers.sphere") or \
        registry.DRIVERS["sphere-scpi"] != ("normbox_lab.drivers.sphere", "SphereLightSource")
    app = NormboxConsole(real)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("1")
            await pilot.press("m")
            await until(pilot, lambda: any("single reading taken" in t
                                           for t in app.toasts_shown), "the reading")
            warned = [t for t in app.toasts_shown if "single reading taken" in t][-1]
            assert "WARNING" in warned and "not stable" in warned and "Lv" in warned, warned
            await pilot.press("o")
            await until(pilot, lambda: real.live.lamp == "stable", "stable at time scale 0",
                        timeout_s=10.0)
            await pilot.press("m")
            await until(pilot, lambda: sum("single reading taken" in t
                                           for t in app.toasts_shown) == 2, "reading 2")
            last = [t for t in app.toasts_shown if "single reading taken" in t][-1]
            assert "WARNING" not in last, last
            assert app.query_one(SpectrumPane).legend() == ["previous: manual",
                                                             "latest: manual"]
    asyncio.run(scenario())
    real.close()


def test_relaunch_shows_the_interrupted_runs_parameters(lab_env):
    """Quit at a prompt of a reduced sweep; the next console shows that run's protocol and
    parameters in the Run tab (not the default sweep)."""
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def first() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await answer_prompt(pilot, app, "patch 1 ")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 2")
            await pilot.press("q")
            await until(pilot, lambda: not session.busy, "the pause")
    asyncio.run(first())
    session.wait(5.0)
    session.close()
    again = NormboxConsole(new_session(lab_env), offer_resume=False)

    async def second() -> None:
        async with again.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: again.lab_ready, "the lab")
            await until(pilot, lambda: again.query_one("#param-patches", Input).value
                        == "[1, 9, 19]", "the run's parameters")
            assert again.query_one("#param-angles_deg", Input).value == "[30, 90]"
            assert any("parameters shown; r resumes it" in line.text
                       for line in again.query_one("#events", RichLog).lines)
    asyncio.run(second())
    again.session.close()
    with Store(lab_env / "tui.sqlite") as s:
        assert [r.status for r in s.runs()] == ["paused"]


def test_image_panel_titles_wrap_instead_of_being_cut_at_80_columns():
    import numpy as np
    from rich.console import Console

    from normbox_lab.images.terminal import figure_renderable

    label = "prediction (fast renderer, fitted Cook-Torrance materials)"
    image = np.full((8, 8, 3), 0.5)
    figure = figure_renderable("virtual camera — patch 19 at 30°",
                               [("truth (Mitsuba, truth materials)", image, None, ""),
                                (label, image, None, ""), ("ΔE00", image[..., 0], 5.0, "ΔE00")],
                               76)
    console = Console(width=80, record=True, color_system=None)
    console.print(figure)
    lines = console.export_text().splitlines()
    each = (76 - 2) // 3 + 1                     # a panel's columns and the space after it
    middle = " ".join(line[each:2 * each].strip() for line in lines[1:4])
    assert " ".join(middle.split()) == label                 # whole, wrapped, not "…"-cut


def test_an_emergency_stop_ends_a_manual_go_to_at_once_with_the_real_angle(lab_env,
                                                                          monkeypatch):
    """x during a manual go-to: the worker no longer waits out the motion's timeout ("motion
    not finished after 18.0 s", no word of the stop); it says the stop halted the rotator and
    where it is."""
    from engine_fakes import FakeStage

    session = new_session(lab_env)
    polls: list[int] = []

    def move_to(self, angle_deg: float, wait: bool = True) -> None:
        self.target, self.moving = float(angle_deg), True

    def is_moving(self) -> bool:
        if getattr(self, "moving", False):
            self.pos += 1.0                        # one degree per look
            polls.append(1)
            if len(polls) == 15:
                session.emergency_stop()           # the operator presses x (another thread)
        return getattr(self, "moving", False)

    def stop(self) -> None:
        self.stops += 1
        self.moving = False

    monkeypatch.setattr(FakeStage, "move_to", move_to)
    monkeypatch.setattr(FakeStage, "is_moving", is_moving)
    monkeypatch.setattr(FakeStage, "stop", stop)
    session.ensure_lab()
    session.lab.instrument("rotator").homed = True
    text, _ = session.manual("goto", 90.0)
    assert text == ("go to 90° stopped by the emergency stop: rotator halted at 15.00°")
    assert session.live.angle_deg == 15.0
    assert session.live.run_state["rotator"] == "halted at 15.00° (emergency stop)"
    session.close()


def test_the_instruments_table_during_a_run_is_the_instruments_state(lab_env):
    """From the run's events: the lamp warming up, an instrument in error (a sphere lamp
    failure), a move under way; roles the run does not use keep their polled state instead of
    "in use by the run"."""
    from types import SimpleNamespace

    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.events import EngineEvent

    session = new_session(lab_env)
    session.poll_instruments()
    plan = eng.build_plan("reference-sweep", {"angles_deg": [30], "patches": [7]})
    session.engine = SimpleNamespace(plan=plan, run_id=1)
    session.thread = SimpleNamespace(is_alive=lambda: True)        # a run owns the lab
    seen = []
    session.post = seen.append

    def event(event_kind: str, key: str = "", **data) -> None:
        session._on_event(EngineEvent(event_kind, 1, key, 0.0, data))

    def states() -> dict[str, str]:
        return {r["role"]: r["state"] for r in session.instrument_rows()}

    event("run-started", run_uuid="u", segment=1, planned=1, done=0, eta_s=10.0)
    event("step-started", "lamp", kind="wait-stable", label="wait until sphere is stable")
    assert states()["sphere"] == "on, warming up (the run waits)"
    assert session.live.lamp == "warming up"
    assert states()["radiometer"] == "in use by the run"
    assert states()["gonio_light_arm"].endswith("unhomed")           # not used: as polled
    event("fault", "lamp", role="sphere", attempt=1, transient=False,
          error="DeviceError('sphere: device error 201: Lamp failure')")
    assert states()["sphere"] == "ERROR: device error 201: Lamp failure (DeviceError)"
    assert session.live.lamp == "error"
    event("step-started", "a30/move", kind="move", label="set the sample angle to 30°")
    assert states()["rotator"] == "moving to 30°"
    event("step-finished", "a30/move", kind="move", duration_s=3.0)
    assert states()["rotator"] == "30.00° (homed)"
    session.thread = None
    session.engine = None
    session.close()


def test_the_console_asks_capabilities_not_attributes_or_the_role_sphere():
    """No getattr/hasattr probe in the console's controller and app (typed readings, declared
    attributes), and no "sphere" literal in the controller (the lab's light sources)."""
    import ast
    from pathlib import Path

    from normbox_lab import tui

    root = Path(tui.__file__).parent
    for name in ("controller.py", "app.py"):
        tree = ast.parse((root / name).read_text(encoding="utf-8"))
        probes = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Call)
                  and isinstance(n.func, ast.Name) and n.func.id in ("getattr", "hasattr")]
        assert probes == [], (name, probes)
    tree = ast.parse((root / "controller.py").read_text(encoding="utf-8"))
    docstrings = {id(n.body[0].value) for n in ast.walk(tree)
                  if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef))
                  and n.body and isinstance(n.body[0], ast.Expr)}
    literals = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Constant)
                and isinstance(n.value, str) and "sphere" in n.value
                and id(n) not in docstrings]
    assert literals == []


def test_the_heat_map_keeps_patch_names_when_scrolled_to_85_and_90_degrees(lab_env):
    """13 angles × 24 patches do not fit 80 columns: scrolled right to 90°, the patch names
    stay on screen (a fixed column)."""
    import numpy as np

    from normbox_lab.core.spectral import PATCH_NAMES
    from normbox_lab.tui.views import HeatMap

    angles = np.arange(30.0, 91.0, 5.0)
    rng = np.random.default_rng(3)
    hm = HeatMap(1, "ref-run-1", 1, list(PATCH_NAMES), angles,
                 rng.uniform(0.2, 6.0, (24, angles.size)),
                 rng.uniform(0.01, 0.3, (24, angles.size)), None, None, None)
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.press("5")
            app.show_heatmap(hm)
            await pilot.pause(0.2)
            table = app.query_one("#heatmap", DataTable)
            app.set_focus(table)
            table.move_cursor(row=0, column=angles.size)            # the 90° column
            await pilot.pause(0.3)
            box = table.region
            text = "\n".join(screen_text(app).splitlines()[box.y:box.y + box.height])
            assert "90°" in text and "85°" in text, text
            assert "dark skin" in text and "patch" in text, text
    asyncio.run(scenario())
    session.close()


def test_the_dry_run_line_and_every_parameter_field_are_whole_at_80x24(lab_env):
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            text = screen_text(app)
            for name in ("angles_deg", "patches", "rotator", "radiometer", "lamp",
                         "lamp_timeout_s"):
                assert f"│{name} " in text, (name, text)
            await pilot.press("d")
            await until(pilot, lambda: "dry-run reference-sweep" in info(app), "the dry run")
            await pilot.pause(0.2)
            widget = app.query_one("#run-info", Static)
            box = widget.content_region
            shown = " ".join(line[box.x:box.x + box.width].strip() for line in
                             screen_text(app).splitlines()[box.y:box.y + box.height])
            assert " ".join(info(app).split()) == " ".join(shown.split()), (info(app), shown)
    asyncio.run(scenario())
    session.close()


def test_p_during_a_move_pauses_at_the_prompt_that_follows_not_after_one_more_patch(lab_env):
    """A pause asked while the holder moves to the next angle (status 'pausing…') took effect
    only at the engine's next checkpoint, after the reading the next prompt prepares: the
    operator was asked to place one more patch (and a second p at that prompt cancelled the
    pause).  The prompt that follows a requested pause is withdrawn at once: the segment ends
    paused before it, nothing more is measured, and r asks it again."""
    import threading

    session = new_session(lab_env)
    app = NormboxConsole(session)
    moving, release = threading.Event(), threading.Event()

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            rotator = session.lab.instrument("rotator")
            move_to = rotator.move_to

            def held_move(angle_deg: float, wait: bool = True) -> None:
                if angle_deg == 90:                    # the move to the second angle: held
                    moving.set()
                    release.wait(30)
                move_to(angle_deg, wait)
            rotator.move_to = held_move
            await pilot.press("s")
            for _ in range(3):                          # 30°: patches 1, 9, 19
                await answer_prompt(pilot, app)
            await until(pilot, moving.is_set, "the move to 90°")
            await pilot.press("p")
            assert app.run_status == "pausing…"
            release.set()
            await until(pilot, lambda: not session.busy and app.run_status == "paused",
                        "paused at the prompt that follows the move")
            assert not isinstance(app.screen, PromptScreen)
            assert app.progress_done == 3
            assert "paused before a90/p01/place: r resumes" in app.toasts_shown
            rotator.move_to = move_to
            await pilot.press("r")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen)
                        and app.session.operator is not None
                        and app.session.operator.pending is not None, "prompt again")
            assert app.screen.request.key == "a90/p01/place"
    asyncio.run(scenario())
    release.set()
    session.wait(5.0)
    session.close()
