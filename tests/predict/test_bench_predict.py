"""`bench predict`'s measurement at the target (normbox_lab.predict.bench): the path count is
interpolated between measured ladder points, never extrapolated; each quantity's noise is the
spread of independent samples (of one sample, or of the mean of batches)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from normbox_lab.predict.bench import Colour, interpolate_count, noise, spread, stock_to_target
from normbox_lab.predict.render import BAND_CENTRES_NM


def test_count_is_interpolated_between_the_ladder_points_around_the_target() -> None:
    ladder = [(1024, 0.0040), (2048, 0.0025), (4096, 0.0010)]
    n, lower = interpolate_count(ladder, 0.0020)
    # log-log between (2048, 0.25 %) and (4096, 0.10 %): not the 1/√N law from 1024
    f = math.log(0.0025 / 0.0020) / math.log(0.0025 / 0.0010)
    assert not lower and n == round(2048 * 2 ** f) == 2425
    assert interpolate_count(ladder, 0.0050) == (1024, True)      # the first point beats it
    assert interpolate_count(ladder, 0.0010) == (4096, False)
    with pytest.raises(ValueError, match="never reached"):
        interpolate_count(ladder, 0.0005)


def _colour() -> Colour:
    return Colour(BAND_CENTRES_NM, np.ones(BAND_CENTRES_NM.size))


def test_noise_of_independent_and_of_correlated_band_errors() -> None:
    rng = np.random.default_rng(3)
    k, nb = 4000, BAND_CENTRES_NM.size
    base = np.full(nb, 0.5)
    independent = base * (1 + 0.01 * rng.standard_normal((k, nb)))
    common = base * (1 + 0.01 * rng.standard_normal((k, 1)))
    c = _colour()
    ni = noise(independent, c, of_mean=False)
    nc = noise(common, c, of_mean=False)
    assert ni["band"] == pytest.approx(0.01, rel=0.03)
    assert nc["band"] == pytest.approx(0.01, rel=0.03)
    # the luminance averages independent band errors down, a common one not at all
    assert nc["Y"] == pytest.approx(0.01, rel=0.05)
    w = c.xyz(np.eye(nb))[:, 1]
    assert ni["Y"] == pytest.approx(0.01 * np.sqrt(np.sum(w ** 2)) / np.sum(w), rel=0.05)
    assert ni["Y"] < 0.3 * nc["Y"]
    # ΔE00 of a pure scale error on a neutral: the lightness difference of L* alone
    from normbox_lab.core.colorimetry import XYZ_to_Lab_D65

    lab = XYZ_to_Lab_D65(c.xyz(common))
    assert nc["ΔE00"] > 0 and np.std(lab[:, 0]) > 0
    # of the mean of k batches: / √k
    nm = noise(common, c, of_mean=True)
    assert nm["Y"] == pytest.approx(nc["Y"] / math.sqrt(k), rel=1e-12)


def test_stock_renders_until_its_batches_reach_the_target() -> None:
    """A stand-in stock renderer whose batches carry independent 1 % band noise × √(64/spp):
    each quantity's render is timed at a batch count that meets its target."""
    from types import SimpleNamespace

    c = _colour()
    calls = []

    def render(spp: int, batches: int, seed: int) -> SimpleNamespace:
        calls.append((spp, batches))
        rng = np.random.default_rng(seed)
        sd = 0.01 * math.sqrt(64 / spp)
        return SimpleNamespace(batches=0.5 * (1 + sd * rng.standard_normal(
            (batches, BAND_CENTRES_NM.size))))

    targets = {"band": 0.002, "Y": 0.0005, "ΔE00": 0.02}
    out = stock_to_target(render, c, targets, seed=1)
    for q, at in out.items():
        assert at.achieved <= 1.10 * targets[q], (q, at)
        assert at.time_s["wall"] >= 0 and "batches" in at.size
    spp, b = (int(x) for x in out["band"].size.replace(" spp × ", " ").split()[:2])
    # 1 % per batch at 64 spp → 0.2 % needs 25 batches of 64 spp (or 100 of 16): 1600 in all
    assert spp * b == pytest.approx(1600, rel=0.2)


def test_spread_names_median_range_and_half_range() -> None:
    assert spread([300.0, 240.0, 360.0]) == "300× (240–360, ±20 %)"
