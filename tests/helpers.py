"""Small synthetic plants shared by tests (not tests themselves), and ``require``."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.examples.build import TABLE4_MATRIX

REPO = Path(__file__).resolve().parents[1]

#: Every skip because a peer or system part is missing (PostgreSQL server, Chromium, the
#: fuzzylite binary, the pyfuzzylite venv, the shared data) has a reason starting with
#: this; with CI=true conftest.py turns such a skip into a failure, since on CI it means
#: a set-up step is broken.
MISSING = "missing peer/system part:"


def missing(what: str, how: str) -> str:
    """The skip reason for a missing part ``what``; ``how`` says how one gets it."""
    return f"{MISSING} {what} ({how})"


def require(what: str, ok: bool, how: str) -> None:
    """Skip the running test (fail it when CI=true) unless the part ``what`` is there."""
    if not ok:
        pytest.skip(missing(what, how))


def requires(what: str, ok: bool, how: str) -> pytest.MarkDecorator:
    """:func:`require` as a mark for whole tests or modules."""
    return pytest.mark.skipif(not ok, reason=missing(what, how))


def shared_dir() -> Path:
    """The ``shared`` folder beside the repository (real plant data; CI provides it).

    TESTS_SHARED_DIR points the tests elsewhere (e.g. at an empty folder, to check that
    CI fails when the data are missing)."""
    return Path(os.environ.get("TESTS_SHARED_DIR") or REPO.parent / "shared")


def damadics_file() -> Path | None:
    """The real DAMADICS hour (``shared/data/damadics``), if present."""
    p = shared_dir() / "data" / "damadics" / "OneHourTestData_ExampleII.mat"
    return p if p.is_file() else None


DAMADICS_HOW = "../shared/data/damadics; CI has it"


def run_diag(
    cwd: Path, *args: str, stdin: str | None = None, timeout: float = 600, **env: str
) -> subprocess.CompletedProcess:
    """`diag ARGS` as a user runs it: a subprocess in ``cwd``, no DIAG_* from the caller,
    ``stdin`` as its input."""
    clean = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")} | env
    return subprocess.run(
        [sys.executable, "-m", "diag_plugin", *args],
        cwd=cwd,
        env=clean,
        capture_output=True,
        text=True,
        timeout=timeout,
        input=stdin,
    )


def read_probe(module: str) -> str:
    """Python that runs ``diag`` with the command's read of pieces watched: when ``module`` is
    first imported, was a read of pieces already under way in its thread? (waits for it, up to
    60 s, once the pieces were asked for). Prints ``RESULT rc [seen]`` to stderr."""
    return f"""
import sys, threading
import diag_plugin.diagnose.cli as cli
asked, reading, seen = threading.Event(), threading.Event(), []
uf = cli.unit_frames
def unit_frames(*a, **k):
    asked.set()
    def pieces():
        reading.set()
        yield from uf(*a, **k)
    return pieces()
cli.unit_frames = unit_frames
class Watch:
    def find_spec(self, name, path=None, target=None):
        if name == {module!r} and not seen:
            seen.append(asked.is_set() and reading.wait(60))
        return None
sys.meta_path.insert(0, Watch())
from diag_plugin.cli import main
rc = main(sys.argv[1:])
print("RESULT", rc, seen, file=sys.stderr)
"""


def probed_valve_diagnose(tmp_path: Path, probe: str, seed: int) -> tuple[str, str]:
    """``diag diagnose valve_unit --json`` on a day of the valve (simulator ``seed``) in a
    fresh process running ``probe`` (Python that runs the command and prints a line
    ``RESULT …`` to stderr): the command's stdout and that line."""
    from diag_plugin.simulate import simulate_valve
    from historian.store import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    with Historian.open(url) as h:
        h.write_samples(simulate_valve(1, seed=seed))
    rulebases = str(REPO / "rulebases")
    argv = ["--db", url, "--rulebases", rulebases, "diagnose", "valve_unit", "--json"]
    res = subprocess.run(
        [sys.executable, "-c", probe, *argv], capture_output=True, text=True, timeout=300
    )
    line = next((x for x in res.stderr.splitlines() if x.startswith("RESULT ")), None)
    assert line is not None, res.stderr
    return res.stdout, line


LOCKER = """\
import sqlite3, sys
c = sqlite3.connect(sys.argv[1], isolation_level=None)
c.execute("BEGIN IMMEDIATE")  # the write lock; readers still read (WAL)
print("locked", flush=True)
sys.stdin.readline()  # held until the test says
c.execute("COMMIT")
print("released", flush=True)
"""


