"""A live writer in a process of its own, for kill -9 tests (not a test itself).

``python writer_child.py URL SPILL TAGS CYCLE START``: puts one cycle of ``TAGS`` tags every
``CYCLE`` wall seconds through :class:`diag_plugin.live.writer.HistorianWriter` (a block every
20 cycles), sample k at 2026-03-01 + (START + k) s with tag i reading i·1000 + k, and prints
``put k`` once ``put`` (and, every 5th cycle, ``put_event`` of "event k") has returned. Runs
until killed. A 6th argument ``--no-journal`` turns the journal off (the writer before issue
35, for the figures in docs/reference/live.md)."""

import asyncio
import sys

import numpy as np
import pandas as pd

from diag_plugin.live.writer import HistorianWriter

T0 = pd.Timestamp("2026-03-01", tz="UTC")


async def main(url: str, spill: str, n: int, cycle: float, start: int) -> None:
    tags = [f"T{i:03d}" for i in range(n)]
    w = HistorianWriter(
        url,
        tags,
        spill_dir=spill,
        flush_every=20,
        cycle=cycle,
        busy_timeout=0.5,
        memory_rows=n * 100,
    )
    await w.start()
    print("started", flush=True)
    k = start
    base = np.arange(n) * 1000.0
    while True:
        w.put(T0 + pd.Timedelta(seconds=k), base + k, np.zeros(n, np.uint8))
        if k % 5 == 0:  # an event now and then, as alarm transitions come
            w.put_event(T0 + pd.Timedelta(seconds=k), "child", f"event {k}")
        print(f"put {k}", flush=True)
        k += 1
        await asyncio.sleep(cycle)


if __name__ == "__main__":
    if len(sys.argv) > 6 and sys.argv[6] == "--no-journal":  # the baseline, for figures
        HistorianWriter._journal_append = lambda self, t, v, q: 0
    url, spill, n, cycle, start = sys.argv[1:6]
    asyncio.run(main(url, spill, int(n), float(cycle), int(start)))
