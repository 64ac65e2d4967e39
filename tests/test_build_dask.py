"""``diag unit build --dask``: the per-test work on a Dask cluster builds the local unit
(issue 34, speed).

Judged on the tour's small tank and heat exchanger (:mod:`diag_plugin.simulate.smallplants`),
as the local pool is in tests/test_build_speed.py: the unit built on a LocalCluster (bound to
127.0.0.1 only: two worker processes of one thread each) is the unit one local process
builds, file for file but the times it was written at; an address where no scheduler listens
is a clear error naming it before the historian is read; a worker killed mid-build has its
tasks rerun by Dask and the unit is the same, or the build fails with a clear error and
leaves none of its files.
"""

from __future__ import annotations

import os
import signal
import socket

import pytest

from diag_plugin.unitbuild.build import build_unit
from diag_plugin.unitbuild.parallel import DaskPool
from historian.errors import UserError
from tests.test_any_plant_tour import diag
from tests.test_build_speed import _plant, _text

distributed = pytest.importorskip("distributed")


def _cluster(workers: int = 2):
    """A LocalCluster on 127.0.0.1: ``workers`` processes of one thread each."""
    return distributed.LocalCluster(
        n_workers=workers,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        protocol="tcp",
    )


@pytest.fixture(scope="module")
def cluster():
    with _cluster() as c:
        yield c


def _same_files(a, b) -> None:
    files = sorted(p.name for p in a.iterdir())
    assert files == sorted(p.name for p in b.iterdir())
    assert len(files) > 1
    for name in files:
        assert _text(a / name) == _text(b / name), name


@pytest.mark.parametrize("kind", ["tank", "heatex"])
def test_the_dask_build_is_the_local_build(tmp_path, cluster, kind):
    frame = _plant(kind, 3.0, 21)
    local = build_unit("u", frame, folder=tmp_path / "local", period="60s", far=0.05, workers=1)
    seen: dict[str, int] = {}
    with DaskPool.connect(cluster.scheduler_address) as pool:
        far = build_unit("u", frame, folder=tmp_path / "dask", period="60s", far=0.05,
                         workers=pool, progress=lambda s, d, n: seen.update({s: n}))  # fmt: skip
    # each shared argument sent to the workers once per build, not with every task: the
    # window's context once for the choice and the training, the unit once for its thresholds
    assert pool.scattered.count("_Context") == 1 and pool.scattered.count("Unit") == 1
    assert not {"int", "float", "bool", "str", "NoneType"} & set(pool.scattered)
    assert [t.as_dict() for t in local.tests] == [t.as_dict() for t in far.tests]
    assert local.learned.limits == far.learned.limits
    assert seen["choose inputs"] > 1 and seen["train models"] > 1
    _same_files(tmp_path / "local", tmp_path / "dask")


def test_the_command_with_dask_writes_the_local_unit(tmp_path, cluster):
    """``diag unit build --dask ADDRESS`` from a historian: the files of the build without it."""
    from tests.test_any_plant_tour import fmt, import_csv

    frame = _plant("heatex", 3.0, 22)
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}"]
    import_csv([*g, "--rulebases", str(tmp_path / "rb")], frame, tmp_path / "x.csv")
    window = ["--from", fmt(frame.index[0]), "--to", fmt(frame.index[-1]), "--far", "0.05"]
    for where, more in (("local", []), ("dask", ["--dask", cluster.scheduler_address])):
        rc, text = diag([*g, "--rulebases", str(tmp_path / where)], "unit", "build", "u",
                        *window, *more)  # fmt: skip
        assert rc == 0, text
    _same_files(tmp_path / "local", tmp_path / "dask")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_an_unreachable_scheduler_is_an_error_naming_it_before_any_work(tmp_path):
    address = f"tcp://127.0.0.1:{_free_port()}"  # nothing listens there
    with pytest.raises(UserError, match=address):
        DaskPool.connect(address, timeout=2)
    # through the command: said before the historian is read (it holds no tags, which the
    # build would say first), exit 2, nothing written
    g = ["--db", f"sqlite:///{tmp_path / 'h.db'}", "--rulebases", str(tmp_path / "rb")]
    rc, text = diag(g, "unit", "build", "u", "--from", "2026-03-02", "--to", "2026-03-05",
                    "--dask", address, "--dask-timeout", "2")  # fmt: skip
    assert rc == 2, text
    assert address in text and "cannot reach the Dask scheduler" in text
    assert "holds no tags" not in text
    assert not (tmp_path / "rb").exists()


