"""`demo --errors SPEC` writes the spec into the lab config (lab.toml), which every run of the
campaign stores as its lab config and the world reads back.  A `seed=N` in the spec picks the
error sources' draws: it must survive that round trip (it was dropped: `ErrorSources.spec()`
names the sources only, so the world drew with the lab's seed instead), and a re-run with the
same spec must inject the same errors."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.acquire.config import format_config, parse_config
from normbox_lab.analyze.budget import errors_for_run
from normbox_lab.core.error_sources import parse_error_spec
from normbox_lab.demo import DemoOptions, demo_config, error_spec
from normbox_lab.sim.world import VirtualNormbox

WL = np.arange(380.0, 781.0)
SPEC = "angle=1,angle-sweep=1,cs1000=0.02,cs1000-wl=0.3,qepro-snr=1000"


def _world_from_lab_toml(opts: DemoOptions, tmp_path) -> tuple[str, VirtualNormbox]:
    """The demo's lab.toml as written and read back (what the runs store), and the world built
    from it, as `run_demo` does."""
    tmp_path.mkdir(parents=True, exist_ok=True)
    path = tmp_path / "lab.toml"
    path.write_text(format_config(demo_config(opts, "quick", tmp_path / "cache")))
    config = parse_config(path.read_text(), str(path))
    return config.text, VirtualNormbox(config=config)


def _injected(world: VirtualNormbox) -> np.ndarray:
    """The errors the world injects: angle errors of a few readings, the radiometer's gain and
    wavelength shift on a flat and a sloped spectrum, the gonio's noise."""
    e = world.errors
    angles = [e.angle_error_deg(a, p, n) for a in (30.0, 65.0, 90.0) for p in (1, 7)
              for n in (0, 1)]
    ramp = np.linspace(1.0, 2.0, WL.size)
    radiometer = np.concatenate([e.radiometer(WL, ramp, (p, a, 0)) for p in (1, 7)
                                 for a in (30.0, 90.0)])
    gonio = e.gonio(np.linspace(0.1, 1.0, 50), ("patch-1", 0))
    return np.concatenate([angles, radiometer, gonio])


@pytest.mark.parametrize("truth", ["model", "paper"])
def test_the_errors_seed_survives_to_the_stored_run_and_a_rerun_injects_the_same(
        truth, tmp_path):
    opts = DemoOptions(quick=True, truth=truth, errors=f"{SPEC},seed=5", out_dir=str(tmp_path))
    assert error_spec(opts).endswith(",seed=5"), error_spec(opts)
    text, world = _world_from_lab_toml(opts, tmp_path / "a")
    assert world.errors.seed == 5
    # what the budget reads from the stored run's lab config
    assert errors_for_run(text, None).seed == 5
    # the same draws as the spec itself, and a re-run injects exactly the same errors
    expected = parse_error_spec(f"{SPEC},seed=5")
    if truth == "model":
        assert world.errors == expected
    _, again = _world_from_lab_toml(opts, tmp_path / "b")
    assert np.array_equal(_injected(world), _injected(again))
    # another seed draws other errors (the seed is not ignored)
    other = DemoOptions(quick=True, truth=truth, errors=f"{SPEC},seed=6", out_dir=str(tmp_path))
    _, world6 = _world_from_lab_toml(other, tmp_path / "c")
    assert world6.errors.seed == 6
    assert not np.allclose(_injected(world), _injected(world6))


def test_without_a_seed_the_spec_draws_with_the_labs_seed(tmp_path):
    opts = DemoOptions(quick=True, truth="model", errors=SPEC, out_dir=str(tmp_path))
    assert "seed" not in error_spec(opts)
    _, world = _world_from_lab_toml(opts, tmp_path)
    assert world.errors.seed == opts.seed
    # a seed equal to the lab's is the same campaign
    same = DemoOptions(quick=True, truth="model", errors=f"{SPEC},seed={opts.seed}",
                       out_dir=str(tmp_path))
    _, world_same = _world_from_lab_toml(same, tmp_path / "s")
    assert np.array_equal(_injected(world), _injected(world_same))
