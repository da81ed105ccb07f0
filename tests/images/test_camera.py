"""images.camera / tracer / normbox_view / cornell / figure1: the virtual camera closes on the
radiometer, its layers and the Wilkie & Weidlich auxiliary images close on themselves, depth and
normals are exact, seeds reproduce.

All scenes use fit-family materials (no backscatter, no dispersion), so every test shares one
set of compiled kernels."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.images import camera as cam
from normbox_lab.images import cornell as cornell_room
from normbox_lab.images import normbox_view, tracer
from normbox_lab.images.figure1 import figure1
from normbox_lab.predict.materials import Material

FLAT_NM = np.array([360.0, 830.0])
SMALL = {"width": 32, "height": 24}


@pytest.fixture(scope="module")
def cornell() -> cornell_room.CornellScene:
    return cornell_room.cornell_scene(SMALL["width"], SMALL["height"])


def _grey_materials() -> dict[str, Material]:
    """Neutral (flat) materials of different albedo, one glossy."""
    wl = np.array([380.0, 780.0])
    out = {name: Material.diffuse(name, [r, r], wl)
           for name, r in zip(cornell_room.CORNELL_SLOTS, (0.5, 0.7, 0.3, 0.6, 0.4, 0.85), strict=True)}
    out["box"] = Material("glossy grey", wl, kd=[0.6, 0.6], ks=[0.4, 0.4], alpha=0.2, eta=1.5,
                          c=0.01)
    return out


def _grow(mask: np.ndarray) -> np.ndarray:
    """The mask and its 8 neighbours (pixels whose area may share an edge with it)."""
    out = mask.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            out |= np.roll(mask, (dy, dx), axis=(0, 1))
    return out


def _blue_lamp() -> tuple[np.ndarray, np.ndarray]:
    wl = np.arange(360.0, 831.0, 5.0)
    return wl, 0.02 + np.exp(-0.5 * ((wl - 450.0) / 20.0) ** 2)


def test_layers_sum_to_radiance_and_depth_normal_are_exact_on_planes(cornell):
    img = cornell.tracer.render(cornell_room.cornell_materials(), *_blue_lamp(), spp=8, seed=1)
    h, w = SMALL["height"], SMALL["width"]
    assert img.radiance.shape == (h, w, 81) and img.wavelength_nm[0] == 380.0
    total = img.emission + img.diffuse + img.specular + img.indirect
    np.testing.assert_allclose(total, img.radiance, rtol=1e-5, atol=1e-7)
    for layer in ("diffuse", "indirect", "emission", "cwni", "nwci"):
        assert np.all(np.isfinite(getattr(img, layer)))
        assert np.any(getattr(img, layer) > 0), layer
    assert np.all(img.specular == 0.0)                     # Lambertian materials only
    # emission only where the light is in the pixel (its centre ray or a neighbour's hits it)
    assert np.all(img.emission[~_grow(img.mask("light"))] == 0.0) and np.any(img.emission > 0)
    # depth and normal along the pixel-centre rays, against the planes' equations
    rows, cols = np.mgrid[0:h, 0:w]
    d = img.camera.ray_direction(cols + 0.5, rows + 0.5)
    o = np.asarray(img.camera.origin_m)
    planes = {"back": (1, 0.5, (0.0, -1.0, 0.0)), "floor": (2, 0.0, (0.0, 0.0, 1.0)),
              "left": (0, -0.5, (1.0, 0.0, 0.0)), "right": (0, 0.5, (-1.0, 0.0, 0.0))}
    for slot, (axis, coord, normal) in planes.items():
        m = img.mask(slot)
        assert m.sum() >= 6, slot
        np.testing.assert_allclose(img.depth_m[m], (coord - o[axis]) / d[m][:, axis],
                                   rtol=2e-5)
        np.testing.assert_allclose(img.normal[m], np.broadcast_to(normal, (m.sum(), 3)),
                                   atol=1e-6)
    miss = img.slot_id == -1
    assert miss.sum() > 0 and np.all(np.isinf(img.depth_m[miss]))
    assert np.all(img.normal[miss] == 0.0)
    assert np.all(img.radiance[~_grow(~miss)] == 0.0)           # all of the pixel misses
    # every hit normal faces the camera
    hit = ~miss
    assert np.all(np.sum(img.normal[hit] * d[hit], axis=-1) < 0)


def test_cwni_and_nwci_equal_the_image_under_neutral_light_on_neutral_materials(cornell):
    img = cornell.tracer.render(_grey_materials(), FLAT_NM, [1.0, 1.0], spp=8, seed=2)
    lit = img.radiance - img.emission
    assert np.any(img.specular > 0)                         # the glossy box
    np.testing.assert_allclose(img.cwni, lit, rtol=2e-5, atol=1e-7)
    np.testing.assert_allclose(img.nwci, lit, rtol=2e-5, atol=1e-7)
    # directly viewed luminaires are omitted from both auxiliary images: where a pixel's centre
    # sees the light (radiance 1), only the pixel's share of the dark ceiling is left
    light = img.mask("light")
    assert light.sum() > 0 and np.all(img.emission[light] > 0.2)
    assert np.all(img.cwni[light] < 0.05) and np.all(img.nwci[light] < 0.05)


def test_cwni_shows_the_white_object_neutral_under_a_coloured_light(cornell):
    """Blue light, red and green walls: CWNI of the white box is flat (illuminant E, xy =
    1/3, 1/3) though its raw spectrum follows the lamp and the walls' bleeding; NWCI of a
    neutral surface is its raw image, of the red wall it is not."""
    from normbox_lab.images.color import XYZ_to_xy

    img = cornell.tracer.render(cornell_room.cornell_materials(), *_blue_lamp(), spp=16, seed=3)
    box = img.mask("box")
    assert box.sum() >= 10
    raw, cwni = img.radiance[box], img.cwni[box]
    rel_spread = (cwni.max(axis=-1) - cwni.min(axis=-1)) / cwni.mean(axis=-1)
    assert np.max(rel_spread) < 1e-4
    assert np.min(raw.max(axis=-1) / raw.min(axis=-1)) > 10.0
    np.testing.assert_allclose(XYZ_to_xy(img.XYZ("cwni")[box]), 1.0 / 3.0, atol=2e-4)
    assert np.min(np.abs(XYZ_to_xy(img.XYZ()[box]) - 1.0 / 3.0).max(axis=-1)) > 0.05
    np.testing.assert_allclose(img.nwci[box], raw, rtol=2e-5, atol=1e-9)
    red = img.mask("left")
    assert not np.allclose(img.nwci[red], img.radiance[red], rtol=1e-2)


def test_seeded_images_reproduce_and_do_not_depend_on_chunking(cornell):
    mats = cornell_room.cornell_materials()
    a = cornell.tracer.render(mats, *_blue_lamp(), spp=4, seed=7)
    b = cornell.tracer.render(mats, *_blue_lamp(), spp=4, seed=7)
    np.testing.assert_array_equal(a.radiance, b.radiance)
    np.testing.assert_array_equal(a.cwni, b.cwni)
    other = cornell.tracer.render(mats, *_blue_lamp(), spp=4, seed=8)
    assert not np.array_equal(a.radiance, other.radiance)
    small_chunks = tracer.CameraTracer(cornell.tracer.scene, cornell.bsdf_slots, cornell.emitter,
                                    cornell.camera, emitter_slot="light", chunk_paths=100)
    c = small_chunks.render(mats, *_blue_lamp(), spp=4, seed=7)
    np.testing.assert_array_equal(a.radiance, c.radiance)


@pytest.mark.parametrize("truth", ["model", pytest.param("default", marks=pytest.mark.slow)])
def test_a_camera_at_the_radiometer_closes_on_the_radiometer(truth):
    """The camera at the radiometer's place with its 1° view: the mean of all pixels estimates
    what `FastNormbox.render_view` does, and emission + diffuse + specular what its direct-only
    render (max_depth 2) does — independent estimators of the same band radiances.  "default":
    the truth materials (backscatter lobe, dispersive Fresnel; other kernels, so slow)."""
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.scene import radiometer_position_m, sample_centre_m

    patch, wall = mats.truth_patch(7, truth), mats.truth_wall(truth)
    nc = normbox_view.normbox_camera_renderer()
    g = nc.geometry
    radiometer = cam.PinholeCamera(tuple(radiometer_position_m(g)), tuple(sample_centre_m(g)),
                                   fov_deg=g.radiometer_view_deg, width_px=4, height_px=4)
    img = nc.render(patch=patch, wall=wall, angle_deg=40.0, spp=4096, seed=11,
                    camera=radiometer)
    assert np.all(img.mask("patch"))
    full = nc.box.render_view(patch=patch, wall=wall, angle_deg=40.0, n_paths=1 << 16, seed=12)
    direct = nc.box.render_view(patch=patch, wall=wall, angle_deg=40.0, n_paths=1 << 16,
                                seed=13, direct_only=True)
    se_cam = np.sqrt(np.sum(img.std_error.astype(np.float64) ** 2, axis=(0, 1))) / 16.0
    for camera_mean, ref in ((img.radiance.mean(axis=(0, 1)), full),
                             ((img.emission + img.diffuse + img.specular).mean(axis=(0, 1)),
                              direct)):
        z = (camera_mean - ref.radiance) / np.hypot(se_cam, ref.std_error)
        assert np.max(np.abs(z)) < 4.5, z
        assert abs(np.mean(z)) < 3.0, z
    # a 1° view of a flat patch: the direct share is large at 40°, the indirect is not zero
    share = img.indirect.mean(axis=(0, 1)) / img.radiance.mean(axis=(0, 1))
    assert np.all((share > 0.02) & (share < 0.9))


def test_normbox_view_frames_the_box_and_figure1_of_identical_materials_is_zero():
    from normbox_lab.predict import materials as mats

    patch, wall = mats.truth_patch(19, "model"), mats.truth_wall("model")
    truth = {"patch": patch, "wall": wall}
    fig = figure1(truth, truth, 60.0, width=40, height=30, spp=4, seed=1)
    img = fig.truth
    # the default white: the radiometer's white patch at 30° (more direct light than at 60°)
    assert fig.white_source.startswith("radiometer")
    assert fig.white_XYZ[1] > 1.2 * img.luminance_cd_m2()[img.mask("patch")].mean()
    # the patch, the holder and the lit panel are in view; the corners are outside the box
    for slot in ("patch", "holder", "panel", "wall"):
        assert img.mask(slot).any(), slot
    assert img.slot_id[0, 0] == -1 and img.slot_id[-1, -1] == -1
    centre = img.camera.project(np.array([0.0, 0.0, 0.2]))
    assert img.slot_names[img.slot_id[int(centre[1]), int(centre[0])]] == "patch"
    # same materials, same seed: identical images, ΔE00 = 0 everywhere
    np.testing.assert_array_equal(fig.truth.radiance, fig.fitted.radiance)
    assert np.all(fig.delta_e00 == 0.0) and fig.delta_e00.shape == (30, 40)
    assert fig.truth_srgb.shape == (30, 40, 3) and fig.summary()["max"] == 0.0
    # the converged region map is zero too; the noise floor (an independent second truth
    # render) is not, and the summary reports it
    conv = fig.noise_summary()
    assert conv["max"] == 0.0 and conv["noise_p95"] > 0.0
    assert conv["block_px"] in (2.0, 4.0, 8.0, 16.0)
    on = fig.scene_mask
    assert np.isfinite(fig.noise_floor_blocks[on]).all() and np.isnan(fig.noise_floor_blocks[~on]).all()


def test_a_kept_figure1_is_read_back_bit_for_bit_and_another_material_renders_again(
        tmp_path, monkeypatch):
    """figure1(cache_dir=...): the second identical call reads its views (and the white
    reference) from the cache without tracing, and every image, map and noise floor is the
    same bits; another fitted material is another key (only its view renders again)."""
    from normbox_lab.predict import materials as mats

    truth = {"patch": mats.truth_patch(7, "model"), "wall": mats.truth_wall("model")}
    fitted = {"patch": mats.truth_patch(13, "model"), "wall": mats.truth_wall("model")}
    args = {"width": 24, "height": 18, "spp": 4, "seed": 2, "cache_dir": tmp_path}
    first = figure1(truth, fitted, 45.0, **args)
    assert len(list(tmp_path.glob("camera-*.npz"))) == 2          # the truth's, the fit's
    nc = normbox_view.normbox_camera_renderer()
    traced: list[str] = []
    render = nc.render
    monkeypatch.setattr(nc, "render", lambda **kw: traced.append(kw["patch"].name) or render(**kw))
    again = figure1(truth, fitted, 45.0, **args)
    assert traced == []
    for name in ("radiance", "emission", "diffuse", "specular", "indirect", "cwni", "nwci",
                 "std_error", "depth_m", "normal", "slot_id"):
        np.testing.assert_array_equal(getattr(again.truth, name), getattr(first.truth, name))
    assert again.truth.camera == first.truth.camera and again.truth.info == first.truth.info
    np.testing.assert_array_equal(again.fitted.radiance, first.fitted.radiance)
    np.testing.assert_array_equal(again.delta_e00, first.delta_e00)
    np.testing.assert_array_equal(again.noise_floor_blocks, first.noise_floor_blocks)
    np.testing.assert_array_equal(again.white_XYZ, first.white_XYZ)
    other = {**fitted, "patch": mats.truth_patch(5, "model")}
    figure1(truth, other, 45.0, **args)
    assert traced == [other["patch"].name] * 2                      # both seeds (halves)


def test_region_block_means_average_within_one_block_and_one_material():
    from normbox_lab.images.figure1 import region_block_means

    xyz = np.arange(4 * 4 * 3, dtype=float).reshape(4, 4, 3)
    slot = np.array([[1, 1, 2, 2], [1, 2, 2, 2], [3, 3, 3, 3], [3, 3, 3, 3]])
    mask = slot != 3
    mask[0, 0] = True
    out = region_block_means(xyz, slot, mask, 2)
    # block (0, 0): slot 1 = pixels (0,0), (0,1), (1,0); slot 2 = (1,1) alone
    np.testing.assert_array_equal(out[0, 0], xyz[[0, 0, 1], [0, 1, 0]].mean(axis=0))
    np.testing.assert_array_equal(out[1, 0], out[0, 1])
    np.testing.assert_array_equal(out[1, 1], xyz[1, 1])
    np.testing.assert_array_equal(out[0, 2], xyz[0:2, 2:4].reshape(-1, 3).mean(axis=0))
    assert np.isnan(out[2:]).all()
    # the mean over the masked pixels is preserved (an unbiased region estimate)
    np.testing.assert_allclose(out[mask].mean(axis=0), xyz[mask].mean(axis=0), rtol=1e-12)
    np.testing.assert_allclose(region_block_means(xyz, slot, mask, 1)[mask], xyz[mask])


def test_converged_maps_grow_blocks_until_the_noise_floor_is_below_target():
    from normbox_lab.images.figure1 import converged_maps

    rng = np.random.default_rng(3)
    h, w = 48, 64
    truth = np.ones((h, w, 3)) * np.array([0.30, 0.32, 0.20])
    noisy = truth * (1.0 + 0.05 * rng.normal(size=(h, w, 1)))
    fitted = truth * np.array([1.02, 1.0, 0.97])           # a real colour difference
    slot = np.ones((h, w), dtype=int)
    mask = np.ones((h, w), dtype=bool)
    white = np.array([0.95, 1.0, 1.09])
    b, de, nf = converged_maps(truth, fitted, noisy, slot, mask, white, 0.3)
    assert b > 2
    assert np.percentile(nf, 95) < 0.3
    _b2, _de2, nf2 = converged_maps(truth, fitted, noisy, slot, mask, white, 0.3, (2,))
    assert np.percentile(nf2, 95) > np.percentile(nf, 95)         # more pixels, less noise
    assert np.median(de) > 3 * np.percentile(nf, 95)             # the real difference stands

