"""A child process writes readings; the parent SIGKILLs it at random moments, many times.

Every reading the child acknowledged (printed after `add_reading` returned) must be in the
store, complete and exact; nothing half-written; `PRAGMA integrity_check` ok.
"""

import os
import random
import signal
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from normbox_lab.acquire.store import Store

CHILD = textwrap.dedent("""
    import sys
    import numpy as np
    from normbox_lab.acquire.store import Store

    store = Store(sys.argv[1], durable=sys.argv[2])
    run_id = store.runs()[0].id
    n = len(store.keys(run_id))
    while True:
        values = np.arange(4096.0) * (n + 1)
        store.add_reading(run_id, f"r{n:05d}", "spectral",
                          {"wavelength_nm": np.arange(4096.0), "values": values},
                          metadata={"n": n})
        print(n, flush=True)
        n += 1
""")


@pytest.mark.parametrize("durable", ["power-loss", "crash"])
def test_sigkill_at_random_moments_loses_no_committed_reading(tmp_path, durable):
    """Both durabilities: "crash" (the demo's, no fsync per commit) is only weaker against a
    power cut, which a kill is not."""
    path = tmp_path / "kill.sqlite"
    with Store(path) as s:
        s.create_run("kill-campaign")
    rng = random.Random(20261122)
    acknowledged: set[int] = set()
    kills = 0
    for _ in range(25):
        child = subprocess.Popen([sys.executable, "-c", CHILD, str(path), durable],
                                 stdout=subprocess.PIPE, text=True)
        # kill after a random number of acknowledged commits (0 = during start-up)
        for _ in range(rng.randint(0, 12)):
            line = child.stdout.readline()
            if not line:
                break
            acknowledged.add(int(line))
        os.kill(child.pid, signal.SIGKILL)
        child.wait()
        for line in child.stdout:  # acks that were printed before the kill landed
            acknowledged.add(int(line))
        child.stdout.close()
        kills += 1
    assert kills == 25
    with Store(path) as s:
        assert s.integrity_check() == "ok"
        run_id = s.runs()[0].id
        readings = list(s.readings(run_id))
        ns = [r.metadata["n"] for r in readings]
        assert len(ns) == len(set(ns)), "a reading was written twice"
        assert sorted(ns) == list(range(len(ns))), "a gap: a committed reading went missing"
        assert acknowledged <= set(ns), "an acknowledged reading is missing"
        for r in readings:
            n = r.metadata["n"]
            assert set(r.arrays) == {"wavelength_nm", "values"}
            assert np.array_equal(r.arrays["values"], np.arange(4096.0) * (n + 1))
        orphans = s._db.execute("SELECT COUNT(*) FROM arrays WHERE owner='reading' AND owner_id"
                                " NOT IN (SELECT id FROM readings)").fetchone()[0]
        assert orphans == 0
    assert len(acknowledged) > 25
