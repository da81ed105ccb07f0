"""Multilayer spectral OpenEXR (normbox_lab.core.exr): exact round trip, Fichet et al. 2021
channel names, and the file checked by an independent header parser and colour-science's regex."""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

from normbox_lab.core import exr

WAVELENGTH_NM = np.arange(380.0, 781.0, 5.0)


def _layers(rng: np.random.Generator, height: int = 5, width: int = 7,
            bands: int = WAVELENGTH_NM.size) -> dict[str, np.ndarray]:
    layers = {k: rng.random((height, width, bands)).astype(np.float32) * 0.05
              for k in exr.SPECTRAL_LAYERS}
    layers["depth_m"] = (0.3 + rng.random((height, width))).astype(np.float32)
    n = rng.normal(size=(height, width, 3))
    layers["normal"] = (n / np.linalg.norm(n, axis=2, keepdims=True)).astype(np.float32)
    layers["preview_rgb"] = rng.random((height, width, 3)).astype(np.float32)
    return layers


def _read_exr_header(path: Path) -> tuple[list[tuple[str, int]], dict[str, tuple[str, bytes]]]:
    """Parse an OpenEXR header by hand (OpenEXR file layout): channels (name, pixel type) and
    raw attributes {name: (type, bytes)}. Independent of Mitsuba and of the module under test."""
    data = path.read_bytes()
    magic, _version = struct.unpack_from("<ii", data, 0)
    assert magic == 20000630
    pos = 8
    attributes: dict[str, tuple[str, bytes]] = {}

    def cstring(at: int) -> tuple[str, int]:
        end = data.index(b"\0", at)
        return data[at:end].decode(), end + 1

    while True:
        name, pos = cstring(pos)
        if not name:
            break
        kind, pos = cstring(pos)
        (size,) = struct.unpack_from("<i", data, pos)
        pos += 4
        attributes[name] = (kind, data[pos:pos + size])
        pos += size
    channels: list[tuple[str, int]] = []
    blob = attributes["channels"][1]
    at = 0
    while blob[at] != 0:
        end = blob.index(b"\0", at)
        name = blob[at:end].decode()
        (pixel_type,) = struct.unpack_from("<i", blob, end + 1)
        channels.append((name, pixel_type))
        at = end + 1 + 16  # pixel type, pLinear + 3 reserved, x and y sampling
    return channels, attributes


def test_channel_names() -> None:
    assert exr.spectral_channel_name(380.0) == "S0.380,000000nm"
    assert exr.spectral_channel_name(550.5, "diffuse") == "diffuse.S0.550,500000nm"
    assert exr.parse_spectral_channel("S0.380,000000nm") == ("radiance", 380.0)
    assert exr.parse_spectral_channel("indirect.S0.402,250000nm") == ("indirect", 402.25)
    assert exr.parse_spectral_channel("S0.550nm") == ("radiance", 550.0)  # other writers
    for name in ("R", "Z", "normal.X", "S1.380,000000nm", "T.380,000000nm", "S0.,nm"):
        assert exr.parse_spectral_channel(name) is None


def test_round_trip_exact(tmp_path: Path) -> None:
    layers = _layers(np.random.default_rng(3))
    # float32 edge values survive bit for bit (lossless PIZ)
    layers["radiance"][0, 0, :6] = [0.0, -0.0, 1e-45, 3.0e38, np.inf, np.nan]
    path = exr.write_spectral_exr(tmp_path / "box.exr", wavelength_nm=WAVELENGTH_NM, **layers,
                                  attributes={"scene": "normbox", "sampleAngle_deg": "45"})
    back = exr.read_spectral_exr(path)
    assert np.array_equal(back["wavelength_nm"], WAVELENGTH_NM)
    for key, value in layers.items():
        assert back[key].dtype == np.float32 and back[key].shape == value.shape
        assert back[key].tobytes() == value.tobytes(), key
    assert back["other"] == {}
    assert back["attributes"]["spectralLayoutVersion"] == "1.0"
    assert back["attributes"]["emissiveUnits"] == "W.m^-2.sr^-1"
    assert back["attributes"]["scene"] == "normbox"
    assert back["attributes"][exr.DEPTH_UNITS_ATTRIBUTE] == "m"


def test_file_layout_by_independent_header_parser(tmp_path: Path) -> None:
    layers = _layers(np.random.default_rng(4), bands=3)
    wl = np.array([400.0, 550.5, 700.0])
    path = exr.write_spectral_exr(tmp_path / "layout.exr", wavelength_nm=wl, **layers)
    channels, attributes = _read_exr_header(path)
    expected = {"R", "G", "B", "Z", "normal.X", "normal.Y", "normal.Z"}
    for prefix in ("", "diffuse.", "specular.", "indirect."):
        expected |= {f"{prefix}S0.400,000000nm", f"{prefix}S0.550,500000nm",
                     f"{prefix}S0.700,000000nm"}
    assert {name for name, _ in channels} == expected
    assert all(pixel_type == 2 for _, pixel_type in channels)  # 2 = FLOAT (32-bit)
    assert attributes["compression"][1] == bytes([4])  # PIZ: lossless
    assert attributes["spectralLayoutVersion"] == ("string", b"1.0")
    assert attributes["emissiveUnits"] == ("string", b"W.m^-2.sr^-1")
    (x_min, y_min, x_max, y_max) = struct.unpack("<4i", attributes["dataWindow"][1])
    assert (x_max - x_min + 1, y_max - y_min + 1) == (7, 5)


