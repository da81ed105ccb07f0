"""The console under stress: a paste of 2000 `x`, a held E-STOP key, random
text into every field and dialog, stale states, the keys during a prompt.

    python -m pytest -q tests/tui/test_tui_stress.py -s     # prints the paste timings
"""

from __future__ import annotations

import asyncio
import random
import time

import pytest
from pilot import new_session, set_reduced_parameters, until
from textual import events
from textual.widgets import Input, Static, TabbedContent

from normbox_lab.acquire.params import ParameterError
from normbox_lab.tui.app import NormboxConsole, PromptScreen
from normbox_lab.tui.screens import NumberScreen
from normbox_lab.tui.tabs import RunPane

PASTE = 2000


async def _burst_s(pilot, app, keys: list[str]) -> float:
    """Post `keys` as the terminal would deliver a paste without brackets (all queued at
    once), then a marker behind them: seconds until the marker runs, i.e. until the screen
    has answered everything queued and takes the next key (printed, not asserted: wall time
    on a shared machine is the scheduler's)."""
    done: list[float] = []
    t0 = time.monotonic()
    for key in keys:
        app.post_message(events.Key(key, key if len(key) == 1 else None))
    app.call_later(lambda: done.append(time.monotonic()))
    await until(pilot, lambda: bool(done), "the queue to drain")
    return done[0] - t0


def test_a_paste_of_2000_x_into_a_field_is_text_and_a_held_x_is_one_stop(lab_env, capsys,
                                                                         monkeypatch):
    """What kept the screen from answering is counted, not timed: a bracketed paste is one
    event and one check of the form; 2000 keys into a field are text and one check (the form
    is checked 0.15 s after the last key; every key parsed every field); 2000 x outside a
    field are one emergency stop (one worker, one toast) on the console's injected clock,
    which stands still, so the burst window never closes between two queued presses."""
    from normbox_lab.core.clock import VirtualClock
    from normbox_lab.tui.tabs import RunPane

    app = NormboxConsole(new_session(lab_env), clock=VirtualClock())
    timings: dict[str, float] = {}
    pastes: list[int] = []
    on_paste = Input._on_paste

    def counted(self, event):
        pastes.append(len(event.text))
        return on_paste(self, event)
    monkeypatch.setattr(Input, "_on_paste", counted)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            pane = app.pane(RunPane)
            field = app.query_one("#param-radiometer", Input)
            field.focus()
            await pilot.pause(0.1)
            field.value, field.cursor_position = "", 0
            await until(pilot, lambda: pane.form_checks > 0, "the form checked")
            checks = pane.form_checks
            # a bracketed paste (what a terminal sends for a paste): one event, one check
            t0 = time.monotonic()
            field.post_message(events.Paste("x" * PASTE))
            await until(pilot, lambda: len(field.value) == PASTE, "the pasted text")
            timings["bracketed paste into the field"] = time.monotonic() - t0
            await until(pilot, lambda: pane.form_checks > checks, "the form checked")
            await pilot.pause(2 * pane.FORM_CHECK_S)
            assert pastes == [PASTE] and pane.form_checks == checks + 1
            # … and the same as 2000 keys (tmux send-keys, a paste without brackets): text,
            # no stop, one check of the form after the last key
            field.value, field.cursor_position = "", 0
            await pilot.pause(2 * pane.FORM_CHECK_S)
            checks = pane.form_checks
            timings["2000 x keys into the field"] = await _burst_s(pilot, app, ["x"] * PASTE)
            await pilot.pause(2 * pane.FORM_CHECK_S)
            assert field.value == "x" * PASTE and pane.form_checks == checks + 1
            assert app.estops_started == 0 and not any("EMERGENCY" in t
                                                       for t in app.toasts_shown)
            app.set_focus(None)
            await pilot.pause(0.05)
            # a held (or pasted) x outside a field: one stop, the screen answers at once
            timings["2000 x keys outside a field"] = await _burst_s(pilot, app, ["x"] * PASTE)
            timings["the next key after them"] = await _burst_s(pilot, app, ["3"])
            await until(pilot, lambda: not app._estop_running, "the stop")
            assert app.estops_started == 1 and app.estops_coalesced == PASTE - 1
            assert sum("EMERGENCY STOP" in t for t in app.toasts_shown) == 1
            assert app.query_one(TabbedContent).active == "spectrum"     # the next key: 3
    asyncio.run(scenario())
    app.session.close()
    with capsys.disabled():
        print("\n" + " · ".join(f"{k} {v * 1000:.0f} ms" for k, v in timings.items()))


def test_a_stop_after_the_burst_is_a_new_stop(lab_env):
    """Coalescing never eats a real second stop: x, a manual move, x again: two stops."""
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            app.set_focus(None)
            await pilot.press("x")
            await until(pilot, lambda: not app._estop_running, "the stop")
            app._estop_last_press_s = -1e9          # the burst window has passed
            await pilot.press("x")
            await until(pilot, lambda: app.estops_started == 2, "the second stop")
    asyncio.run(scenario())
    app.session.close()


