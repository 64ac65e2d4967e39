"""One way to say "on this Dask cluster" for every command (issue 34).

``diag unit build --dask ADDRESS [--dask-timeout S]`` and ``diag train NAME --dask ADDRESS
[--dask-timeout S]`` take the same options and connect through one helper
(:mod:`diag_plugin.training.dask_connect`) with the same checks before any work: the scheduler
reachable within the timeout, a worker there, the same package version; each failure exit 2
naming the address. train's old spelling ``--engine dask --scheduler ADDRESS`` still works,
marked deprecated in its ``--help``. A LocalCluster bound to 127.0.0.1 (as in
tests/test_build_dask.py) is the cluster; the plant is a valve of our own making.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from tests.test_any_plant_tour import diag
from tests.test_build_dask import _cluster, _free_port

distributed = pytest.importorskip("distributed")


@pytest.fixture(scope="module")
def cluster():
    with _cluster() as c:
        yield c


def _valve(days: float = 1.5, seed: int = 8) -> pd.DataFrame:
    """A flow following its valve's opening 20 s late, through a square-root law."""
    rng = np.random.default_rng(seed)
    n = int(days * 8640)
    u = np.repeat(rng.uniform(5, 95, n // 12 + 1), 12)[:n]
    f = 40 * np.sqrt(np.r_[np.full(2, u[0]), u[:-2]] / 100) + rng.normal(0, 0.2, n)
    idx = pd.date_range("2026-04-01", periods=n, freq="10s", tz="UTC")
    return pd.DataFrame({"U": u, "F": f}, index=idx)


@pytest.fixture
def plant(tmp_path):
    from historian import Historian

    db = f"sqlite:///{tmp_path / 'plant.db'}"
    with Historian(db) as h:
        h.ensure_tag("U", unit="%", lo=0, hi=100)
        h.ensure_tag("F", unit="t/h", lo=0, hi=40)
        h.write_samples(_valve())
    g = ["--db", db, "--rulebases", str(tmp_path / "rb")]
    rc, text = diag(g, "model", "new", "m", "--output", "F", "--input", "U[k-2]")
    assert rc == 0, text
    return g, tmp_path


def _rules(path) -> list[str]:
    return [ln for ln in path.read_text().splitlines() if ln.lstrip().startswith("{ if")]


def test_both_commands_say_it_the_same_way_and_train_s_old_spelling_is_marked():
    helps = {}
    for cmd in (["train"], ["unit", "build"]):
        rc, text = diag([], *cmd, "--help")
        assert rc == 0
        helps[" ".join(cmd)] = " ".join(text.split())
    for text in helps.values():
        assert "--dask ADDRESS" in text and "--dask-timeout S" in text
        assert "seconds to reach the scheduler and see a worker there (10)" in text
    train = helps["train"]
    assert "--engine {local,dask} deprecated: say --dask ADDRESS" in train
    assert "--scheduler ADDRESS deprecated: say --dask ADDRESS" in train


@pytest.mark.parametrize(
    "spelling", [["--dask"], ["--engine", "dask", "--scheduler"]], ids=["new", "old"]
)
def test_train_with_no_scheduler_there_is_exit_2_naming_it_before_any_work(plant, spelling):
    g, tmp = plant
    address = f"tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    before = (tmp / "rb" / "m.toml").read_text()
    rc, text = diag(g, "train", "m", *spelling, address, "--dask-timeout", "1")
    assert rc == 2, text
    assert f"--dask {address}: cannot reach the Dask scheduler within 1 s" in text
    assert (tmp / "rb" / "m.toml").read_text() == before  # nothing trained, nothing written
    rc, text = diag(g, "experiments", "m", "--json")
    assert '"experiments": []' in text
    rc, text = diag(g, "train", "m", "--dask", address, "--dask-timeout", "0")
    assert rc == 2 and "--dask-timeout 0: must be positive" in text


def test_train_on_a_scheduler_without_workers_is_exit_2_naming_it(plant):
    g, _ = plant
    with _cluster(workers=0) as empty:
        rc, text = diag(g, "train", "m", "--dask", empty.scheduler_address, "--dask-timeout", "1")
    assert rc == 2, text
    assert f"--dask {empty.scheduler_address}: the scheduler has no worker after 1 s" in text


def test_train_on_the_cluster_is_the_local_training_in_either_spelling(plant, cluster):
    g, tmp = plant
    model = tmp / "rb" / "m.toml"
    runs = {}
    for name, more in (
        ("local", []),
        ("dask", ["--dask", cluster.scheduler_address]),
        ("old", ["--engine", "dask", "--scheduler", cluster.scheduler_address]),
    ):
        # chunks of 6 h: the cluster trains several and the client merges them
        rc, text = diag(g, "train", "m", "--chunk", "6h", "--no-baseline", *more)
        assert rc == 0, text
        runs[name] = (_rules(model), text)
    assert len(runs["local"][0]) > 10
    assert runs["dask"][0] == runs["local"][0] and runs["old"][0] == runs["local"][0]
    assert "deprecated: say --dask ADDRESS" in runs["old"][1]
    assert "deprecated" not in runs["dask"][1]
    rc, text = diag(
        g, "train", "m", "--dask", cluster.scheduler_address, "--scheduler", "tcp://127.0.0.1:1"
    )
    assert rc == 2 and "give one address" in text
