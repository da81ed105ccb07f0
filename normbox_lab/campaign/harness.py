"""Execute one campaign scenario: `normbox-lab` itself, in forked processes, on a scenario lab.

Each segment of a run is one process that runs the real command line
(``normbox_lab.cli.main(["run", …])``) with stdin from /dev/null, stdout and stderr to files:
what a user would see.  The process is forked from the campaign's process after everything
heavy was imported once (`preload`), so a segment costs milliseconds of start-up, not the
seconds of an interpreter that imports colour-science.  Inside the segment two observers are
installed before the command runs (they change nothing the command does):

- a subscriber to the engine's events writes a journal (one JSON line per event, written
  unbuffered, so it survives `kill -9`): the event kind, key, virtual time and small data; the
  engine's per-reading estimates at the start of each segment; and, with every stored reading,
  what the world really showed for it (`truth` below);
- the world's `radiance_in_view` / `brdf_truth` note the state they rendered: patch, the
  rotator's physical angle, the panel point aimed at, the lamp's *set* level, the gonio
  material and arm angles (and, for the Mitsuba world, the noise-free render itself).

Operator actions fire at the n-th engine event of a kind: ``kill`` is a real ``SIGKILL`` of
the segment, ``pause`` one ``SIGINT`` (Ctrl-C: pause after the current reading), ``estop``
two (abort now: the emergency stop), ``resume2`` a second ``normbox-lab run --resume`` of the
same run from another interpreter while the segment executes it (it must be refused).  The run is then resumed with ``run --resume UUID``, as a
user would, until it is done or the segments run out.  A segment that outlives its wall-clock
limit is killed and reported as a hang.
"""

from __future__ import annotations

import json
import os
import signal
import sys
import time
import traceback
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from normbox_lab.campaign.scenario import Action, Scenario, lab_toml

#: wall-clock limit of one segment (a virtual-clock run of a small protocol takes < 2 s)
SEGMENT_LIMIT_S = {"analytic": 90.0, "normbox": 600.0}
#: resumes after the scripted actions are used up, before the campaign gives up on the run
EXTRA_RESUMES = 3

_PRELOADED = False


def preload() -> None:
    """Import and warm up, once, what every segment needs (forked segments inherit it)."""
    global _PRELOADED
    if _PRELOADED:
        return
    import normbox_lab.acquire.lab
    import normbox_lab.acquire.session
    import normbox_lab.analyze.qa
    import normbox_lab.cli
    import normbox_lab.sim.labsim
    import normbox_lab.sim.world  # noqa: F401  (no Mitsuba import until the first render)
    from normbox_lab.sim import core
    from normbox_lab.sim.analytic_world import AnalyticWorld
    from normbox_lab.sim.radiometer_common import RadiometerOptics

    core._load_builtin()
    RadiometerOptics().prepare()              # the emulators' colorimetric tables
    import colour  # noqa: F401  (not for the emulators: the drivers' colorimetry needs it)
    AnalyticWorld()                           # the reflectance table
    from normbox_lab.sim import sphere

    sphere.preset_spectrum("D65")
    _PRELOADED = True


@dataclass
class Segment:
    argv: list[str]
    action: Action | None
    rc: int | None = None            # None: killed (by its action, or as a hang)
    killed: bool = False             # by its `kill` action
    hung: bool = False               # past the wall-clock limit
    fired: bool = False              # its action fired
    wall_s: float = 0.0
    stdout: str = ""
    stderr: str = ""
    journal: list[dict[str, Any]] = field(default_factory=list)
    runs_out: tuple[int, str, str] | None = None     # `runs` right after the segment


@dataclass
class Execution:
    scenario: Scenario
    workdir: Path
    store: Path
    lab: Path
    segments: list[Segment]
    run_uuid: str | None
    wall_s: float
    reference: Execution | None = None     # the same scenario without actions (kills only)


# --- inside a segment -------------------------------------------------------------------------
def _nominal_output(world: Any) -> float:
    sphere = getattr(world, "sphere", None)
    if sphere is not None and hasattr(sphere, "level_percent"):
        return float(sphere.level_percent) / 100.0
    return float(getattr(world, "lamp_level", 1.0))


