"""Worlds for the emulators in tests (shared by the instrument and the acquisition tests)."""

from __future__ import annotations

import numpy as np


class FlatWorld:
    """A gonioreflectometer world whose sample has the same BRDF at every geometry and
    wavelength (1/sr)."""

    def __init__(self, brdf_per_sr: float) -> None:
        self.f = brdf_per_sr

    def brdf_truth(self, theta_i_deg, theta_o_deg, tilt_deg, wavelength_nm):
        return np.full(np.shape(wavelength_nm), self.f)
