"""`core.npzfile`: a .npz is written whole or not at all."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.core.npzfile import keep_npz, write_npz


class _Unwritable:
    def __array__(self, *args, **kwargs):
        raise RuntimeError("cannot become an array")


def test_a_write_that_fails_midway_leaves_no_file_and_the_old_one_intact(tmp_path):
    path = tmp_path / "a.npz"
    write_npz(path, x=np.arange(3.0))
    with pytest.raises(RuntimeError):
        write_npz(path, x=np.arange(5.0), y=_Unwritable())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.npz"]
    with np.load(path) as z:
        np.testing.assert_array_equal(z["x"], np.arange(3.0))


def test_keep_skips_a_place_that_cannot_be_written(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    keep_npz(blocker / "cache" / "a.npz", x=np.arange(3.0))      # no error, nothing kept
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]
    with pytest.raises(OSError):
        write_npz(blocker / "cache" / "a.npz", x=np.arange(3.0))