#: random text for the fields: the reported cases first, then random characters
TEXTS = ["9" * 309, "9" * 5000, "[30,,60]", "30,,60", "[٣]", "٤٥", "[30,30]", "[7,7]", "NaN",
         "1e309", "-Infinity", "[", "]", "[[30]]", "  ", "", "x" * 2000, "\x00", "30\n60"]


def _random_texts(n: int, seed: int = 36) -> list[str]:
    rng = random.Random(seed)
    alphabet = "0123456789+-.eE,[] \"xw_٣４" + "".join(chr(c) for c in range(0x20, 0x7f))
    return TEXTS + ["".join(rng.choice(alphabet) for _ in range(rng.randint(0, 40)))
                    for _ in range(n)]


def test_random_text_into_every_form_field_is_a_value_or_one_line(lab_env):
    """Every parameter field of every protocol, as the form checks it while typing (the
    same parser as --param): a value or one line, never another exception."""
    from normbox_lab.acquire import engine as eng
    from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
    from normbox_lab.acquire.params import check_parameters

    config = parse_config(SIM_CONFIG_TEMPLATE, "<sim>")
    tried = 0
    for protocol in ("reference-sweep", "brdf-inplane", "light-map", "repeatability"):
        module = eng.load_protocol(protocol)
        limits = vars(module).get("LIMITS") or {}
        for key, default in module.PARAMETERS.items():
            for text in _random_texts(60, seed=hash((protocol, key)) % 1000):
                tried += 1
                try:
                    value = eng.coerce_param(default, text, key, limits.get(key))
                    check_parameters(limits, {**module.PARAMETERS, key: value}, config,
                                     only=key)
                except ParameterError as exc:
                    assert "\n" not in str(exc) and exc.exit_code == 2, repr(str(exc))
    assert tried > 1500


@pytest.mark.parametrize("text, shown", [
    ("٤٥", "'٤٥' has digits of another script; use the digits 0-9"),
    ("9" * 309, "a 309-character number is too long"),
    ("NaN", "NaN is not a finite number"),
    ("400", "400 is above 95"),
    ("45", None),
])
def test_the_go_to_dialog_reads_numbers_like_the_form(lab_env, text, shown):
    """The go-to dialog moved to 45° for `٤٥` while the form refused `[٣]`; its title was cut
    at "(range from the lab config" at 80 columns."""
    app = NormboxConsole(new_session(lab_env))
    result: list = []

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            app.push_screen(NumberScreen("rotator: go to angle, degrees (range from the lab "
                                         "config)", 0.0, 95.0), result.append)
            await until(pilot, lambda: isinstance(app.screen, NumberScreen), "the dialog")
            await pilot.pause(0.1)
            title = app.screen.query_one("#number-title", Static)
            words = " ".join(str(title.render()).split())
            assert words == "rotator: go to angle, degrees (range from the lab config): 0 … 95"
            assert title.size.height >= 2            # wrapped, not cut
            field = app.screen.query_one("#number", Input)
            field.value = text
            await pilot.press("enter")
            await pilot.pause(0.1)
            if shown is None:
                assert result == [45.0]
            else:
                error = str(app.screen.query_one("#number-error", Static).render())
                assert error.startswith(shown), error
                assert result == []
    asyncio.run(scenario())
    app.session.close()


def test_2_and_w_over_another_tab_bring_the_run_tab_under_the_prompt(lab_env):
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "the prompt")
            tabs = app.screen_stack[0].query_one(TabbedContent)
            await pilot.press("1")                  # the prompt steps aside: tab 1 …
            await until(pilot, lambda: tabs.active == "instruments"
                        and not isinstance(app.screen, PromptScreen), "tab 1")
            await pilot.press("w")                  # … and comes back over tab 1
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "the prompt")
            assert tabs.active == "instruments"
            await pilot.press("2")
            await until(pilot, lambda: tabs.active == "run", "the Run tab")
            assert isinstance(app.screen, PromptScreen)       # the prompt still waits
            tabs.active = "instruments"
            await pilot.pause(0.1)
            await pilot.press("w")
            await until(pilot, lambda: tabs.active == "run", "the Run tab (w)")
            assert isinstance(app.screen, PromptScreen)
            await pilot.press("x")
    asyncio.run(scenario())
    app.session.wait(5.0)
    app.session.close()


def test_the_instruments_state_is_current_when_the_prompt_appears(lab_env):
    """"moving to 30°" and "sample angle 19.5°" were still shown under the prompt for 30°."""
    app = NormboxConsole(new_session(lab_env))
    seen: list[str] = []

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            original = app._show_prompt

            def show_prompt(req) -> None:
                original(req)
                seen.append(str(app.query_one("#live", Static).render()))
                seen.append(" ".join(r["state"] for r in app.session.instrument_rows()))
            app._show_prompt = show_prompt
            await pilot.press("s")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "the prompt")
            await pilot.press("x")
    asyncio.run(scenario())
    app.session.wait(5.0)
    app.session.close()
    live, rows = seen[0], seen[1]
    assert "sample angle 30.0°" in live, live
    assert "moving" not in rows and "30.00°" in rows, rows