def _install_world_probes(notes: dict[str, Any]) -> None:
    from normbox_lab.sim.analytic_world import AnalyticWorld
    from normbox_lab.sim.world import VirtualNormbox

    classes: list[type] = [AnalyticWorld, VirtualNormbox]

    def wrap(cls: type) -> None:
        view, brdf = cls.radiance_in_view, cls.brdf_truth

        def radiance_in_view(self):
            wl, radiance = view(self)
            note = {"patch": self.patch, "angle_deg": float(self.angle_deg()),
                    "aim": list(self.aim) if self.aim is not None else None,
                    "nominal_output": _nominal_output(self),
                    "output": None, "world": cls.__name__}
            if self.aim is not None:             # the panel point, as this world models it
                note["truth"] = [float(v) for v in self.panel_radiance(*self.aim)
                                 * note["nominal_output"]]
            elif cls is not AnalyticWorld and self.patch is not None:
                r = self.render(self.patch, float(self.angle_deg())
                                + float(getattr(self, "last_angle_error_deg", 0.0)))
                _, full = r.to_1nm(self.wavelength_nm)
                note["truth"] = [float(v) for v in full * note["nominal_output"]
                                 * float(getattr(self, "box_light_gain", 1.0))]
            notes["view"] = note
            return wl, radiance

        def brdf_truth(self, theta_i_deg, theta_o_deg, tilt_deg, wavelength_nm):
            notes["brdf"] = {"theta_i_deg": float(theta_i_deg),
                             "theta_o_deg": float(theta_o_deg), "tilt_deg": float(tilt_deg),
                             "material": self.gonio_material}
            return brdf(self, theta_i_deg, theta_o_deg, tilt_deg, wavelength_nm)

        cls.radiance_in_view = radiance_in_view
        cls.brdf_truth = brdf_truth

    for cls in classes:
        wrap(cls)


def _small(data: Any) -> dict[str, Any]:
    out = {}
    for k, v in dict(data).items():
        if isinstance(v, (str, int, float, bool)) or v is None:
            out[k] = v
        elif k == "prompt":
            out[k] = {"kind": v.kind, "choices": list(v.choices)}
    return out


#: fault kinds that latch a changed physics for the rest of the process (the light, the
#: detector), not one failed exchange
LATCHED_KINDS = ("lamp-drift", "flicker", "lamp-dim", "dark-drift", "tec-drift", "saturation")


def _faults_fired() -> tuple[int, int]:
    """(faults the emulators of this process have injected so far, of which latched)."""
    from normbox_lab.sim import core

    logs = [entry for e in list(core.CONTEXT.instances.values())
            for entry in getattr(getattr(e, "faults", None), "log", ())]
    return len(logs), sum(1 for x in logs if x.split("#")[0] in LATCHED_KINDS)


def _second_owner(argv: list[str], uuid: str) -> dict[str, Any]:
    """`normbox-lab run --resume UUID` from another process while this one executes the run
    (a real interpreter: it must be refused at once, naming this process)."""
    import subprocess

    second = ["run", "--resume", uuid, "--plain"]
    for opt in ("--lab", "--store"):
        if opt in argv:
            second += [opt, argv[argv.index(opt) + 1]]
    try:
        done = subprocess.run([sys.executable, "-m", "normbox_lab", *second], check=False,
                              capture_output=True, text=True, timeout=120,
                              stdin=subprocess.DEVNULL)
    except subprocess.TimeoutExpired:
        return {"rc": None, "stdout": "", "stderr": "timed out after 120 s",
                "owner_pid": os.getpid()}
    return {"rc": done.returncode, "stdout": done.stdout[-600:], "stderr": done.stderr[-1500:],
            "owner_pid": os.getpid()}


