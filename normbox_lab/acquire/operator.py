"""Operators answer the engine's prompts (`PromptRequest` → choice).

- `VirtualOperator` (simulated labs): carries out what a prompt asks on the virtual world
  ("place patch N" → `world.place_patch(N)`, "mount material" → `world.mount_gonio_material`,
  "aim at panel point" → `world.aim_panel`; the world is an `OperatorWorld`), taking
  `response_s` of lab-clock time, and answers fault prompts with a fixed policy (retry / skip /
  abort; retry at most `max_fault_retries` times per key, then skip) — only ever with a choice
  the prompt offers (a prompt without "skip" gets "abort" once retries are used up).
- `TerminalOperator` (real labs, `normbox-lab run`): prints the prompt and reads the answer
  (in a simulated lab with `--terminal-operator`, "ok" also does the action in the world).
"""

from __future__ import annotations

import sys
from typing import Any, Protocol, TextIO, runtime_checkable

from normbox_lab.core.clock import Clock
from normbox_lab.core.errors import NormboxError


@runtime_checkable
class OperatorWorld(Protocol):
    """What an operator does by hand in a simulated lab, done to the virtual Normbox (both
    worlds, `sim.world.VirtualNormbox` and `sim.analytic_world.AnalyticWorld`, are one)."""

    def place_patch(self, n: int) -> None:
        """Put ColorChecker patch `n` (1–24) on the sample holder."""
        ...

    def mount_gonio_material(self, name: str | int) -> None:
        """Mount a material ("patch-7", "wall") on the gonioreflectometer."""
        ...

    def aim_panel(self, x_mm: float, y_mm: float) -> None:
        """Aim the radiometer at a point of the light panel (light map)."""
        ...


def _operator_world(world: object) -> OperatorWorld | None:
    if world is None or isinstance(world, OperatorWorld):
        return world
    raise NormboxError(f"a simulated operator needs a world that places patches, mounts "
                       f"gonio materials and aims at the panel; {type(world).__name__} does not")


class VirtualOperator:
    interactive = False           # answers at once: Ctrl-C during its prompts is a normal pause

    def __init__(self, world: Any, clock: Clock, *, fault_policy: str = "retry",
                 response_s: float = 5.0, max_fault_retries: int = 3) -> None:
        if fault_policy not in ("retry", "skip", "abort"):
            raise ValueError(f"fault policy must be retry, skip or abort, not {fault_policy!r}")
        self.world = _operator_world(world)
        self.clock = clock
        self.fault_policy = fault_policy
        self.expected_response_s = float(response_s)
        self.max_fault_retries = max_fault_retries
        self._fault_counts: dict[str, int] = {}
        self.log: list[tuple[str, str]] = []

    def __call__(self, req: Any) -> str:
        if req.kind == "fault":
            n = self._fault_counts[req.key] = self._fault_counts.get(req.key, 0) + 1
            choice = self.fault_policy
            if choice == "retry" and n > self.max_fault_retries:
                choice = "skip"
            if choice not in req.choices:
                # e.g. preparing an instrument offers only retry / abort: never skip there
                choice = "abort" if "abort" in req.choices else req.choices[0]
            self.log.append((req.key, choice))
            return choice
        self.clock.sleep(self.expected_response_s)
        act_on_world(self.world, req)
        self.log.append((req.key, "ok"))
        return "ok"


def act_on_world(world: OperatorWorld | None, req: Any) -> None:
    """Do in the simulated world what an operator prompt asks (nothing without a world)."""
    if world is None:
        return
    action = req.data.get("action")
    if action == "place_patch":
        world.place_patch(int(req.data["patch"]))
    elif action == "mount_gonio_material":
        material = req.data["material"]
        if isinstance(material, int) or (str(material).isascii() and str(material).isdigit()):
            material = f"patch-{int(material)}"     # the worlds' material names
        world.mount_gonio_material(material)
    elif action == "aim_panel":
        world.aim_panel(float(req.data["x_mm"]), float(req.data["y_mm"]))


class TerminalOperator:
    """Asks on the terminal.  Enter = the first choice."""

    expected_response_s = 20.0
    interactive = True            # a person is asked: Ctrl-C at the prompt stops the run there

    def __init__(self, stream_in: TextIO | None = None, stream_out: TextIO | None = None,
                 before: Any = None, world: Any = None) -> None:
        self.stream_in = stream_in or sys.stdin
        self.stream_out = stream_out or sys.stdout
        self.before = before          # called before asking (e.g. to pause a progress bar)
        self.world = _operator_world(world)   # a simulated lab: "ok" does the action there

    def __call__(self, req: Any) -> str:
        if self.before is not None:
            self.before()
        choices = "/".join(req.choices)
        while True:
            self.stream_out.write(f"\n>>> {req.message}\n    [{choices}] (Enter = "
                                  f"{req.choices[0]}): ")
            self.stream_out.flush()
            line = self.stream_in.readline()
            if not line:                      # end of input: take the safe way out
                return "abort" if "abort" in req.choices else req.choices[0]
            answer = line.strip().lower() or req.choices[0]
            matches = [c for c in req.choices if c.startswith(answer)]
            if len(matches) == 1:
                if matches[0] == "ok":
                    act_on_world(self.world, req)
                return matches[0]
            self.stream_out.write(f"    please answer one of {choices}\n")
