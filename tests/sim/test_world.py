"""The VirtualNormbox world: state from the operator, rotator and sphere; what instruments see;
and one driver → emulator → world → reading round trip (CS-1000A over sim://)."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.predict import brdf_model as bm
from normbox_lab.predict.materials import truth_brdf_inplane, truth_patch, truth_wall
from normbox_lab.sim.world import VirtualNormbox


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    return str(tmp_path_factory.mktemp("world-cache"))


@pytest.fixture
def world(cache_dir):
    return VirtualNormbox(quality="quick", cache_dir=cache_dir)


class FakeRotator:
    def __init__(self, angle_deg: float) -> None:
        self.angle = angle_deg

    def angle_deg(self) -> float:
        return self.angle


class FakeSphere:
    def __init__(self, output: float, state: str = "on") -> None:
        self.output = output
        self._state = state

    def relative_output(self) -> float:
        return self.output

    def state(self) -> str:
        return self._state


def _luminance(wl, radiance):
    from normbox_lab.predict.render import luminance_cd_m2

    return luminance_cd_m2(wl, radiance)


def test_radiance_in_view_end_to_end(world):
    world.place_patch(19)
    world.set_sample_angle(30.0)
    wl, radiance = world.radiance_in_view()
    assert wl[0] == 380.0 and wl[-1] == 780.0 and np.all(np.diff(wl) == 1.0)
    assert radiance.shape == (401,) and np.all(radiance >= 0)
    # tens to hundreds of cd/m²: a white patch at 30° is the brightest configuration
    assert 120.0 < _luminance(wl, radiance) < 300.0
    r = world.last_render
    assert r is not None and np.all(r.std_error > 0)
    # the 1 nm spectrum is the band spectrum interpolated
    assert np.interp(r.wavelength_nm, wl, radiance) == pytest.approx(r.radiance)
    # a dark patch at 90° (indirect light) is ~100× darker
    world.place_patch(24)
    world.set_sample_angle(90.0)
    assert 0.3 < _luminance(*world.radiance_in_view()) < 5.0
    assert world.placed == [19, 24]


def test_rotator_and_sphere_drive_the_view(world):
    world.place_patch(19)
    world.set_sample_angle(90.0)                    # ignored once a rotator is attached
    world.attach_rotator(FakeRotator(30.0))
    assert world.angle_deg() == 30.0
    _, full = world.radiance_in_view()
    world.attach_sphere(FakeSphere(0.5, "on"))
    _, half = world.radiance_in_view()
    assert np.allclose(half, 0.5 * full)
    assert world.lamp_state == "on"
    world.attach_sphere(FakeSphere(0.0, "off"))
    _, dark = world.radiance_in_view()
    assert not np.any(dark)
    world.attach_sphere(None)
    world.attach_rotator(FakeRotator(30.0004))      # encoder noise: the same (cached) render
    _, again = world.radiance_in_view()
    assert np.array_equal(again, full)
    assert world.last_render.cached


def test_aim_panel_sees_the_lamp_map(world):
    from normbox_lab.predict.scene import panel_map

    world.aim_panel(0.0, 0.0)
    wl, centre = world.radiance_in_view()
    world.aim_panel(-88.0, -80.0)
    _, corner = world.radiance_in_view()
    m = panel_map(3.0)
    assert np.allclose(corner / centre, m[0, 0] / m[2, 2])
    # the mean over the 25 points is the lamp's luminance
    lum = np.mean([_luminance(wl, world.panel_radiance(x, y))
                   for x in (-88, -44, 0, 44, 88) for y in (-80, -40, 0, 40, 80)])
    assert lum == pytest.approx(world.lamp.luminance_cd_m2, rel=1e-3)
    world.place_patch(3)                            # placing a patch ends the aim
    assert world.aim is None


def test_brdf_truth_of_the_mounted_material(world, cache_dir):
    wl = np.arange(380.0, 781.0, 10.0)
    world.mount_gonio_material("patch-18")
    got = world.brdf_truth(-30.0, 30.0, 4.0, wl)
    assert got.shape == wl.shape
    assert np.array_equal(got, truth_brdf_inplane(truth_patch(18), -30.0, 30.0, wl, 4.0))
    world.mount_gonio_material("wall")
    wall = world.brdf_truth(-30.0, 10.0, 4.0, wl)
    assert np.allclose(wall, truth_brdf_inplane(truth_wall(), -30.0, 10.0, wl, 4.0))
    with pytest.raises(ValueError):
        world.mount_gonio_material("patch-0")
    mats = world.materials()
    assert len(mats) == 26 and mats["patch-18"].alpha < 0.2 and mats["wall"] is world.wall
    # the closure world: the truth is the fit model
    model_world = VirtualNormbox(truth="model", quality="quick", cache_dir=cache_dir)
    model_world.mount_gonio_material("patch-7")
    m = truth_patch(7, "model")
    wi, wo = bm.inplane_directions(-50.0, 20.0, 4.0)
    kd, ks, _ = m.spectra_at(wl)
    assert np.array_equal(model_world.brdf_truth(-50.0, 20.0, 4.0, wl),
                          bm.ct_ggx_brdf(wi, wo, kd, ks, m.alpha, m.eta, m.c))


def test_constructed_from_a_lab_config(cache_dir):
    from types import SimpleNamespace

    from normbox_lab.core.geometry import NormboxGeometry

    cfg = SimpleNamespace(geometry=NormboxGeometry(sample_height_mm=220.0),
                          render={"quality": "quick", "truth": "model", "cache_dir": cache_dir})
    w = VirtualNormbox(config=cfg)
    assert w.geometry.sample_height_mm == 220.0
    assert w.truth == "model" and w.quality == "quick" and w.cache_dir == cache_dir


def test_driver_emulator_world_reading(world):
    """CS-1000A driver ⇄ bytes ⇄ emulator ⇄ VirtualNormbox: the reading is the render."""
    from normbox_lab.core.clock import VirtualClock
    from normbox_lab.drivers import cs1000
    from normbox_lab.sim import core

    clock = VirtualClock()
    core.CONTEXT.reset(clock=clock, world=world)
    try:
        world.place_patch(13)
        world.set_sample_angle(45.0)
        radiometer = cs1000.CS1000A.open("sim://cs1000a?noise=off&key=world-test", clock)
        try:
            reading = radiometer.measure()
        finally:
            radiometer.close()
    finally:
        core.CONTEXT.reset()
    wl, expected = world.radiance_in_view()
    assert np.array_equal(reading.wavelength_nm, wl)
    assert np.allclose(reading.radiance_W_sr_m2_nm, expected, rtol=2e-3,
                       atol=1e-4 * expected.max())
    assert reading.colorimetry.Y == pytest.approx(_luminance(wl, expected), rel=5e-3)
