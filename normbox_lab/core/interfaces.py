"""The old import path of the instrument roles: they live in `normbox_lab.core.capabilities`
(one contract: capabilities, and the roles as named bundles of them)."""

from normbox_lab.core.capabilities import (
    Gonioreflectometer,
    Instrument,
    InstrumentIdentity,
    LightSource,
    RotationStage,
    Spectrometer,
    Spectroradiometer,
)

__all__ = [
    "Gonioreflectometer",
    "Instrument",
    "InstrumentIdentity",
    "LightSource",
    "RotationStage",
    "Spectrometer",
    "Spectroradiometer",
]