def _install_engine_probe(journal_fd: int, action: Action | None, notes: dict[str, Any],
                          argv: list[str]) -> None:
    from normbox_lab.acquire import runner

    original = runner.Engine.run
    counts: dict[str, int] = {}

    def write(obj: dict[str, Any]) -> None:
        os.write(journal_fd, (json.dumps(obj, default=str) + "\n").encode())

    def run(self, *args, **kwargs):
        def on_event(ev) -> None:
            fired, latched = _faults_fired()
            entry = {"ev": ev.kind, "key": ev.key, "t": ev.time_s, "d": _small(ev.data),
                     "f": fired, "latched": latched}
            if ev.kind == "run-started":
                entry["estimates"] = {k: float(v) for k, v in
                                      dict(getattr(self, "_estimates", {}) or {}).items()}
                entry["suspend_timeout_s"] = float(getattr(self, "suspend_timeout_s", 0.0))
            elif ev.kind == "estimates":          # re-estimated after a skipped reading
                entry["estimates"] = {k: float(v) for k, v in
                                      dict(ev.data.get("estimates") or {}).items()}
            if ev.kind == "reading-stored":       # what the world showed since the last one
                entry["view"] = notes.pop("view", None)
                entry["brdf"] = notes.pop("brdf", None)
            write(entry)
            if action is None:
                return
            name = ev.kind if ev.kind != "step-started" else f"step-started:{ev.data.get('kind')}"
            counts[name] = counts.get(name, 0) + 1
            if name == action.event and counts[name] == action.nth:
                write({"action": action.label()})
                if action.what == "resume2":
                    write({"second_owner": _second_owner(argv, str(self.run_uuid))})
                    return
                if action.what == "kill":
                    os.kill(os.getpid(), signal.SIGKILL)
                os.kill(os.getpid(), signal.SIGINT)
                if action.what == "estop":
                    os.kill(os.getpid(), signal.SIGINT)
        self.subscribe(on_event)
        return original(self, *args, **kwargs)

    runner.Engine.run = run


