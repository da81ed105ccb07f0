"""Pilot tests of the operator console (`normbox-lab tui`): Textual's `App.run_test()` at 80×24,
driven with keys like an operator, on a simulated lab (analytic world, virtual clock at time
scale 0; the CS-1000A driver against its wire-level emulator, fake stage and lamp drivers from
`engine_fakes`).  No pytest-asyncio: each test runs its coroutine with `asyncio.run`.
"""

from __future__ import annotations

import asyncio

import numpy as np
from pilot import (
    KEYS,
    answer_prompt,
    new_session,
    set_reduced_parameters,
    until,
)

from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.acquire.store import Store
from normbox_lab.sim import labsim as labmod
from normbox_lab.tui.app import DrillScreen, NormboxConsole, PromptScreen, ResumeScreen
from normbox_lab.tui.controller import Session
from normbox_lab.tui.tabs import ImagesPane

# `lab_env` (real CS-1000A driver + emulator, fake stage/lamp drivers) is in conftest.py;
# the pilot helpers are in pilot.py


def test_sweep_prompts_pause_resume_progress_and_heat_map(lab_env):
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            # dry-run: step count and ETA from the timing models
            await pilot.press("d")
            info = app.query_one("#run-info")
            await until(pilot, lambda: "dry-run" in str(info.render()), "the dry-run")
            text = str(info.render())
            assert "6 readings" in text and "lab time" in text
            assert app.dry.plan.planned == 6 and app.dry.total_s > 0

            await pilot.press("s")
            texts = [await answer_prompt(pilot, app, "Place patch 1 (dark skin) on the holder")]
            await until(pilot, lambda: app.progress_done == 1, "the first reading")
            texts.append(await answer_prompt(pilot, app, "patch 9 (moderate red)"))
            await until(pilot, lambda: app.progress_done == 2, "the second reading")
            assert "then Enter" in texts[0]
            # the progress bar follows the engine
            bar = app.query_one("#bar")
            assert bar.total == 6 and bar.progress == 2
            # pause while the third prompt waits: nothing is being measured, so it pauses
            # there (reported: it used to ask for one more patch first)
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 3")
            await pilot.press("p")                 # in the modal: pause here
            await until(pilot, lambda: app.run_status == "paused" and not session.busy,
                        "the pause")
            assert app.progress_done == 2
            with Store(lab_env / "tui.sqlite") as s:
                (run,) = s.runs()
                assert run.status == "paused" and s.keys(run.id) == {"a30/p01", "a30/p09"}
            await pilot.press("r")                 # resume: the prompt for patch 19 again
            for p in (19, 1, 9, 19):
                await answer_prompt(pilot, app, f"patch {p} ")
            await until(pilot, lambda: app.run_status == "done", "the end of the run")
            assert app.progress_done == 6 and app.query_one("#bar").progress == 6
            assert app.events_seen.count("run-started") == 2

            # live state and spectrum come from the engine's events
            live = session.live
            assert live.angle_deg == 90.0 and live.last_key == "a90/p19"
            assert live.last_Lv_cd_m2 is not None and live.last_Lv_cd_m2 > 0
            await until(pilot, lambda: app.spectrum_series() == ["a90/p09", "a90/p19"],
                        "the spectrum")
            await pilot.press("3")
            await until(pilot, lambda: app._plot is not None, "the plot")

            # Runs tab: the run and its six readings
            await pilot.press("4")
            await until(pilot, lambda: app.query_one("#readings-table").row_count == 6,
                        "the readings table")

            # Results: a comparison artifact (pipeline code, synthetic prediction) → heat map
            run_id = session.store.runs()[0].id
            expected = write_comparison(session.store, run_id)
            await pilot.press("5")
            table = app.query_one("#heatmap")
            await until(pilot, lambda: table.row_count == 4, "the heat map")
            assert len(table.columns) == 3           # patch + 2 angles
            cell = table.get_cell_at((1, 1))          # patch 9 at 30°
            assert cell.plain.strip() == f"{expected[1, 0]:.1f}"
            from normbox_lab.tui.views import RATING_STYLES, rating_class

            assert str(cell.style) == RATING_STYLES[rating_class(expected[1, 0])][0]
            # drill-down follows the cursor
            await pilot.press("down")
            drill = str(app.query_one("#drill").render())
            assert drill.startswith("#2 moderate red: mean ΔE00")
            await pilot.press("enter")                # drill-down: every angle of patch 9
            await until(pilot, lambda: isinstance(app.screen, DrillScreen), "the drill-down")
            lines = str(app.screen.query_one("#drill-text").render()).splitlines()
            assert lines[0].startswith("#2 moderate red") and len(lines) == 2 + 2
            assert lines[2].split()[:2] == ["30°", f"{expected[1, 0]:.2f}"]
            await pilot.press("escape")
        assert session.wait(5.0)
        session.close()
        with Store(lab_env / "tui.sqlite") as s:
            (run,) = s.runs()
            assert run.status == "done" and s.keys(run.id) == KEYS
            kinds = [k for _, k, _ in s.events(run.id)]
            assert "status:paused" in kinds

    asyncio.run(scenario())


