"""``diag diagnose``'s output written faster (issue 34, speed): the CSV writer gives the bytes
``DataFrame.to_csv`` gives, and the default piece (more than 7 days where the unit has few
tags or a long period) gives the same JSON and CSV as 7-day pieces.

The example valve unit is run on a simulator seed used nowhere else (808) with a fault.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.cli import main
from diag_plugin.diagnose.cli import (
    CHUNK_VALUES,
    CSV_DATE,
    CSV_FLOAT,
    CSV_ROWS,
    default_chunk,
    write_frame_csv,
)
from diag_plugin.simulate import FaultSpec, simulate_valve

SHIPPED = Path(__file__).resolve().parents[1] / "rulebases"


def _pandas_csv(frame: pd.DataFrame, path: Path) -> bytes:
    frame.to_csv(path, float_format=CSV_FLOAT, date_format=CSV_DATE)
    return path.read_bytes()


def _mixed(n: int, tz: str | None = "UTC", unit: str = "ns", seed: int = 0) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    index = pd.date_range("2026-03-01", periods=n, freq="37s", tz=tz, name="ts").as_unit(unit)
    few = rng.choice([0.0, 1.0, np.nan, -0.0, 0.25, 1e-7], n)
    wide = rng.standard_normal(n) * 10.0 ** rng.integers(-9, 9, n)
    wide[rng.random(n) < 0.1] = np.nan
    wide[: min(n, 4)] = [np.inf, -np.inf, -0.0, 123456789.0][: min(n, 4)]
    words = rng.choice(["", "f_P0", "a, b", 'say "x"', "two\nlines", "cr\r", "ü|ß"], n)
    text = pd.Series(words, index=index, dtype="str").where(rng.random(n) > 0.2)
    obj = pd.Series(rng.choice(["", "0", "1"], n), index=index, dtype=object)
    return pd.DataFrame(
        {
            "status": rng.integers(0, 5, n).astype(np.int8),
            "few": few,  # with -0.0: formatted value by value
            "fewer": rng.choice([0.0, 1.0, np.nan, 0.5, 1 / 3, 2e-300], n),
            "wide": wide,
            "big": rng.integers(-(2**40), 2**40, n),
            "text": text,
            "detected": obj,
        },
        index=index,
    )


@pytest.mark.parametrize("n", [0, 1, 50, CSV_ROWS + 1, 3 * CSV_ROWS + 7])
def test_csv_is_the_bytes_of_to_csv(tmp_path, n):
    frame = _mixed(n, seed=n)
    write_frame_csv(frame, str(tmp_path / "fast.csv"))
    assert (tmp_path / "fast.csv").read_bytes() == _pandas_csv(frame, tmp_path / "pd.csv")


@pytest.mark.parametrize(
    ("tz", "unit"), [("UTC", "s"), ("UTC", "us"), ("Europe/Berlin", "ns"), (None, "ns")]
)
def test_csv_times_in_any_zone_and_unit(tmp_path, tz, unit):
    frame = _mixed(500, tz=tz, unit=unit, seed=3)
    if unit == "ns":  # fractions of a second: written by strftime as pandas does
        frame.index = frame.index + pd.to_timedelta(np.arange(500) * 1_000_001, "ns")
    write_frame_csv(frame, str(tmp_path / "fast.csv"))
    assert (tmp_path / "fast.csv").read_bytes() == _pandas_csv(frame, tmp_path / "pd.csv")


def test_csv_falls_back_to_pandas_for_other_columns(tmp_path):
    frame = _mixed(100, seed=5)
    frame["flag"] = frame["status"] > 2  # bool
    frame["mixed"] = pd.Series([1, "a"] * 50, index=frame.index, dtype=object)
    frame["f32"] = frame["wide"].astype(np.float32)
    for c in ("flag", "mixed", "f32"):
        part = frame[["few", c]]
        write_frame_csv(part, str(tmp_path / "fast.csv"))
        assert (tmp_path / "fast.csv").read_bytes() == _pandas_csv(part, tmp_path / "pd.csv")


def test_default_chunk_is_a_week_or_the_values_bound():
    assert default_chunk("10s", 6) == pd.Timedelta("10s") * (CHUNK_VALUES // 6)
    assert default_chunk("180s", 46) == pd.Timedelta("180s") * (CHUNK_VALUES // 46)
    assert default_chunk("1s", 1000) == pd.Timedelta("7D")


def test_default_pieces_give_the_outputs_of_weekly_pieces(tmp_path, capsys):
    """18 days at 10 s (155,520 rows, 6 tags): the default reads it in one piece, ``--chunk 7D``
    in three; JSON and CSV are the same bytes (and the CSV is ``to_csv``'s)."""
    from historian.store import Historian

    onset = pd.Timestamp("2026-01-09T06:00", tz="UTC")
    frame = simulate_valve(18, seed=808, faults=[FaultSpec("f14", -0.3, onset)])
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(frame)
    base = ["--db", url, "--rulebases", str(SHIPPED), "diagnose", "valve_unit", "--json"]
    out = {}
    for name, extra in (("auto", []), ("week", ["--chunk", "7D"])):
        csv = tmp_path / f"{name}.csv"
        assert main([*base, "--csv", str(csv), *extra]) == 0
        out[name] = (capsys.readouterr().out, hashlib.md5(csv.read_bytes()).hexdigest())
    assert out["auto"] == out["week"]
    assert '"FAILURE"' in out["auto"][0]
    table = pd.read_csv(tmp_path / "auto.csv", keep_default_na=False, index_col="ts")
    assert len(table) == len(frame)


def test_summary_is_the_same_with_and_without_the_csv(tmp_path, capsys):
    """Without ``--csv`` the pieces' residuals, certainties and tags are not joined (issue 34):
    the JSON and the timeline are those of a run that writes the CSV, on a historian with
    gaps, NaN and Bad-quality samples, read in 2-day pieces and from ``--from``."""
    from historian.quality import BAD, GOOD
    from historian.store import Historian

    onset = pd.Timestamp("2026-01-04T06:00", tz="UTC")
    frame = simulate_valve(6, seed=8034, faults=[FaultSpec("f14", -0.3, onset)])
    rng = np.random.default_rng(34)
    frame = frame.mask(rng.random(frame.shape) < 0.003)  # single missing samples
    frame = frame.drop(frame.index[20_000:21_500])  # a gap of all tags
    quality = pd.DataFrame(GOOD, index=frame.index, columns=frame.columns)
    quality.iloc[30_000:30_400, 1] = BAD
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(frame, quality)
    base = ["--db", url, "--rulebases", str(SHIPPED), "diagnose", "valve_unit", "--chunk", "2D"]
    for extra in ([], ["--from", "2026-01-02T03:00"]):
        for fmt in (["--json"], []):
            assert main([*base, *extra, *fmt]) == 0
            alone = capsys.readouterr().out
            csv = tmp_path / "out.csv"
            assert main([*base, *extra, *fmt, "--csv", str(csv)]) == 0
            with_csv = capsys.readouterr().out
            if fmt:
                assert alone == with_csv
                assert '"FAILURE"' in alone and '"CHECK_FUNCTION"' in alone
            else:  # the timeline, then the CSV's name
                assert "timeline" in alone
                assert with_csv.startswith(alone)  # then "wrote FILE" (wrapped when long)
                assert with_csv[len(alone) :].startswith("wrote")


PROBE_GC = """
import gc, sys
full = []
def count(phase, info):
    if phase == "stop" and info["generation"] == 2:
        full.append(1)
gc.callbacks.append(count)
from diag_plugin.cli import main
rc = main(sys.argv[1:])
print("RESULT", rc, len(full), gc.get_freeze_count(), file=sys.stderr)
"""


def test_diagnose_runs_no_full_collection_over_its_start_up(tmp_path):
    """The imports and the unit's load made ~10⁶ objects that live as long as the process,
    and every full garbage collection traversed them again (4 of them, ~0.3 CPU s of a run,
    issue 34): ``diag diagnose`` makes them without a collection and freezes them. A day of
    the valve in a fresh process: no full collection at all, and the start-up's objects
    frozen (on ``main``: 5 full collections, nothing frozen)."""
    from helpers import probed_valve_diagnose

    out, line = probed_valve_diagnose(tmp_path, PROBE_GC, seed=809)
    rc, full, frozen = map(int, line.split()[1:])
    assert rc == 0, line
    assert '"samples": 8640' in out
    assert full == 0, f"{full} full collections"
    assert frozen > 100_000, frozen


def _gappy_valve(tmp_path) -> str:
    """6 days of the valve with a fault, single missing samples, a gap and Bad samples."""
    from historian.quality import BAD, GOOD
    from historian.store import Historian

    onset = pd.Timestamp("2026-01-04T06:00", tz="UTC")
    frame = simulate_valve(6, seed=8034, faults=[FaultSpec("f14", -0.3, onset)])
    rng = np.random.default_rng(34)
    frame = frame.mask(rng.random(frame.shape) < 0.003)
    frame = frame.drop(frame.index[20_000:21_500])
    quality = pd.DataFrame(GOOD, index=frame.index, columns=frame.columns)
    quality.iloc[30_000:30_400, 1] = BAD
    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(frame, quality)
    return url


def test_csv_is_written_while_the_pieces_replay(tmp_path, capsys, monkeypatch):
    """``--csv`` is written piece by piece in a thread of its own while the next pieces are
    replayed (issue 34, round seven), not after the last: rows are in the file before the
    last piece is evaluated; the bytes are those of the pieces joined and written at once
    (as before), the JSON the same. Read in 12-hour pieces from ``--from``: the first pieces
    have no ``why`` (the column the rows before it get), the last a fault; a piece the
    stream cannot write is replayed again and the CSV written joined, no partial file left."""
    import diag_plugin.diagnose.cli as dcli
    from diag_plugin.diagnose.unit import Unit

    url = _gappy_valve(tmp_path)
    csv = tmp_path / "out.csv"
    base = ["--db", url, "--rulebases", str(SHIPPED), "diagnose", "valve_unit", "--json",
            "--chunk", "12h", "--from", "2026-01-02T03:00", "--csv", str(csv)]  # fmt: skip

    def run(patch: dict) -> tuple[str, bytes]:
        with monkeypatch.context() as m:
            for (obj, attr), value in patch.items():
                m.setattr(obj, attr, value)
            assert main(base) == 0
        return capsys.readouterr().out, csv.read_bytes()

    seen = []  # per evaluate: the bytes of the CSV (or its partial file) so far
    evaluate = Unit.evaluate

    def spy(self, frame):
        seen.append(max((p.stat().st_size for p in tmp_path.glob("out.csv*")), default=0))
        return evaluate(self, frame)

    streamed = run({(Unit, "evaluate"): spy})
    assert len(seen) >= 8 and seen[-1] > 0  # rows written before the last piece replayed
    add_why, added = dcli.CsvPieces._add_why, []

    def why_later(self, head):
        added.append(1)
        return add_why(self, head)

    assert run({(dcli.CsvPieces, "_add_why"): why_later}) == streamed
    assert len(added) == 1  # the why column from a later piece on
    joined = run({(dcli.CsvPieces, "can_write"): staticmethod(lambda path: False)})
    assert streamed == joined
    assert '"FAILURE"' in streamed[0]
    write = dcli.CsvPieces._write
    count = []

    def fails_second(self, d):
        count.append(1)
        if len(count) == 2:
            self.failed = True  # as where a piece's columns differ in kind
            return None
        return write(self, d)

    assert run({(dcli.CsvPieces, "_write"): fails_second}) == joined
    assert sorted(p.name for p in tmp_path.glob("out.csv*")) == ["out.csv"]
