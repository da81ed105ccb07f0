"""The demo's child renders the sweep's truth ahead (`demo_prewarm.render_truth_ahead`), from
the sweep's end, into the lab config's render cache.  What it leaves there must be exactly what
the demo's own world would have rendered (same keys, same numbers), so the campaign does not
depend on which process traced a configuration; with error sources on it renders nothing (the
sample-angle errors move the rendered angles)."""

from __future__ import annotations

import numpy as np

from normbox_lab.acquire.config import format_config, parse_config
from normbox_lab.demo import DemoOptions, demo_config, make_world
from normbox_lab.demo_prewarm import render_truth_ahead


def _lab_toml(opts: DemoOptions, tmp_path):
    path = tmp_path / "lab.toml"
    path.write_text(format_config(demo_config(opts, "quick", tmp_path / "render-cache")))
    return path, parse_config(path.read_text(), str(path))


def test_the_truth_rendered_ahead_is_what_the_demos_world_reads(tmp_path):
    opts = DemoOptions(quick=True, out_dir=str(tmp_path))
    path, config = _lab_toml(opts, tmp_path)
    steps: list[str] = []
    assert render_truth_ahead(path, [19, 7], [30.0, 90.0],
                              on_step=lambda name, s: steps.append(name)) == 4
    assert steps == ["truth ahead at 90°", "truth ahead at 30°"]      # the sweep's end first
    assert len(list((tmp_path / "render-cache").glob("fast-*.npz"))) == 4
    # the demo's world (make_world, as run_demo builds it) finds every one, traces none
    world, _ = make_world(config, opts, "quick")
    traced = []
    world.fast._render_view = lambda **kw: traced.append(kw)
    kept = {(p, a): world.render(p, a) for p in (19, 7) for a in (30.0, 90.0)}
    assert traced == [] and all(r.cached for r in kept.values())
    # and what it finds is what a world without a cache renders, bit for bit
    fresh = parse_config(path.read_text().replace(str(tmp_path / "render-cache"),
                                                  str(tmp_path / "other-cache")), str(path))
    world2, _ = make_world(fresh, opts, "quick")
    for (p, a), r in kept.items():
        again = world2.render(p, a)
        assert not again.cached
        np.testing.assert_array_equal(again.radiance, r.radiance)
        np.testing.assert_array_equal(again.std_error, r.std_error)


def test_with_error_sources_on_nothing_is_rendered_ahead(tmp_path):
    opts = DemoOptions(quick=True, errors="angle=1", out_dir=str(tmp_path))
    path, _ = _lab_toml(opts, tmp_path)
    assert render_truth_ahead(path, [19], [30.0]) == 0
    assert not list((tmp_path / "render-cache").glob("fast-*.npz"))