def write_comparison(store: Store, run_id: int) -> np.ndarray:
    """A `comparison` artifact as `normbox-lab compare` writes it, with a prediction that
    differs from the measured spectra by a known factor per patch; returns its ΔE00."""
    from normbox_lab.analyze.compare import compare

    patches, angles = [1, 9, 19], [30.0, 90.0]
    ref = np.stack([np.stack([store.reading(run_id, f"a{int(a)}/p{p:02d}")
                              .arrays["radiance_W_sr_m2_nm"] for a in angles])
                    for p in patches])
    wl = store.reading(run_id, "a30/p01").arrays["wavelength_nm"]
    tilt = np.linspace(-1.0, 1.0, wl.size)
    pred = ref * (1.0 + np.array([0.02, 0.15, 0.40])[:, None, None] * tilt)
    result = compare(ref, pred, wl, angles, ["dark skin", "moderate red", "white"],
                     white_patch=2)
    result.store(store, f"ref-run-{run_id}", run_ref=run_id)
    de = result.delta_e00
    assert len({int(rating_class_of(v)) for v in de.ravel()}) >= 2   # colours differ
    return de


def rating_class_of(v: float) -> int:
    from normbox_lab.analyze.compare import rating_index

    return int(rating_index(v))


def test_quit_at_a_prompt_leaves_a_resumable_run(lab_env):
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await answer_prompt(pilot, app)
            await answer_prompt(pilot, app)
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 3")
            await pilot.press("q")              # the modal has no q: it goes to the app
            if isinstance(app.screen, PromptScreen):
                app.action_quit_console()
            await until(pilot, lambda: not app.is_running, "the console to close",
                        timeout_s=10.0)
    asyncio.run(scenario())
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "paused"
        assert s.keys(run.id) == {"a30/p01", "a30/p09"}
        run_uuid = run.uuid

    # resume through the engine (what `normbox-lab run --resume` does), virtual operator
    from normbox_lab.acquire import engine as eng

    lab = labmod.build_lab(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), world="analytic")
    with Store(lab_env / "tui.sqlite") as s:
        rec = s.get_run(run_uuid)
        plan = eng.build_plan(rec.protocol, rec.parameters, lab)
        result = eng.Engine(lab, s, plan).run(resume=rec.id)
        assert result.status == "done" and result.taken == 4
        assert s.keys(rec.id) == KEYS and s.get_run(rec.id).status == "done"
    lab.close()


