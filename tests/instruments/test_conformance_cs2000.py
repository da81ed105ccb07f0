"""colour-specio's Konica Minolta CS-2000 driver (an outside client, dev extra) drives the
cs2000a emulator over a pty, over TCP and over RFC 2217 (``rfc2217://``, pyserial's own port
unmodified): connect (remote mode), identify, speed and sync modes
(SPMS/SPMR, SCMS/SCMR), measure (MEAS, MEDR conditions and four spectral blocks in hex).  Its
measurement waits the announced time in real seconds (2 s here) before reading."""

from __future__ import annotations

import numpy as np
import pytest
import serial
from served import CountingSocketSerial, served

from normbox_lab.sim.radiometer_common import colorimetry, default_spectrum

konica = pytest.importorskip(
    "specio.spectrometers.konica_minolta",
    reason="colour-specio (pre-release with the CS-2000 driver) is not installed")


def _connect(server, transport: str):
    if transport == "pty":
        return konica.CS2000(server.path)
    if transport == "rfc2217":
        # `sim serve --tcp … --rfc2217`: pyserial's own rfc2217:// port, unmodified (its
        # in_waiting counts every byte, so specio's read_all() empties the line)
        return konica.CS2000(serial.serial_for_url(server.url,
                                                   **konica.CS2000.CS2000_SERIAL_KWARGS))
    # TCP: pyserial's socket:// port with a byte-counting in_waiting (see CountingSocketSerial)
    port = CountingSocketSerial(None, **konica.CS2000.CS2000_SERIAL_KWARGS)
    port.port = server.url
    port.open()
    return konica.CS2000(port)


@pytest.mark.parametrize("transport", ["pty", "tcp", "rfc2217"])
def test_ordinary_workflow(transport):
    with served("cs2000a", transport, noise="off", time_factor="0.05") as server:
        emu = server.emulator
        cs = _connect(server, transport)
        try:
            assert (cs.manufacturer, cs.model, cs.serial_number) == \
                ("Konica-Minolta", "CS-2000A", "2000123")
            cs.speedmode = konica.SpeedModeSetting(konica.SpeedMode.FAST,
                                                   konica.InternalNDMode.AUTO)
            assert (cs.speedmode.mode, cs.speedmode.nd_mode) == \
                (konica.SpeedMode.FAST, konica.InternalNDMode.AUTO)
            assert cs.syncmode.mode == konica.SyncMode.NO_SYNC
            cs.syncmode = konica.SyncSpeedSetting(konica.SyncMode.INTERNAL, 59.94)
            assert (cs.syncmode.mode, cs.syncmode.frequency) == (konica.SyncMode.INTERNAL, 59.94)
            assert [c for c in emu.commands if c.startswith(b"SC")] == \
                [b"SCMR", b"SCMS,1,5994", b"SCMR"]

            m = cs.measure()
            # the default light: Planckian 2856 K at 100 cd/m²; specio integrates it itself
            wl, radiance = default_spectrum()
            truth = colorimetry(radiance)
            assert np.array_equal(m.spd.wavelengths, wl)                 # 380–780 nm, 1 nm
            assert np.allclose(m.spd.values, radiance, rtol=1e-6)        # float32 on the wire
            assert m.XYZ[1] == pytest.approx(truth["Lv"], rel=2e-3)
            assert m.xy == pytest.approx([truth["x"], truth["y"]], abs=5e-4)
            assert m.exposure == pytest.approx(1.0)                     # ttt 2 s, half light
            assert emu.commands[-5:] == [b"MEDR,0,0,1", b"MEDR,1,1,1", b"MEDR,1,1,2",
                                         b"MEDR,1,1,3", b"MEDR,1,1,4"]
        finally:
            cs._port.close()
