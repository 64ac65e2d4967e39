"""``diag run`` without a configuration: the embedded default.

A simulated servomotor–valve plant (7 days of history into a SQLite historian in ``--data``,
the example unit trained on it, cached for later starts) is served as a Modbus TCP PLC on
127.0.0.1; the live loop (:class:`~diag_plugin.live.loop.LiveLoop`) polls it, diagnoses the
unit and publishes over OPC UA and Modbus, while a scripted P0-sensor fault (f14) is raised,
acknowledged by a scripted operator and cleared.

The units' state is saved in ``data``/plant.state.json (every 60 cycles and on stop,
:mod:`~diag_plugin.live.state`) and restored on the next start when the unit files are the
same. The simulated plant stops with the plug-in, so there is no downtime to catch up on: a
restored run resumes the scenario at the sample after the state's last cycle (samples a
killed run stored after its last save are sent again: stored once, diagnosed again live).
"""

from __future__ import annotations

import asyncio
import contextlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import pandas as pd

from connectors.alarms import AlarmState
from diag_plugin.live.loop import LiveLoop, close_all
from diag_plugin.status import UnitStatus

HISTORY_START = pd.Timestamp("2026-01-01", tz="UTC")
HISTORY_DAYS, HISTORY_SEED = 7, 21
SCENARIO_SEED = 22
#: the scripted fault: f14 (P0 sensor), isolated by the example unit as f_P0 → FAILURE
SCENARIO_FAULT, SCENARIO_STRENGTH = "f14", -0.3
FAULT_ON, FAULT_OFF = 120, 400  # samples after the start of the live run
SCENARIO_DAYS = 1.0  # the pre-simulated live run (8640 samples; then it starts again)
ACK_AFTER = 20  # cycles between the alarm being raised and the operator acknowledging
STATE_FILE = "plant.state.json"  # in --data
STATE_EVERY = 60  # cycles between state saves (and on stop)


@dataclass
class Embedded:
    """The embedded plant's files (:func:`prepare_embedded`)."""

    data: Any  # Path
    url: str
    unit_file: Any  # Path
    history_end: pd.Timestamp


def prepare_embedded(data: Any, say: Callable[[str], None] = print) -> Embedded:
    """``data``/plant.db with 7 days of simulated fault-free history and the example unit in
    ``data``/rulebases, built on first start and reused afterwards."""
    from pathlib import Path

    from connectors.modbus_server import PLANT_TAGS

    data = Path(data)
    rb = data / "rulebases"
    unit_file = rb / "valve_unit.unit.toml"
    ready = data / ".ready"
    db = data / "plant.db"
    url = f"sqlite:///{db}"
    n = int(HISTORY_DAYS * 86400 / 10)
    history_end = HISTORY_START + pd.Timedelta(seconds=10 * (n - 1))
    if ready.is_file() and unit_file.is_file() and db.is_file():
        say(f"using the embedded plant in {data} (history and example unit cached)")
        return Embedded(data, url, unit_file, history_end)
    from diag_plugin.examples.build import build_valve_unit
    from diag_plugin.simulate.valve import TAGS, simulate_valve
    from historian.store import Historian

    say(f"first start: simulating {HISTORY_DAYS} days of plant history into {db} ...")
    rb.mkdir(parents=True, exist_ok=True)
    frame = simulate_valve(HISTORY_DAYS, seed=HISTORY_SEED, start=HISTORY_START)
    history_end = frame.index[-1]
    h = Historian.open(url)
    for t in PLANT_TAGS:
        info = TAGS[t]
        h.ensure_tag(t, unit=info.unit, lo=info.lo, hi=info.hi, description=info.description)
    h.write_samples(frame[list(PLANT_TAGS)])
    with contextlib.suppress(Exception):
        h.close()
    say(f"training the example valve unit in {rb} ...")
    source = f"diag run (embedded): simulate {HISTORY_DAYS} days, seed {HISTORY_SEED}"
    build_valve_unit(rb, frame, source)
    ready.write_text(f"{history_end.isoformat()}\n", encoding="utf-8")
    return Embedded(data, url, unit_file, history_end)


def scenario_rows(history_end: pd.Timestamp) -> pd.DataFrame:
    """The live run: continues after the history, fault f14 from sample 120 to 400."""
    from diag_plugin.simulate import FaultSpec, simulate_valve

    start = history_end + pd.Timedelta(seconds=10)
    step = pd.Timedelta(seconds=10)
    fault = FaultSpec(
        SCENARIO_FAULT,
        SCENARIO_STRENGTH,
        onset=start + FAULT_ON * step,
        end=start + FAULT_OFF * step,
    )
    return simulate_valve(SCENARIO_DAYS, seed=SCENARIO_SEED, start=start, faults=[fault])


