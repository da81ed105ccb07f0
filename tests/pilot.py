"""Helpers of the console's pilot tests (Textual's `App.run_test()`): a simulated session, waiting
on a condition, answering the operator prompt, the screen as text.  Imported by every
`test_tui*` module; the fixtures (`lab_env`, `fake_drivers`) are in conftest.py."""

from __future__ import annotations

import time

from normbox_lab.acquire.config import SIM_CONFIG_TEMPLATE, parse_config
from normbox_lab.tui.app import PromptScreen
from normbox_lab.tui.controller import Session

ANGLES = "[30, 90]"
PATCHES = "[1, 9, 19]"
KEYS = {f"a{a}/p{p:02d}" for a in (30, 90) for p in (1, 9, 19)}


def new_session(path) -> Session:
    return Session(parse_config(SIM_CONFIG_TEMPLATE, "<sim>"), path / "tui.sqlite",
                   world="analytic", time_scale=0.0)


async def until(pilot, condition, what: str, timeout_s: float = 30.0) -> None:
    t0 = time.monotonic()
    while not condition():
        if time.monotonic() - t0 > timeout_s:
            raise AssertionError(f"timed out waiting for {what}")
        await pilot.pause(0.02)


async def answer_prompt(pilot, app, expect: str | None = None) -> str:
    """Wait for the operator prompt modal, check its text, press Enter; returns the text."""
    await until(pilot, lambda: isinstance(app.screen, PromptScreen)
                and bool(app.screen.query("#prompt-message"))       # composed
                and app.session.operator is not None and app.session.operator.pending is not None,
                "an operator prompt")
    screen = app.screen
    text = str(screen.query_one("#prompt-message").render())
    if expect is not None:
        assert expect in text, text
    await pilot.press("enter")
    # at time scale 0 the next prompt may already be up: wait for *this* one to close
    await until(pilot, lambda: app.screen is not screen, "the prompt to close")
    return text


def screen_text(app) -> str:
    """What the terminal shows now (the top screen composited), as plain text lines."""
    strips = app.screen._compositor.render_strips()
    return "\n".join("".join(seg.text for seg in strip) for strip in strips)


async def set_reduced_parameters(pilot, app) -> None:
    await until(pilot, lambda: app.lab_ready, "the lab")
    app.set_parameter("angles_deg", ANGLES)
    app.set_parameter("patches", PATCHES)
    assert app.parameters()["patches"] == [1, 9, 19]