def test_a_manual_go_to_shows_moving_and_s_waits_for_it(lab_env):
    """A manual go-to showed no "moving" state; a manual reading finished after s had
    already started the run."""
    app = NormboxConsole(new_session(lab_env))
    states: list[str] = []

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            session = app.session
            session.manual("home")
            lab_move = session.lab.instrument("rotator").move_to

            def move_to(target, wait=True):
                states.append(session.live.manual_state)
                return lab_move(target, wait=wait)
            session.lab.instrument("rotator").move_to = move_to
            session.manual_action = "go to"            # as the Instruments tab sets it
            app.action_start()
            assert not session.busy
            assert any("a manual action is under way (go to)" in t for t in app.toasts_shown)
            session.manual_action = ""
            session.manual("goto", 30.0)
            assert session.live.manual_state == "" and session.manual_action == ""
    asyncio.run(scenario())
    app.session.close()
    assert states == ["rotator moving to 30°"]


MARKUP_TEXTS = ["30,[/b]", "30,[@click=app.quit]q[/]", "[b]x[/b],1", "30,[/]", "[$x]"]


def test_a_refusal_that_quotes_markup_is_shown_as_typed(lab_env):
    """The form's and the go-to dialog's refusal quote what was typed; shown as markup, a
    typed ``[/b]`` ended the console with a MarkupError and ``[@click=app.quit]`` became a
    link that quits.  Each refusal is shown as its text, and the console goes on."""
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            field = app.query_one("#param-angles_deg", Input)
            for text in MARKUP_TEXTS:
                field.value = text
                message = app.pane(RunPane).check_parameters()
                await pilot.pause(0.05)
                shown = str(app.query_one("#param-error", Static).render())
                assert message and " ".join(shown.split()) == " ".join(message.split()), (
                    text, shown, message)
            app.push_screen(NumberScreen("rotator: go to angle, degrees", 0.0, 95.0))
            await until(pilot, lambda: isinstance(app.screen, NumberScreen)
                        and bool(app.screen.query("#number")), "the dialog")
            for text in MARKUP_TEXTS:
                app.screen.query_one("#number", Input).value = text
                await pilot.press("enter")
                await pilot.pause(0.05)
                shown = str(app.screen.query_one("#number-error", Static).render())
                assert text.strip()[:3] in shown or "not a number" in shown, (text, shown)
                assert isinstance(app.screen, NumberScreen)
            assert app.is_running
    asyncio.run(scenario())
    app.session.close()


def _screen_text(app) -> str:
    """The screen's text as drawn (a Textual SVG screenshot's text runs)."""
    import html
    import re

    return html.unescape(" ".join(re.findall(r"<text[^>]*>([^<]*)</text>",
                                             app.export_screenshot()))).replace("\xa0", " ")


def test_a_run_whose_protocol_file_name_looks_like_markup_is_listed_as_named(lab_env):
    """A DataTable reads a str cell as markup: the protocol file ``sweep[b]v2[i].py`` was
    listed as "sweepv2.py" in bold italics.  Listed as named, in the resume offer and the Runs
    tab."""
    from textual.widgets import DataTable

    from normbox_lab.acquire.store import Store
    from normbox_lab.tui.screens import ResumeScreen

    with Store(lab_env / "tui.sqlite") as store:
        store.create_run(str(lab_env / "sweep[b]v2[i].py"), parameters={}, planned=2,
                         status="paused")
    app = NormboxConsole(new_session(lab_env))

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: isinstance(app.screen, ResumeScreen)
                        and bool(app.screen.query("#resume-table")), "the resume offer")
            await pilot.pause(0.1)
            assert "sweep[b]v2[i].py" in _screen_text(app)
            await pilot.press("n")
            await until(pilot, lambda: not isinstance(app.screen, ResumeScreen), "not now")
            await pilot.press("4")                          # the Runs tab lists it too
            await pilot.pause(0.2)
            assert app.query_one("#runs-table", DataTable).row_count >= 1
            assert "sweep[b]v2[i].py" in _screen_text(app)
            assert app.is_running
    asyncio.run(scenario())
    app.session.close()


def test_a_protocol_path_that_looks_like_markup_is_named_as_typed(lab_env):
    """`tui --protocol 'a[/b].py'` (no such file): the parameter box names the file; shown as
    markup, the closing tag ended the console with a MarkupError."""
    app = NormboxConsole(new_session(lab_env), protocol="a[/b].py")

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            await pilot.pause(0.1)
            assert "protocol file a[/b].py does not exist" in _screen_text(app)
            assert app.is_running
    asyncio.run(scenario())
    app.session.close()