def test_quit_while_paused_then_resume_offered_at_start(lab_env):
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def first() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await answer_prompt(pilot, app)
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 2")
            await pilot.press("p")                 # pause at a prompt: here, before it
            await until(pilot, lambda: app.run_status == "paused" and not session.busy,
                        "the pause")
            await pilot.press("q")
            await until(pilot, lambda: not app.is_running, "the console to close")
    asyncio.run(first())
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "paused" and run.done == 1

    session2 = new_session(lab_env)
    app2 = NormboxConsole(session2)

    async def second() -> None:
        async with app2.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: isinstance(app2.screen, ResumeScreen)
                        and bool(app2.screen.query("Label")), "the offer, composed")
            assert "1 interrupted run" in str(app2.screen.query("Label").first().render())
            await pilot.press("enter")
            # the first missing reading is a30/p09: a fresh process knows nothing of the
            # physical state, so it asks for that patch again, and never for a committed one
            for p in (9, 19, 1, 9, 19):
                await answer_prompt(pilot, app2, f"patch {p} ")
            await until(pilot, lambda: app2.run_status == "done", "the end of the run")
    asyncio.run(second())
    assert session2.wait(5.0)
    session2.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "done" and s.keys(run.id) == KEYS
        segments = [d for _, k, d in s.events(run.id) if k == "segment"]
        assert len(segments) == 2 and segments[1]["committed"] == 1