def _child(argv: list[str], workdir: Path, tag: str, action: Action | None,
           probes: bool) -> None:
    """In the forked process: redirect, observe, run the command line, exit with its code."""
    rc = 1
    try:
        os.chdir(workdir)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        for fd, name in ((1, f"{tag}.stdout"), (2, f"{tag}.stderr")):
            out = os.open(name, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(out, fd)
            os.close(out)
        # the Python streams too (a test runner may have put its own objects there)
        sys.stdin = open(0, encoding="utf-8", closefd=False)  # noqa: SIM115
        sys.stdout = open(1, "w", encoding="utf-8", closefd=False)  # noqa: SIM115
        sys.stderr = open(2, "w", encoding="utf-8", buffering=1, closefd=False)  # noqa: SIM115
        signal.signal(signal.SIGINT, signal.default_int_handler)
        if probes:
            journal = os.open(f"{tag}.journal", os.O_WRONLY | os.O_CREAT | os.O_APPEND, 0o644)
            notes: dict[str, Any] = {}
            _install_world_probes(notes)
            _install_engine_probe(journal, action, notes, argv)
        from normbox_lab import cli

        try:
            rc = int(cli.main(argv) or 0)
        except SystemExit as exc:              # argparse and explicit exits
            rc = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except BaseException:                  # noqa: BLE001 - what Python itself prints
            traceback.print_exc()
            rc = 1
    finally:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
        finally:
            os._exit(rc)


def run_cli(argv: list[str], workdir: Path, tag: str, *, action: Action | None = None,
            limit_s: float = 90.0, probes: bool = True) -> Segment:
    """Run `normbox-lab ARGV` in a forked process; the outcome as a `Segment`."""
    seg = Segment(list(argv), action)
    sys.stdout.flush()
    sys.stderr.flush()
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:                                           # pragma: no cover - child
        _child(argv, workdir, tag, action, probes)
    status = None
    while True:
        done, status = os.waitpid(pid, os.WNOHANG)
        if done:
            break
        if time.monotonic() - t0 > limit_s:
            os.kill(pid, signal.SIGKILL)
            _, status = os.waitpid(pid, 0)
            seg.hung = True
            break
        time.sleep(0.005)
    seg.wall_s = time.monotonic() - t0
    if os.WIFSIGNALED(status):
        seg.killed = not seg.hung and os.WTERMSIG(status) == signal.SIGKILL
    else:
        seg.rc = os.WEXITSTATUS(status)
    seg.stdout = _read(workdir / f"{tag}.stdout")
    seg.stderr = _read(workdir / f"{tag}.stderr")
    for line in _read(workdir / f"{tag}.journal").splitlines():
        try:
            entry = json.loads(line)
        except ValueError:                     # a line cut by the kill
            continue
        if "action" in entry:
            seg.fired = True
        seg.journal.append(entry)
    return seg


def _read(path: Path) -> str:
    try:
        return path.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return ""


def _param_args(scenario: Scenario) -> list[str]:
    return [a for k, v in sorted(scenario.params.items())
            for a in ("--param", f"{k}={json.dumps(v, separators=(',', ':'))}")]


def _run_uuid(seg: Segment) -> str | None:
    for entry in seg.journal:
        if entry.get("ev") == "run-started":
            return str(entry["d"].get("run_uuid"))
    return None


def _store_status(store: Path, uuid: str) -> str | None:
    from normbox_lab.acquire.store import Store

    try:
        with Store(store) as s:
            return s.get_run(uuid).status
    except Exception:                          # noqa: BLE001 - the checks report the store
        return None


def execute(scenario: Scenario, workdir: Path, *, with_reference: bool = True) -> Execution:
    """Run the scenario in `workdir` (created): its segments, and for a scenario with a kill
    the same scenario without actions (the uninterrupted run the resume must match)."""
    preload()
    workdir = workdir.resolve()              # the segments run inside it
    workdir.mkdir(parents=True, exist_ok=True)
    lab = workdir / "lab.toml"
    lab.write_text(lab_toml(scenario), encoding="utf-8")
    store = workdir / "store.sqlite"
    limit = SEGMENT_LIMIT_S.get(scenario.world, 90.0)
    common = ["--lab", str(lab), "--store", str(store), "--plain",
              "--fault-policy", scenario.policy]
    t0 = time.monotonic()
    segments: list[Segment] = []
    uuid: str | None = None
    actions = list(scenario.actions)
    for i in range(len(actions) + EXTRA_RESUMES):
        action = actions[i] if i < len(actions) else None
        if uuid is None:
            argv = ["run", scenario.protocol, "--world", scenario.world, *common,
                    *_param_args(scenario)]
        else:
            argv = ["run", "--resume", uuid, *common]
        seg = run_cli(argv, workdir, f"seg{i}", action=action, limit_s=limit)
        segments.append(seg)
        uuid = uuid or _run_uuid(seg)
        if uuid is not None and (seg.killed or seg.hung):
            seg.runs_out = runs_listing(workdir, store, f"seg{i}-runs")
        if uuid is None or seg.hung:
            break
        status = _store_status(store, uuid)
        if status == "done":
            break
        if i >= len(actions) and status in ("failed",):
            break
    ex = Execution(scenario, workdir, store, lab, segments, uuid, 0.0)
    if with_reference and any(a.what == "kill" for a in scenario.actions):
        ex.reference = execute(scenario.with_(actions=()), workdir / "uninterrupted",
                               with_reference=False)
    ex.wall_s = time.monotonic() - t0
    return ex


def runs_listing(workdir: Path, store: Path, tag: str) -> tuple[int, str, str]:
    seg = run_cli(["runs", "--store", str(store)], workdir, tag, probes=False, limit_s=60.0)
    return (-1 if seg.rc is None else seg.rc), seg.stdout, seg.stderr


def qa_listing(workdir: Path, store: Path, run: str, tag: str) -> tuple[int, str, str]:
    seg = run_cli(["qa", run, "--store", str(store)], workdir, tag, probes=False, limit_s=60.0)
    return (-1 if seg.rc is None else seg.rc), seg.stdout, seg.stderr


__all__ = ["Execution", "Segment", "execute", "preload", "qa_listing", "run_cli",
           "runs_listing"]