class Locker:
    """A second process holding the SQLite file's write lock until :meth:`release`."""

    def __init__(self, db: Path) -> None:
        self.p = subprocess.Popen(
            [sys.executable, "-c", LOCKER, str(db)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        assert self.p.stdout.readline().strip() == "locked"

    def release(self) -> None:
        self.p.stdin.write("\n")
        self.p.stdin.flush()
        assert self.p.stdout.readline().strip() == "released"
        self.p.wait(10)


def valve_frame(days: float, seed: int) -> pd.DataFrame:
    """Flow through a valve from the controller output (1 sample late) and upstream pressure,
    10 s samples, 50 missing CV values."""
    rng = np.random.default_rng(seed)
    n = int(days * 8640)
    idx = pd.date_range("2026-01-01", periods=n, freq="10s", tz="UTC", name="ts")
    cv = np.clip(50 + np.cumsum(rng.normal(0, 1.5, n)) % 100, 0, 100)
    p1 = 500 + 150 * np.sin(np.arange(n) / 8640 * 2 * np.pi) + rng.normal(0, 5, n)
    f = np.r_[0, 30 * (cv[:-1] / 100) ** 2 * np.sqrt(p1[1:] / 650)] + rng.normal(0, 0.1, n)
    frame = pd.DataFrame({"CV": cv, "P1": p1, "F": f}, index=idx)
    frame.iloc[rng.choice(n, 50, replace=False), 0] = np.nan
    return frame


#: seed 001 Table 4 (rules 10–14) as a matrix file: the servomotor–valve unit
#: the seed 001 Table 4 matrix, as the example unit ships it
VALVE_TABLE4 = TABLE4_MATRIX


def valve_plant(d: Path, without: tuple[str, ...] = ()) -> pd.DataFrame:
    """The example unit trained on a fault-free day of the simulated valve (seed 5) in
    ``d/rb``, and the PLC's register map as a plain CSV, ``d/plc.csv`` (less the tags
    ``without``, which another source serves). Returns the day's frame."""
    from connectors.modbus_server import default_plant_map
    from diag_plugin.examples.build import build_valve_unit
    from diag_plugin.simulate import simulate_valve

    frame = simulate_valve(1, seed=5)
    (d / "rb").mkdir()
    build_valve_unit(d / "rb", frame, "test")
    rows = ["tag,table,address,type"] + [
        f"{t.tag},{t.table},{t.address},{t.type}"
        for t in default_plant_map().tags
        if t.tag not in without
    ]
    (d / "plc.csv").write_text("\n".join(rows) + "\n", encoding="utf-8")
    return frame


def plant_toml(
    d: Path,
    plc: int,
    historian: str,
    *,
    cycle: float,
    extra: str = "",
    flush_every: int = 5,
) -> Path:
    """``d/plant-PLC.toml``: the unit of :func:`valve_plant` polling one PLC (``plc.csv``) at
    ``cycle`` s into ``historian``; ``extra`` lines go into ``[plant]``."""
    p = d / f"plant-{plc}.toml"
    p.write_text(
        f"""\
[plant]
cycle = {cycle}
historian = "{historian}"
flush_every = {flush_every}
units = ["rb/valve_unit.unit.toml"]
{extra}
[[source]]
name = "plc"
port = {plc}
map = "plc.csv"
timeout = {min(cycle, 0.5)}

[outputs]
modbus_port = 0
opcua_port = 0
""",
        encoding="utf-8",
    )
    return p


def diag_run_polling(d: Path, cfg: Path) -> tuple[subprocess.Popen, list[str], dict[str, str]]:
    """``diag run --config cfg --plain`` started in ``d`` (its own process), returned once it
    polls, with its argv and environment (for the restart)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("DIAG_")}
    argv = [sys.executable, "-m", "diag_plugin", "run", "--config", cfg.name, "--plain"]
    run = subprocess.Popen(argv, cwd=d, env=env, stdout=subprocess.PIPE, text=True)
    for line in run.stdout:
        if "polling" in line:
            break
    return run, argv, env


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Out:
    """A text stream for a console to print to (not a terminal); ``text`` is what it got."""

    def __init__(self) -> None:
        self.lines: list[str] = []

    def write(self, s: str) -> None:
        self.lines.append(s)

    def flush(self) -> None:
        pass

    def isatty(self) -> bool:
        return False

    @property
    def text(self) -> str:
        return "".join(self.lines)


def cv_flow_historian(tmp_path, noise: float, seed: int) -> list[str]:
    """Four days of a valve-like flow at 10 s, F = 30 (CV/100)² + N(0, noise) t/h, in SQLite;
    the global options for ``diag``."""
    from historian import Historian

    url = f"sqlite:///{tmp_path / 'h.db'}"
    rng = np.random.default_rng(seed)
    n = 4 * 8640
    idx = pd.date_range("2026-03-01", periods=n, freq="10s", tz="UTC", name="ts")
    cv = rng.uniform(5, 95, n // 60 + 1).repeat(60)[:n]
    f = np.r_[0, 30 * (cv[:-1] / 100) ** 2] + rng.normal(0, noise, n)
    with Historian.open(url) as h:
        h.ensure_tag("CV", unit="%", lo=0, hi=100, description="controller output")
        h.ensure_tag("F", unit="t/h", lo=0, hi=40, description="flow")
        h.write_samples(pd.DataFrame({"CV": cv, "F": f}, index=idx))
    rules = tmp_path / "rulebases"
    rules.mkdir()
    return ["--db", url, "--rulebases", str(rules)]


def trained_valve_file(folder: Path, method: str, seed: int = 6):
    """A model file F[k] = f(CV[k-1], P1[k]) of ``method`` trained on a day of the simulated
    valve (seed ``seed``) and saved in ``folder``: ``(rule base, training result, frame)``."""
    from diag_plugin.rulebase.document import RuleBase, Variable
    from diag_plugin.training.chunked import train

    f = valve_frame(1, seed=seed)
    rb = RuleBase.new(
        method[0],
        Variable("F[k]", "F", "t/h", (0.0, 40.0)),
        [
            Variable("CV[k-1]", "CV", "%", (0.0, 100.0)),
            Variable("P1[k]", "P1_", "kPa", (300.0, 700.0)),
        ],
        method=method,
        path=Path(folder) / f"{method[0]}.toml",
    )
    a, b = f.index[0], f.index[-1] + pd.Timedelta("10s")
    res = train(rb, lambda s, e: f[(f.index >= s) & (f.index < e)], a, b, chunk=pd.Timedelta("5h"))
    rb.apply_training(res.model, {"samples": res.samples})
    rb.save()
    return rb, res, f


def broken_edit_is_named(path: Path, folder: Path, old: str, new: str, message: str) -> None:
    """Replacing ``old`` by ``new`` in the model file ``path`` (written to ``folder/bad.toml``)
    makes loading it fail with ``bad.toml:LINE: message``, LINE where ``old`` stood."""
    from diag_plugin.rulebase.document import RuleBase, RuleBaseError

    text = Path(path).read_text()
    assert old in text
    line = next(k for k, ln in enumerate(text.splitlines(), 1) if old in ln)
    (folder / "bad.toml").write_text(text.replace(old, new, 1))
    with pytest.raises(RuleBaseError, match=rf"bad\.toml:{line}: {message}"):
        RuleBase.load(folder / "bad.toml")


def compares_and_explains(path: Path, frame: pd.DataFrame):
    """A trained model file of a method without sets goes through the workbench's seam:
    ``compare`` covers the data with no worst regions, ``explain`` ranks candidates and
    offers no set counts."""
    from diag_plugin.rulebase.document import RuleBase
    from diag_plugin.workbench.compare import compare
    from diag_plugin.workbench.explain import explain

    c = compare(RuleBase.load(path), frame)
    assert c.metrics["coverage"] > 0.99 and c.as_dict()["worst_regions"] == []
    e = explain(RuleBase.load(path), frame, max_lag=2)
    assert e.candidates and np.isfinite(e.baseline_rmse_pct)
    # set counts mean nothing to such a method: explain does not offer them
    assert not any("--sets" in c.command for c in e.candidates)
    return c


def cli_new_train_compare(folder: Path, name: str, method: str) -> tuple[dict, str]:
    """``diag model new NAME --method METHOD`` (F from CV[k-1]), ``train``, ``compare --json``
    in ``folder``: the comparison and the model file's text."""
    import json

    new = ("model", "new", name, "--output", "F", "--input", "CV[k-1]", "--method", method)
    for args in (new, ("train", name), ("compare", name, "--json")):
        r = run_diag(folder, *args)
        assert r.returncode == 0, r.stderr
    doc = json.loads(r.stdout)
    assert doc["coverage"] > 0.99 and np.isfinite(doc["rmse_pct"])
    return doc, (folder / "rulebases" / f"{name}.toml").read_text()


def free_run_is_the_reference(make) -> None:
    """``make(output_lags, input_spans)`` — an untrained estimator of a free-running method —
    fitted on a stable plant y[k] = f(y[k−1], y[k−2], u[k−1]): its compiled ``simulate``
    gives :func:`~diag_plugin.models.estimation.free_run` over its one-row prediction (the
    reference), with missing inputs (the recursion restarts from the measured values after
    them) and inputs outside their spans (clipped); the measured lags are never read past
    the start."""
    from diag_plugin.models.estimation import free_run

    rng = np.random.default_rng(12)
    n = 1500
    u = rng.uniform(0, 100, n)
    yv = np.zeros(n)
    for k in range(2, n):
        yv[k] = 0.5 * yv[k - 1] - 0.2 * yv[k - 2] + 0.3 * u[k - 1] + 0.002 * u[k - 1] ** 2
    X, y = np.column_stack([yv[1:-1], yv[:-2], u[1:-1]]), yv[2:]
    m = make([1, 2, 0], [(0.0, 60.0), (0.0, 60.0), (0.0, 90.0)]).fit(X, y)
    X[[100, 101, 700], 2] = np.nan  # missing inputs: no estimate, then a restart
    X[900:905, 2] = 150.0  # outside the span: clipped
    sim = m.simulate(X)
    ref = free_run(X, m.output_lags, m.spans_, m._predict_rows)
    np.testing.assert_array_equal(np.isnan(sim), np.isnan(ref))
    assert np.isnan(sim).sum() == 3
    np.testing.assert_allclose(sim, ref, rtol=1e-12, atol=1e-9 * np.ptp(y))
    spoilt = X.copy()
    spoilt[2:100, :2] = -1.0  # measured lags the free run does not read
    np.testing.assert_array_equal(m.simulate(spoilt), sim)


def plant_statuses(plant, rows: pd.DataFrame) -> dict[str, list]:
    """Per unit the statuses of ``plant`` (a :class:`~diag_plugin.diagnose.plant.Plant`)
    cycled row by row over ``rows``."""
    got: dict[str, list] = {}
    for ts, row in rows.iterrows():
        for st in plant.cycle(ts, row.to_dict()):
            got.setdefault(st.unit, []).append(st)
    return got


def same_status(x, y, where, *, exact: bool = True) -> None:
    """Two unit statuses alike: status, quality, detected, faults, message, the tags named and
    the symptoms equal; the residuals, tag shares and certainties bit for bit (``exact``) or
    to 1e-9 (the fast path against the one-by-one path: the same inputs, the residual's
    arithmetic differing in the last bits)."""
    assert (x.status, x.quality, x.detected, x.faults, x.message) == (
        y.status,
        y.quality,
        y.detected,
        y.faults,
        y.message,
    ), where
    assert [t for t, _ in x.tags] == [t for t, _ in y.tags], where
    assert x.symptoms.keys() == y.symptoms.keys() and x.residuals.keys() == y.residuals.keys()
    np.testing.assert_array_equal(list(x.symptoms.values()), list(y.symptoms.values()))
    if exact:
        assert x.tags == y.tags and x.certainties == y.certainties, where
        np.testing.assert_array_equal(list(x.residuals.values()), list(y.residuals.values()))
        return
    np.testing.assert_allclose([v for _, v in x.tags], [v for _, v in y.tags], rtol=1e-9)
    np.testing.assert_allclose(
        list(x.residuals.values()), list(y.residuals.values()), rtol=1e-9, atol=1e-9
    )
    assert x.certainties == pytest.approx(y.certainties, rel=1e-9, nan_ok=True), where


def operator_steps(rng, n: int, levels, first: float = 10.0, hold=(240, 720)) -> np.ndarray:
    """``n`` samples of a quantity the operators step among ``levels`` (never to the level it
    is at, starting from ``first``), each held ``hold`` samples (uniform)."""
    out = np.empty(n)
    i, level = 0, first
    while i < n:
        j = min(n, i + int(rng.uniform(*hold)))
        level = float(rng.choice([v for v in levels if v != level]))
        out[i:j] = level
        i = j
    return out