@pytest.mark.parametrize("allowed", [3, 0], ids=["rerun", "no-rerun"])
def test_a_worker_killed_mid_build_is_rerun_to_the_same_unit_or_a_clean_error(tmp_path, allowed):
    """Dask's default (``allowed-failures`` 3) runs a killed worker's tasks again: the same
    unit. A scheduler that allows no failure gives up: a clear error, and no file left."""
    import dask

    frame = _plant("tank", 3.0, 21)
    local = build_unit("u", frame, folder=tmp_path / "local", period="60s", far=0.05, workers=1)
    killed: list[int] = []
    with (
        dask.config.set({"distributed.scheduler.allowed-failures": allowed}),
        _cluster() as c,
        DaskPool.connect(c.scheduler_address) as pool,
    ):
        pids = sorted(pool.client.run(os.getpid).values())
        assert len(pids) == 2 and os.getpid() not in pids

        def progress(stage: str, done: int, total: int) -> None:
            if stage == "train models" and not killed and done < total:
                os.kill(pids[0], signal.SIGKILL)  # a worker process this test started
                killed.append(pids[0])

        try:
            far = build_unit("u", frame, folder=tmp_path / "dask", period="60s", far=0.05,
                             workers=pool, progress=progress)  # fmt: skip
        except UserError as exc:  # Dask gave up on the work: said, and nothing left
            assert c.scheduler_address in str(exc)
            assert not (tmp_path / "dask").exists() or not any((tmp_path / "dask").iterdir())
            far = None
    assert killed
    if far is not None:  # Dask ran the killed worker's tasks again: the same unit
        assert local.learned.limits == far.learned.limits
        _same_files(tmp_path / "local", tmp_path / "dask")


def test_a_failed_build_leaves_none_of_its_files(tmp_path, monkeypatch):
    """A build that fails after writing its models (here: the thresholds) removes what it
    wrote, and the folder it made; files that were there before stay."""
    import diag_plugin.learn.thresholds as T

    frame = _plant("tank", 3.0, 21)
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "other.toml").write_text("# not this build's\n")

    def broken(*a, **k):
        raise RuntimeError("lost")

    monkeypatch.setattr(T, "learn_thresholds", broken)
    for folder in (tmp_path / "new", tmp_path / "old"):
        with pytest.raises(RuntimeError, match="lost"):
            build_unit("u", frame, folder=folder, period="60s", far=0.05, workers=1)
    assert not (tmp_path / "new").exists()
    assert [p.name for p in (tmp_path / "old").iterdir()] == ["other.toml"]


def test_a_failed_rebuild_puts_the_old_unit_back(tmp_path, monkeypatch):
    """A ``--force`` rebuild that fails after overwriting the unit's model files leaves the
    unit that was there byte for byte as it was (it was deleted with the new files before)."""
    import diag_plugin.learn.thresholds as T

    frame = _plant("tank", 3.0, 21)
    folder = tmp_path / "units"
    build_unit("u", frame, folder=folder, period="60s", far=0.05, workers=1)
    old = {p.name: p.read_bytes() for p in folder.iterdir()}
    assert any(n.startswith("u_") for n in old) and "u.unit.toml" in old

    def broken(*a, **k):
        raise RuntimeError("lost")

    monkeypatch.setattr(T, "learn_thresholds", broken)
    with pytest.raises(RuntimeError, match="lost"):
        build_unit("u", _plant("tank", 3.0, 22), folder=folder, period="60s", far=0.05,
                   workers=1, force=True)  # fmt: skip
    assert {p.name: p.read_bytes() for p in folder.iterdir()} == old
