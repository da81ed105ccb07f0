"""Executors: in-process and a local 2-worker dask cluster give identical predictions."""

from __future__ import annotations

import numpy as np
import pytest

from normbox_lab.predict.executors import InProcessExecutor, dask_available, make_executor


def _square(x: int) -> int:
    return x * x


def test_inprocess_maps_in_order():
    ex = make_executor(None)
    assert isinstance(ex, InProcessExecutor)
    assert ex.map(_square, [3, 1, 2]) == [9, 1, 4]
    ex.close()


def test_unknown_executor_is_refused():
    with pytest.raises(ValueError, match="unknown executor"):
        make_executor("mpi")


def test_dask_missing_says_how_to_install(monkeypatch):
    import sys

    monkeypatch.setitem(sys.modules, "distributed", None)     # as if the extra were missing
    assert not dask_available()
    with pytest.raises(ImportError, match="normbox-lab\\[scale\\]"):
        make_executor("dask")


def test_ray_is_not_an_executor():
    with pytest.raises(ValueError, match="unknown executor 'ray'"):
        make_executor("ray")


def test_local_dask_cluster_gives_the_in_process_spectra():
    from normbox_lab.predict import materials as mats
    from normbox_lab.predict.fastrender import predict_spectra

    patches = [mats.truth_patch(n, "model") for n in (2, 24)]
    wall = mats.truth_wall("model")
    kw = {"wall": wall, "n_paths": 2000, "seed": 7, "patches_per_job": 1}
    # in process first: it also fills Dr.Jit's on-disk kernel cache the workers then reuse
    here = predict_spectra(patches, [35.0, 85.0], **kw)
    assert here.radiance.shape == (2, 2, 81) and here.executor == "inprocess"
    assert np.all(here.radiance > 0) and np.all(here.std_error > 0)
    rad, se = here.spectrum("patch-24", 85.0)
    np.testing.assert_array_equal(rad, here.radiance[1, 1])
    np.testing.assert_array_equal(se, here.std_error[1, 1])
    with make_executor("dask", workers=2) as ex:
        assert len(ex.client.scheduler_info()["workers"]) == 2
        there = predict_spectra(patches, [35.0, 85.0], executor=ex, **kw)
    assert there.executor == "dask"
    np.testing.assert_array_equal(there.radiance, here.radiance)
    np.testing.assert_array_equal(there.std_error, here.std_error)
    np.testing.assert_array_equal(there.n_paths, here.n_paths)
    assert np.all(here.n_paths == 2048)      # whole sub-batches of 256 paths, at least 4


def test_predict_cli_address_needs_the_dask_executor(tmp_path, capsys):
    from normbox_lab.cli import main

    rc = main(["predict", "1", "--address", "tcp://scheduler:8786",
               "--store", str(tmp_path / "s.sqlite")])
    assert rc == 2
    assert "--address names a dask scheduler" in capsys.readouterr().err
