"""A writer killed with SIGKILL mid-ingest loses no acknowledged batch and leaves a sound
database; a restarted writer re-sends everything without duplicates."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pandas as pd

from historian import Historian

BATCH = 20_000
N_BATCHES = 400  # far more than get written before the kill

WRITER = textwrap.dedent(
    """
    import sys
    import numpy as np
    import pandas as pd
    from historian import Historian

    url, cold, batch, n_batches = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    t0 = pd.Timestamp("2024-01-01", tz="UTC")
    with Historian(url, cold_dir=cold) as h:
        for i in range(n_batches):
            idx = t0 + pd.to_timedelta((i * batch + np.arange(batch)) * 10, unit="s")
            frame = pd.DataFrame({"W": np.full(batch, float(i))}, index=idx)
            h.write_samples(frame, batch_rows=batch)  # one transaction, committed on return
            print(f"ACK {i}", flush=True)
    print("DONE", flush=True)
    """
)


def _run_writer(url, cold, n_batches):
    return subprocess.Popen(
        [sys.executable, "-c", WRITER, url, str(cold), str(BATCH), str(n_batches)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))),
    )


def test_sigkill_mid_ingest_keeps_acked_batches(db_url, tmp_path):
    cold = tmp_path / "cold"
    proc = _run_writer(db_url, cold, N_BATCHES)
    acked = []
    deadline = time.monotonic() + 120
    try:
        for line in proc.stdout:
            if line.startswith("ACK"):
                acked.append(int(line.split()[1]))
            if len(acked) >= 5 or time.monotonic() > deadline:
                break
        os.kill(proc.pid, signal.SIGKILL)  # mid-ingest: the next batch is being written
    finally:
        proc.kill()
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL
    assert len(acked) >= 5

    with Historian(db_url, cold_dir=cold) as h:
        assert h.integrity_check() == []
        s = h.read_samples("W")
        assert s.index.is_unique
        counts = s.groupby(s.to_numpy()).size()
        for i in acked:  # every acknowledged batch is complete
            assert counts.get(float(i)) == BATCH, f"batch {i} incomplete"
        # no partial batch: a batch is all or nothing
        assert set(counts.to_numpy()) <= {BATCH}

    # restart: re-sending batches already stored duplicates nothing
    n = max(acked) + 3
    proc = _run_writer(db_url, cold, n)
    out, _ = proc.communicate(timeout=300)
    assert proc.returncode == 0 and "DONE" in out
    with Historian(db_url, cold_dir=cold) as h:
        assert h.integrity_check() == []
        s = h.read_samples("W")
        assert len(s) == n * BATCH and s.index.is_unique
        np.testing.assert_array_equal(np.unique(s.to_numpy()), np.arange(n, dtype=float))
        assert s.index[-1] == pd.Timestamp("2024-01-01", tz="UTC") + pd.Timedelta(
            seconds=10 * (n * BATCH - 1)
        )