def test_radiance_channels_match_colour_science_fichet2021_pattern(tmp_path: Path) -> None:
    import re

    from colour.io import fichet2021 as fichet

    pattern = re.compile(rf"^(S[0-3])\.*{fichet.PATTERN_FICHET2021}$")
    wl = np.array([380.0, 412.5, 780.0])
    path = exr.write_spectral_exr(tmp_path / "s.exr", wavelength_nm=wl,
                                  radiance=np.ones((2, 2, 3)), diffuse=np.ones((2, 2, 3)))
    channels, _ = _read_exr_header(path)
    parsed = {}
    for name, _ in channels:
        match = pattern.match(name)
        if match is not None:  # the layout's main image: radiance only
            parsed[name] = fichet.match_groups_to_nm(match.group(2), match.group(4),
                                                     match.group(5))
    assert sorted(parsed.values()) == pytest.approx(wl.tolist())
    assert all(not name.startswith("diffuse.") for name in parsed)


@dataclass
class _FakeSpectralImage:
    wavelength_nm: np.ndarray
    radiance: np.ndarray
    diffuse: np.ndarray
    specular: np.ndarray
    indirect: np.ndarray
    depth_m: np.ndarray
    normal: np.ndarray


def test_accepts_spectral_image_like_objects(tmp_path: Path) -> None:
    layers = _layers(np.random.default_rng(5), bands=4)
    wl = np.array([450.0, 500.0, 550.0, 600.0])
    image = _FakeSpectralImage(wl, *(layers[k] for k in exr.SPECTRAL_LAYERS),
                               layers["depth_m"], layers["normal"])
    preview = np.zeros((5, 7, 3), dtype=np.float32)
    back = exr.read_spectral_exr(exr.write_spectral_exr(tmp_path / "o.exr", image,
                                                        preview_rgb=preview))
    assert np.array_equal(back["wavelength_nm"], wl)
    for key in (*exr.SPECTRAL_LAYERS, "depth_m", "normal"):
        assert back[key].tobytes() == layers[key].tobytes()
    assert back["preview_rgb"].tobytes() == preview.tobytes()
    # an explicit keyword wins over the object's attribute
    doubled = layers["radiance"] * 2
    back = exr.read_spectral_exr(exr.write_spectral_exr(tmp_path / "p.exr", image,
                                                        radiance=doubled))
    assert back["radiance"].tobytes() == doubled.tobytes()


def test_extra_spectral_layers(tmp_path: Path) -> None:
    wl = np.array([500.0, 600.0])
    emission = np.full((2, 3, 2), 0.5, dtype=np.float32)
    path = exr.write_spectral_exr(tmp_path / "e.exr", wavelength_nm=wl,
                                  radiance=np.ones((2, 3, 2)), extra_spectral={"emission": emission})
    back = exr.read_spectral_exr(path)
    assert "emission.S0.500,000000nm" in back["channel_names"]
    assert back["emission"].tobytes() == emission.tobytes()
    with pytest.raises(ValueError, match="free identifier"):
        exr.write_spectral_exr(tmp_path / "f.exr", wavelength_nm=wl, radiance=np.ones((2, 3, 2)),
                               extra_spectral={"other": emission})


def test_float64_input_is_stored_as_float32_and_partial_layers(tmp_path: Path) -> None:
    radiance = np.random.default_rng(6).random((3, 4, 2))  # float64
    path = exr.write_spectral_exr(tmp_path / "r.exr", wavelength_nm=[500.0, 600.0],
                                  radiance=radiance)
    back = exr.read_spectral_exr(path)
    assert back["radiance"].tobytes() == radiance.astype(np.float32).tobytes()
    assert "diffuse" not in back and "depth_m" not in back and "normal" not in back


def test_bad_input_is_refused(tmp_path: Path) -> None:
    wl = np.array([500.0, 600.0])
    with pytest.raises(ValueError, match="nothing to write"):
        exr.write_spectral_exr(tmp_path / "a.exr")
    with pytest.raises(ValueError, match="wavelength_nm"):
        exr.write_spectral_exr(tmp_path / "a.exr", radiance=np.ones((2, 2, 2)))
    with pytest.raises(ValueError, match="bands"):
        exr.write_spectral_exr(tmp_path / "a.exr", wavelength_nm=wl, radiance=np.ones((2, 2, 3)))
    with pytest.raises(ValueError, match="expected"):
        exr.write_spectral_exr(tmp_path / "a.exr", wavelength_nm=wl, radiance=np.ones((2, 2, 2)),
                               depth_m=np.ones((3, 2)))
    with pytest.raises(ValueError, match="distinct"):
        exr.write_spectral_exr(tmp_path / "a.exr", wavelength_nm=[500.0, 500.0],
                               radiance=np.ones((2, 2, 2)))
    assert not (tmp_path / "a.exr").exists()
