"""Operators answer the engine's prompts (`PromptRequest` → choice).

- `VirtualOperator` (simulated labs): carries out what a prompt asks on the virtual world
  ("place patch N" → `world.place_patch(N)`, "mount material" → `world.mount_gonio_material`,
  "aim at panel point" → `world.aim_panel`), taking `response_s` of lab-clock time, and answers
  fault prompts with a fixed policy (retry / skip / abort; retry at most `max_fault_retries`
  times per key, then skip).
- `TerminalOperator` (real labs, `normbox-lab run`): prints the prompt and reads the answer
  (in a simulated lab with `--terminal-operator`, "ok" also does the action in the world).
"""

from __future__ import annotations

import sys
from typing import Any, TextIO

from normbox_lab.core.clock import Clock


class VirtualOperator:
    interactive = False           # answers at once: Ctrl-C during its prompts is a normal pause

    def __init__(self, world: Any, clock: Clock, *, fault_policy: str = "retry",
                 response_s: float = 5.0, max_fault_retries: int = 3) -> None:
        if fault_policy not in ("retry", "skip", "abort"):
            raise ValueError(f"fault policy must be retry, skip or abort, not {fault_policy!r}")
        self.world = world
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
            self.log.append((req.key, choice))
            return choice
        self.clock.sleep(self.expected_response_s)
        act_on_world(self.world, req)
        self.log.append((req.key, "ok"))
        return "ok"


def act_on_world(world: Any, req: Any) -> None:
    """Do in the simulated world what an operator prompt asks (nothing without a world)."""
    if world is None:
        return
    action = req.data.get("action")
    if action == "place_patch" and hasattr(world, "place_patch"):
        world.place_patch(int(req.data["patch"]))
    elif action == "mount_gonio_material" and hasattr(world, "mount_gonio_material"):
        material = req.data["material"]
        if isinstance(material, int) or str(material).isdigit():
            material = f"patch-{int(material)}"     # the worlds' material names
        world.mount_gonio_material(material)
    elif action == "aim_panel" and hasattr(world, "aim_panel"):
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
        self.world = world            # a simulated lab: "ok" does the action in the world

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