def resume_index(last: pd.Timestamp | None, start: pd.Timestamp, step: pd.Timedelta) -> int:
    """The scenario sample after ``last`` (a restored state's last cycle; 0 without one or
    before the scenario's start): the live timeline is ``start + i · step``."""
    if last is None or last < start:
        return 0
    return int((last - start) // step) + 1


async def run_embedded(
    data: Any,
    *,
    cycle: float = 0.25,
    duration: float = 0.0,
    plc_port: int = 5021,
    modbus_port: int = 5020,
    opcua_port: int = 4840,
    flush_every: int = 20,
    tty: bool | None = None,
    out: Any = None,
) -> int:
    """``diag run`` without a config: the simulated valve plant, scripted fault, operator."""
    from connectors.modbus import ModbusTagClient
    from connectors.modbus_server import PlantServer, StatusServer, UnitLayout, default_plant_map
    from connectors.opcua_server import DiagOpcUaServer
    from connectors.sources import SourceSet
    from diag_plugin.diagnose.plant import Plant
    from diag_plugin.live.writer import HistorianWriter
    from historian.livestore import history_runs

    out = out or sys.stdout

    def say(s: str) -> None:
        print(s, file=out, flush=True)

    from diag_plugin.live.state import restore_state

    emb = await asyncio.to_thread(prepare_embedded, data, say)
    rows = await asyncio.to_thread(scenario_rows, emb.history_end)
    plant = Plant.load([emb.unit_file], emb.unit_file.parent)
    if plant.broken:
        say(f"warning: broken units: {plant.broken}")
    first = plant.cycle(rows.index[0], rows.iloc[0].to_dict())
    plant.reset()
    layouts = [UnitLayout.from_status(s) for s in first]
    step = pd.Timedelta(seconds=10)
    span = len(rows) * step
    values = rows.to_dict("records")
    state = emb.data / STATE_FILE
    say(restore_state(plant, state, now=None))
    i0 = resume_index(plant.last_ts, rows.index[0], step)
    if i0:
        k, j = divmod(i0, len(values))
        say(
            f"embedded scenario resumes at its sample {j} of run {k + 1} "
            f"({rows.index[j] + k * span:%Y-%m-%d %H:%M:%S} UTC, the cycle after the state's)"
        )

    plc = PlantServer(default_plant_map(), "127.0.0.1", plc_port)
    status = StatusServer(layouts, "127.0.0.1", modbus_port)
    opcua = DiagOpcUaServer("127.0.0.1", opcua_port)
    # one source, in a SourceSet for its outage events (down once, back once with the gap)
    client = SourceSet(
        [ModbusTagClient(default_plant_map(), "127.0.0.1", plc_port, timeout=1.0)], ["plc"]
    )
    raised: dict[str, int] = {}

    async def feed(i: int) -> pd.Timestamp:
        k, j = divmod(i + i0, len(values))
        row = values[j]
        await plc.set_row(row)
        await opcua.update_plant({t: row[t] for t in opcua.plant_tags if t in row})
        return rows.index[j] + k * span

    async def operator(lp: LiveLoop, i: int, statuses: list[UnitStatus]) -> None:
        for s in statuses:
            state = lp._alarm(s.unit)
            if state is AlarmState.ACTIVE_UNACK:
                since = raised.setdefault(s.unit, i)
                if i - since >= ACK_AFTER:
                    lp.event(f"{s.unit}: operator acknowledges", s.ts)
                    await lp.acknowledge(s.unit, "operator")
                    raised.pop(s.unit, None)
            else:
                raised.pop(s.unit, None)

    writer = HistorianWriter(
        emb.url,
        client.names,
        spill_dir=f"{emb.data / 'plant.db'}.spill",
        flush_every=flush_every,
        cycle=cycle,
    )
    await plc.start()
    await status.start()
    await opcua.start()
    await writer.start()
    for text in writer.notes:  # a crashed run's journal, damaged spill files
        say(text)
    history = asyncio.ensure_future(asyncio.to_thread(history_runs, emb.url, client.names))
    say(
        f"embedded plant: Modbus PLC 127.0.0.1:{plc_port}, status Modbus 127.0.0.1:{modbus_port}"
        f", OPC UA {opcua.endpoint}, historian {emb.url}; one 10 s sample every {cycle:g} s"
        f"; fault {SCENARIO_FAULT} from sample {FAULT_ON} to {FAULT_OFF}"
    )
    try:
        loop = LiveLoop(
            plant,
            client,
            historian=writer,
            opcua=opcua,
            status_server=status,
            cycle=cycle,
            duration=duration,
            stale_history=history,
            feed=feed,
            after=operator,
            tty=tty,
            out=out,
            state=state,
            state_every=STATE_EVERY,
        )
        return await loop.run()
    finally:
        await close_all(client, opcua, status, plc, writer)
