"""Poll 10,000 float32 tags over Modbus TCP on loopback (issue 10 target: < 1 s per cycle).

Our :class:`~connectors.modbus_server.RegisterServer` runs in a child process (so it does
not share the client's event loop or GIL) and serves N float32 tags in holding registers;
:class:`~connectors.modbus.ModbusTagClient` polls them (blocks of 124 registers, decoded with
numpy). Prints ms per cycle, tags/s and the client's peak memory. Not a timed test::

    .venv/bin/python benchmarks/bench_modbus.py [--tags 10000] [--cycles 20]
"""

from __future__ import annotations

import argparse
import asyncio
import multiprocessing as mp
import resource
import statistics
import sys
import time
import tracemalloc
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from connectors.modbus import ModbusTagClient  # noqa: E402
from connectors.registermap import RegisterMap, TagSpec  # noqa: E402


def tag_map(n: int) -> RegisterMap:
    """N float32 tags packed from holding register 0 (at most 32,768 fit in one table)."""
    if not 1 <= n <= 32768:
        raise SystemExit("--tags must be 1..32768 (float32 tags in one register table)")
    return RegisterMap([TagSpec(f"T{i:05d}", "hr", 2 * i, "float32") for i in range(n)])


def serve(n: int, port_q: mp.Queue, stop: mp.Event) -> None:
    from connectors.modbus_server import RegisterServer

    async def main() -> None:
        srv = RegisterServer(tag_map(n), port=0)
        await srv.start()
        await srv.update_array(np.arange(n, dtype=np.float64) * 0.5)
        port_q.put(srv.port)
        while not stop.is_set():
            await asyncio.sleep(0.1)
        await srv.stop()

    asyncio.run(main())


async def bench(n: int, cycles: int, port: int) -> None:
    regmap = tag_map(n)
    c = ModbusTagClient(regmap, port=port, timeout=2.0)
    p = await c.poll()  # connect + warm up
    assert p.good, p.reasons[0]
    assert np.allclose(p.values, np.arange(n) * 0.5)
    tracemalloc.start()
    times = []
    for _ in range(cycles):
        p = await c.poll()
        times.append(p.seconds)
        assert p.good
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    t0 = time.perf_counter()
    samples = await c.read()  # the TagSample list form, for comparison
    t_samples = time.perf_counter() - t0
    await c.close()
    med = statistics.median(times)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"tags: {n} float32 in {len(c.plan.blocks)} read blocks (<=125 registers)")
    print(
        f"poll (arrays): median {med * 1e3:.1f} ms/cycle, min {min(times) * 1e3:.1f}, "
        f"max {max(times) * 1e3:.1f} over {cycles} cycles; {n / med:,.0f} tags/s"
    )
    print(f"read() as {len(samples)} TagSample objects: {t_samples * 1e3:.1f} ms/cycle")
    print(f"client peak traced memory during polls: {peak / 1e6:.2f} MB; max RSS {rss:.0f} MB")
    print(f"target < 1000 ms per cycle: {'met' if med < 1.0 else 'MISSED'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tags", type=int, default=10_000)
    ap.add_argument("--cycles", type=int, default=20)
    a = ap.parse_args()
    ctx = mp.get_context("spawn")
    q, stop = ctx.Queue(), ctx.Event()
    proc = ctx.Process(target=serve, args=(a.tags, q, stop), daemon=True)
    proc.start()
    try:
        port = q.get(timeout=60)
        asyncio.run(bench(a.tags, a.cycles, port))
    finally:
        stop.set()
        proc.join(10)
        if proc.is_alive():
            proc.kill()


if __name__ == "__main__":
    main()
