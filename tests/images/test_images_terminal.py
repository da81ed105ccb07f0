"""Terminal previews: two pixels per cell, colours from the image, maps through a colour map."""

import numpy as np

from normbox_lab.images.terminal import as_uint8, downsample, half_block_text


def test_half_blocks_carry_the_upper_and_lower_pixel_colours():
    img = np.zeros((4, 2, 3), dtype=np.uint8)
    img[0, 0] = (255, 0, 0)
    img[1, 0] = (0, 0, 255)
    img[2:, 1] = (10, 20, 30)
    text = half_block_text(img, width_cells=2)
    assert text.plain == "▀▀\n▀▀"
    spans = {(s.start, str(s.style)) for s in text.spans}
    assert (0, "rgb(255,0,0) on rgb(0,0,255)") in spans
    assert (4, "rgb(10,20,30) on rgb(10,20,30)") in spans


def test_downsample_averages_boxes_and_keeps_aspect():
    img = np.zeros((240, 320, 3), dtype=np.uint8)
    img[:, :160] = 200
    small = downsample(img, 40)
    assert small.shape == (30, 40, 3)
    assert np.all(small[:, :20] == 200) and np.all(small[:, 20:] == 0)


def test_scalar_maps_use_a_colour_map_and_float_images_are_encoded():
    m = np.array([[0.0, 5.0], [10.0, np.nan]])
    rgb = as_uint8(m, vmax=10.0)
    assert rgb.shape == (2, 2, 3) and rgb.dtype == np.uint8
    assert rgb[0, 0].sum() < rgb[0, 1].sum() < rgb[1, 0].sum()   # magma brightens with value
    np.testing.assert_array_equal(as_uint8(np.full((1, 1, 3), 0.5)), [[[128, 128, 128]]])