def test_command_line_builds_the_console_without_importing_textual_early(lab_env, monkeypatch):
    import subprocess
    import sys

    # `normbox-lab --help` (all parsers registered) must not import textual
    code = ("import sys; from normbox_lab.cli import build_parser; build_parser(); "
            "print('textual' in sys.modules, 'numpy' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True).stdout.split()
    assert out[0] == "False"

    from normbox_lab.cli import main

    seen = {}

    def fake_run(self) -> None:          # no terminal here: record what the app was given
        seen.update(world=self.session.world_kind, protocol=self.protocol,
                    prefill=dict(self.prefill), scale=self.session.time_scale,
                    store=self.session.store_path.name)
        self.first_paint_wall_s = self.first_paint_cpu_s = 0.0
    monkeypatch.setattr(NormboxConsole, "run", fake_run)
    assert main(["tui", "--world", "analytic", "--time-scale", "0", "--store", "c.sqlite",
                 "--protocol", "light-map", "--param", "x=1", "--exit-after-first-paint"]) == 0
    assert seen == {"world": "analytic", "protocol": "light-map", "prefill": {"x": "1"},
                    "scale": 0.0, "store": "c.sqlite"}


def test_the_lab_config_is_read_after_the_first_paint(lab_env, capsys):
    """Its checks import the drivers and the protocols (numpy with them, 0.3 s of CPU): the
    console paints first.  Nothing of the acquisition is imported before the first paint;
    then the config is read."""
    import subprocess
    import sys

    code = ("import sys\n"
            "from normbox_lab.tui import app as A\n"
            "seen = {}\n"
            "def paint(self):\n"
            "    seen.update(mods=[m for m in ('numpy', 'normbox_lab.acquire.config', "
            "'normbox_lab.drivers', 'normbox_lab.acquire.engine', 'serial') "
            "if m in sys.modules])\n"
            "    self.exit()\n"
            "A.NormboxConsole._first_paint = paint\n"
            "A.NormboxConsole.run = lambda self: A.App.run(self, headless=True)\n"
            "from normbox_lab.cli import main\n"
            f"main(['tui', '--store', {str(lab_env / 'fp.sqlite')!r}])\n"
            "print('imported before the first paint:', seen['mods'])\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         check=True, cwd=lab_env).stdout
    assert "imported before the first paint: []" in out, out


def test_a_lab_config_the_console_cannot_use_ends_it_with_one_line(lab_env, monkeypatch,
                                                                   capsys):
    """Read after the first paint, a bad lab config still ends the console at once with one
    line naming file, line and field, exit 2 (as `run` refuses it)."""
    from textual.app import App

    from normbox_lab.cli import main

    bad = lab_env / "bad.toml"
    bad.write_text(SIM_CONFIG_TEMPLATE.replace('port = "sim://cs1000a"',
                                               'port = "sim://cs1000a?faults=garble@٣"'))
    monkeypatch.setattr(NormboxConsole, "run", lambda self: App.run(self, headless=True))
    capsys.readouterr()
    assert main(["tui", "--lab", str(bad), "--store", str(lab_env / "b.sqlite")]) == 2
    err = capsys.readouterr().err
    assert err.startswith(f"normbox-lab: error: {bad}:") and err.count("\n") == 1, err
    assert "instruments.radiometer.port: faults 'garble@٣'" in err
    assert main(["tui", "--lab", str(lab_env / "none.toml")]) == 2
    assert "no such file" in capsys.readouterr().err


def test_a_store_the_console_cannot_use_ends_it_with_one_line(lab_env, monkeypatch, capsys):
    """Opened after the first paint, a --store that names no store (a directory, a text
    file, a device) ended nothing: the console stayed up on "lab not ready".  It ends with
    one line, exit 2, as `runs --store` refuses it."""
    from textual.app import App

    from normbox_lab.cli import main

    text = lab_env / "notes.txt"
    text.write_text("not a store\n" * 20)
    monkeypatch.setattr(NormboxConsole, "run", lambda self: App.run(self, headless=True))
    for store, expect in ((str(text), "not a normbox-lab store"),
                          (str(lab_env), "not a file"), ("/dev/zero", "not a file")):
        capsys.readouterr()
        assert main(["tui", "--store", store, "--world", "analytic"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"normbox-lab: error: {store}") and expect in err, err
        assert err.count("\n") == 1, err


def test_quit_while_measuring_pauses_after_the_current_reading(lab_env):
    """Virtual operator (prompts answered by the simulation): q while a reading is being
    stored ends the segment right after it; the run is resumable."""
    import threading

    session = Session(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), lab_env / "tui.sqlite",
                      world="analytic", time_scale=0.0, virtual_operator=True)
    gate = threading.Event()
    make_engine = session.make_engine

    def gated(*args, **kwargs):
        engine = make_engine(*args, **kwargs)
        # hold the engine thread inside the second reading's events until q was handled
        engine.subscribe(lambda ev: gate.wait(10.0) if ev.kind == "reading-stored"
                         and ev.key == "a30/p02" else None)
        return engine
    session.make_engine = gated
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            app.set_parameter("angles_deg", "[30, 90]")      # 48 readings
            await pilot.press("s")
            await until(pilot, lambda: session.live.last_key == "a30/p02", "two readings")
            await pilot.press("q")
            await until(pilot, lambda: app.quitting, "the quit")
            gate.set()
            await until(pilot, lambda: not app.is_running, "the console to close")
    asyncio.run(scenario())
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "paused" and s.keys(run.id) == {"a30/p01", "a30/p02"}
        paused = [d for _, k, d in s.events(run.id) if k == "status:paused"]
        assert paused[0]["next"] == "a30/p03"


def test_fault_prompt_at_preparation_offers_retry_and_abort_only(lab_env):
    """A radiometer that never answers (emulator fault `no-reply=1.0`): after the engine's
    retries the console asks; preparing an instrument is not a reading, so there is no
    "skip" (s does nothing), only retry or abort."""
    text = SIM_CONFIG_TEMPLATE.replace('port = "sim://cs1000a"',
                                       'port = "sim://cs1000a?faults=no-reply=1.0"')
    assert "no-reply=1.0" in text
    session = Session(parse_config(text, "<faulty>"), lab_env / "tui.sqlite",
                      world="analytic", time_scale=0.0)
    app = NormboxConsole(session)

    async def fault(pilot, key: str) -> PromptScreen:
        await until(pilot, lambda: isinstance(app.screen, PromptScreen)
                    and app.screen.request.kind == "fault" and app.screen.request.key == key,
                    f"the fault prompt at {key}")
        screen = app.screen
        assert screen.request.choices == ("retry", "abort")
        message = str(screen.query_one("#prompt-message").render())
        assert "retry, or abort the run?" in message and "skip" not in message
        return screen

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            app.set_parameter("angles_deg", "[30]")
            app.set_parameter("patches", "[1]")
            await pilot.press("s")
            screen = await fault(pilot, "prepare/radiometer")
            await pilot.press("s")                          # no skip here: nothing happens
            await pilot.pause(0.2)
            assert app.screen is screen
            await pilot.press("r")                          # retry: it fails again
            await until(pilot, lambda: app.screen is not screen, "the retry")
            screen = await fault(pilot, "prepare/radiometer")
            await pilot.press("a")                          # abort the run
            await until(pilot, lambda: app.run_status == "aborted", "the end of the run")
    asyncio.run(scenario())
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "aborted" and run.done == 0
        ops = [d["answer"] for _, k, d in s.events(run.id) if k == "operator"]
        assert ops == ["retry", "abort"]
        assert not [d for _, k, d in s.events(run.id) if k == "skip"]


def test_brdf_protocol_prefilled_mount_prompt_and_brdf_plot(monkeypatch, tmp_path):
    """`--protocol brdf-inplane --param ...` prefill; the gonio (the real QE Pro and Zaber
    drivers against their emulators) asks to mount the material; BRDF readings are plotted
    and carry the TEC temperature."""
    monkeypatch.chdir(tmp_path)
    session = new_session(tmp_path)
    app = NormboxConsole(session, protocol="brdf-inplane", offer_resume=False,
                         prefill={"materials": "[7]", "theta_i_deg": "[-30]",
                                  "theta_o_deg": "[10, 30]"})

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            assert app.query_one("#protocol").value == "brdf-inplane"
            assert app.parameters()["theta_o_deg"] == [10, 30]
            await pilot.press("s")
            await answer_prompt(pilot, app, "Mount patch 7 (orange) on the gonioreflectometer")
            await until(pilot, lambda: app.run_status == "done", "the end of the run",
                        timeout_s=60.0)
            await until(pilot, lambda: app.spectrum_series() == ["p07/i-30/o+10",
                                                                 "p07/i-30/o+30"], "the plot")
            assert app.latest[4] == "BRDF sr⁻¹" and session.live.temperature_c is not None
            # confirming the prompt mounted the sample in the simulated world
            assert session.lab.world.gonio_material == "patch-7"
    asyncio.run(scenario())
    assert session.wait(5.0)
    session.close()


def test_abort_at_a_prompt_then_resume_with_r(lab_env):
    session = new_session(lab_env)
    app = NormboxConsole(session)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await set_reduced_parameters(pilot, app)
            await pilot.press("s")
            await answer_prompt(pilot, app, "patch 1 ")
            await until(pilot, lambda: isinstance(app.screen, PromptScreen), "prompt 2")
            await pilot.press("a")                 # abort while the operator is asked…
            await pilot.press("a")                 # …confirmed
            await until(pilot, lambda: app.run_status == "aborted", "the abort")
            await until(pilot, lambda: not session.busy, "the worker to end")
            with Store(lab_env / "tui.sqlite") as s:
                (run,) = s.runs()
                assert run.status == "aborted" and s.keys(run.id) == {"a30/p01"}
            await pilot.press("r")                 # resume the latest unfinished run
            for p in (9, 19, 1, 9, 19):
                await answer_prompt(pilot, app, f"patch {p} ")
            await until(pilot, lambda: app.run_status == "done", "the end of the run")
    asyncio.run(scenario())
    assert session.wait(5.0)
    session.close()
    with Store(lab_env / "tui.sqlite") as s:
        (run,) = s.runs()
        assert run.status == "done" and s.keys(run.id) == KEYS
        assert "abort" in [k for _, k, _ in s.events(run.id)]


def test_images_tab_shows_the_latest_image_figure_as_half_blocks(lab_env):
    from normbox_lab.analyze.report import ImageFigure, ImagePanel

    rgb = np.zeros((24, 32, 3), dtype=np.uint8)
    rgb[:, :16] = (200, 30, 40)
    with Store(lab_env / "tui.sqlite") as store:
        ImageFigure("fig-camera", "virtual camera", "c",
                    [ImagePanel("truth", rgb), ImagePanel("ΔE00", np.ones((24, 32)), vmax=5.0,
                                                          unit="ΔE00")],
                    "patch 19 at 30°").store(store)
    session = new_session(lab_env)
    app = NormboxConsole(session, offer_resume=False)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: session.store is not None and app.panes_built, "the store")
            await pilot.press("6")
            images = app.pane(ImagesPane)
            await until(pilot, lambda: images.shown_artifact_id is not None,
                        "the image preview")
            figure = app.query_one("#images-text").content.renderables[0]
            title, grid = figure.renderables
            assert title.plain.startswith("virtual camera — patch 19 at 30°")
            # the ΔE00 map has its colour scale under it, 0 … 5 ΔE00
            scale = grid.columns[1]._cells[2]
            assert scale.plain.startswith("█") and scale.plain.rstrip().endswith("5 ΔE00")
            assert "0" in scale.plain.split("\n")[1]
            labels = [c._cells[0].plain for c in grid.columns]
            assert labels == ["truth", "ΔE00 (0…5 ΔE00)"]
            block = grid.columns[0]._cells[1]
            assert set(block.plain) <= {"▀", "\n"}
            assert any("rgb(200,30,40)" in str(s.style) for s in block.spans), block.spans[:3]
            # side by side: each panel gets about half of the console's width
            assert 30 <= len(block.plain.split("\n")[0]) <= 40
    asyncio.run(scenario())
    session.close()


def _cells(svg: str, row: int) -> list[tuple[str, str, str]]:
    """One row of a Textual SVG screenshot as (character, colour, background) per column
    (80 columns)."""
    import html
    import re

    fills = dict(re.findall(r"\.terminal-\d+-(r\d+) \{ fill: (#[0-9a-f]+)", svg))
    cells = [(" ", "", "")] * 80
    for x, y, w, colour in ((float(m[2]), float(m[3]), float(m[4]), m[1]) for m in re.finditer(
            r'<rect fill="(#[0-9a-f]+)" x="([\d.]+)" y="([\d.]+)" width="([\d.]+)"', svg)):
        if round((y - 1.5) / 24.4) == row:
            for col in range(round(x / 12.2), round((x + w) / 12.2)):
                cells[col] = (cells[col][0], cells[col][1], colour)
    for m in re.finditer(r'<text class="terminal-\d+-(r\d+)" x="([\d.]+)" y="([\d.]+)"[^>]*>'
                         r"([^<]*)</text>", svg):
        if round((float(m[3]) - 20) / 24.4) == row:
            for k, ch in enumerate(html.unescape(m[4]).replace("\xa0", " ")):
                col = min(round(float(m[2]) / 12.2) + k, 79)
                # a blank's colour is not seen
                cells[col] = (ch, fills[m[1]] if ch != " " else "", cells[col][2])
    return cells


def test_the_first_paint_draws_the_protocol_list_and_the_log_as_they_are_drawn_after(lab_env):
    """Before the first paint the Run tab has faces in place of the protocol Select (its
    option list, hidden until opened) and of the empty event log; right after the paint the
    widgets take their places.  The first screen is drawn as the widgets draw it: the
    protocol line cell by cell (character, colour, background), the log's background and its
    scroll bar."""
    from textual.widgets import Footer, OptionList, RichLog, Select

    app = NormboxConsole(new_session(lab_env))
    first: dict = {}
    paint = NormboxConsole._first_paint

    def first_paint(self) -> None:
        if self.query_one(Footer).children and not first:
            first.update(svg=self.export_screenshot(),
                         widgets=[type(w).__name__ for w in self.screen.walk_children()])
        paint(self)

    app._first_paint = first_paint.__get__(app)

    async def scenario() -> None:
        async with app.run_test(size=(80, 24)) as pilot:
            await until(pilot, lambda: app.lab_ready, "the lab")
            select = app.query_one("#protocol", Select)
            assert select.value == "reference-sweep"
            first["after"] = app.export_screenshot()
            assert not app.query("#protocol-face") and not app.query("#events-face")
            log = app.query_one("#events", RichLog)
            assert log.show_vertical_scrollbar and log.region.bottom == 23
    asyncio.run(scenario())
    app.session.close()
    assert "RichLog" not in first["widgets"]
    assert "SelectOverlay" not in first["widgets"] and OptionList.__name__ not in first["widgets"]
    before, after = _cells(first["svg"], 3), _cells(first["after"], 3)
    assert "".join(c for c, _, _ in before[:26]) == "reference-sweep         ▼ "
    assert before[:26] == after[:26], (before[:26], after[:26])
    # the log's rows (row 22: the last, empty after the start too): background, scroll bar
    assert _cells(first["svg"], 22) == _cells(first["after"], 22)
    assert _cells(first["svg"], 22)[0][2] != _cells(first["svg"], 22)[79][2]   # a bar is drawn
