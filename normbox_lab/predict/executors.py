"""Where independent jobs run: in this process (default), or on a dask.distributed cluster.

    ex = make_executor("dask", workers=2)          # a LocalCluster of 2 worker processes
    ex = make_executor("dask", address="tcp://scheduler:8786")   # an existing cluster
    results = ex.map(fn, items)                    # in the order of `items`
    ex.close()

An executor only moves work: `fn` must be a module-level function and `items` picklable, and
every result must depend on its item alone (seeds travel inside the items), so the same items
give identical results in-process and on any cluster.  dask is an optional extra
for users (`pip install 'normbox-lab[scale]'`); the development install has it, so the
2-worker cluster test runs in the default suite.  (Ray was dropped: untested here, and one
distributed back end is enough.)
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, Protocol, Self

EXECUTOR_KINDS = ("inprocess", "dask")


class Executor(Protocol):
    name: str

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]: ...

    def close(self) -> None: ...


class InProcessExecutor:
    """Runs the jobs one after another in the calling process."""

    name = "inprocess"

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
        return [fn(item) for item in items]

    def close(self) -> None:
        pass

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


class DaskExecutor:
    """dask.distributed: a new `LocalCluster` of `workers` processes (one thread each), or the
    cluster at `address`.  Jobs are scheduled dynamically (a free worker takes the next one)."""

    name = "dask"

    def __init__(self, address: str | None = None, *, workers: int = 2,
                 threads_per_worker: int = 1) -> None:
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:            # the optional extra is not installed
            raise ImportError("the dask executor needs dask.distributed: "
                              "pip install 'normbox-lab[scale]'") from exc
        self._cluster = None
        if address:
            self.client = Client(address)
        else:
            self._cluster = LocalCluster(n_workers=int(workers),
                                         threads_per_worker=int(threads_per_worker),
                                         processes=True, dashboard_address=None)
            self.client = Client(self._cluster)
        self.workers = int(workers)

    def map(self, fn: Callable[[Any], Any], items: Sequence[Any]) -> list[Any]:
        futures = self.client.map(fn, list(items), pure=False)
        return list(self.client.gather(futures))

    def close(self) -> None:
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def make_executor(kind: str | None = None, *, workers: int = 2,
                  address: str | None = None) -> Executor:
    """`kind`: "inprocess" (default, also None) or "dask"."""
    kind = (kind or "inprocess").lower()
    if kind in ("inprocess", "in-process", "local"):
        return InProcessExecutor()
    if kind == "dask":
        return DaskExecutor(address, workers=workers)
    raise ValueError(f"unknown executor {kind!r}; expected one of {EXECUTOR_KINDS}")


def dask_available() -> bool:
    try:
        import distributed  # noqa: F401
    except ImportError:
        return False
    return True
