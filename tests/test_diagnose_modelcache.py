"""``diag diagnose``'s cache of its tests' models (issue 34, "Speed"; diagnose/modelcache.py):
a unit loaded through it, cold or warm, diagnoses as the unit read from its files; an edited
rule base is read again; the entries are plain arrays (no pickle); ``off`` keeps nothing.

Two units: the pumping station of tests/test_unit_statesettle.py (a state's settle and its
envelope, on a seed with pump 1's current biased), and the shipped valve unit through the
command itself.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from diag_plugin.cli import main
from diag_plugin.diagnose.modelcache import ModelCache
from diag_plugin.diagnose.unit import Unit
from diag_plugin.simulate import FaultSpec, simulate_valve
from diag_plugin.unitbuild.build import build_unit
from tests.test_unit_statesettle import _station

SHIPPED = Path(__file__).resolve().parents[1] / "rulebases"


@pytest.fixture(scope="module")
def station(tmp_path_factory):
    folder = tmp_path_factory.mktemp("cache_station")
    res = build_unit("station", _station(4, 1), folder=folder, period="60s", far=0.01)
    return res.path, folder


def _same_models(a: Unit, b: Unit) -> None:
    assert list(a.models) == list(b.models)
    for name, ma in a.models.items():
        mb = b.models[name]
        assert (ma.inputs, ma.output, ma.span, ma.period, ma.out_range, ma.path) == (
            mb.inputs,
            mb.output,
            mb.span,
            mb.period,
            mb.out_range,
            mb.path,
        )
        sa, sb = ma.model.to_state(), mb.model.to_state()
        assert sa.keys() == sb.keys()
        for k in sa:
            assert np.array_equal(sa[k], sb[k]) if isinstance(sa[k], np.ndarray) else sa[k] == sb[k]
        assert np.array_equal(ma.model.conclusions_, mb.model.conclusions_)


def _same_diagnosis(a, b) -> None:
    for f in ("status", "residuals", "symptoms", "certainties", "why"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.equals(y), f


def test_a_unit_through_the_cache_diagnoses_as_read_from_its_files(station, tmp_path):
    """Cold (the entries written) and warm (read from them): the same models, state for
    state, and the same diagnosis through the state's settle and its envelope."""
    path, folder = station
    store = ModelCache(tmp_path / "models")
    plain = Unit.load(path, folder)
    cold = Unit.load(path, folder, store=store)
    entries = sorted((tmp_path / "models").glob("*.npz"))
    assert len(entries) == len({m.path.read_bytes() for m in plain.models.values()}) > 0
    warm = Unit.load(path, folder, store=store)
    assert sorted((tmp_path / "models").glob("*.npz")) == entries
    assert "state" in warm.file.envelope
    x = _station(3, 12, bias_at=2000)
    want = plain.reset().evaluate(x)
    assert (want.status.to_numpy() != want.status.iloc[0]).any()
    for u in (cold, warm):
        _same_models(plain, u)
        _same_diagnosis(want, u.reset().evaluate(x))


def test_entries_are_plain_arrays_and_an_edit_is_read_again(station, tmp_path):
    """Every entry loads without pickle; a rule's conclusion edited in the file is a new
    entry, read from the file; a broken entry is read from the file and written again."""
    path, folder = station
    work = tmp_path / "unit"
    shutil.copytree(folder, work)
    store = ModelCache(tmp_path / "models")
    first = Unit.load(work / path.name, work, store=store)
    for f in (tmp_path / "models").glob("*.npz"):
        with np.load(f, allow_pickle=False) as z:
            assert all(z[k].dtype != object for k in z.files)
    name, tm = next(iter(first.models.items()))
    text = tm.path.read_text(encoding="utf-8")
    rule = next(line for line in text.splitlines() if "then = " in line and "if = " in line)
    then = rule.split("then = ")[1].split(",")[0]
    edited = rule.replace(f"then = {then},", f"then = {float(then) + 0.125!r},")
    tm.path.write_text(text.replace(rule, edited, 1), encoding="utf-8")
    again = Unit.load(work / path.name, work, store=store)
    assert len(list((tmp_path / "models").glob("*.npz"))) == len(first.models) + 1
    plain = Unit.load(work / path.name, work)
    _same_models(plain, again)
    assert not np.array_equal(again.models[name].model.conclusions_, tm.model.conclusions_)
    for f in (tmp_path / "models").glob("*.npz"):
        f.write_bytes(b"not an npz")
    broken = Unit.load(work / path.name, work, store=store)
    _same_models(plain, broken)
    for m in broken.models.values():  # written again
        with np.load(store.folder / f"{store.key(m.path.read_bytes())}.npz") as z:
            assert "meta" in z.files


def test_diag_diagnose_keeps_the_models_and_says_the_same(tmp_path, capsys, monkeypatch):
    """The command through the cache (cold, warm) and without it (``off``): the same JSON and
    CSV; the cache folder holds the unit's models afterwards, readable by its owner alone."""
    onset = pd.Timestamp("2026-01-05T06:00", tz="UTC")
    frame = simulate_valve(8, seed=809, faults=[FaultSpec("f14", -0.3, onset)])
    url = f"sqlite:///{tmp_path / 'h.db'}"
    from historian.store import Historian

    with Historian.open(url) as h:
        h.write_samples(frame)
    cache = tmp_path / "cache"
    base = ["--db", url, "--rulebases", str(SHIPPED), "diagnose", "valve_unit", "--json"]
    out = []
    for setting in ("off", str(cache), str(cache)):
        monkeypatch.setenv("DIAG_MODEL_CACHE", setting)
        csv = tmp_path / "d.csv"
        assert main([*base, "--csv", str(csv)]) == 0
        out.append((capsys.readouterr().out, hashlib.md5(csv.read_bytes()).hexdigest()))
        if setting == "off":
            assert not cache.exists()
    assert out[0] == out[1] == out[2]
    assert '"FAILURE"' in out[0][0]
    assert len(list(cache.glob("*.npz"))) >= 4
    assert cache.stat().st_mode & 0o077 == 0


def test_a_folder_others_may_write_is_not_trusted(station, tmp_path, caplog):
    """An existing cache folder that others may write to (a model planted there would be
    believed) is not used: nothing read from it, nothing written, the reason logged once,
    and the unit loads from its files as without a cache."""
    path, folder = station
    shared = tmp_path / "models"
    shared.mkdir(mode=0o700)
    ModelCache(shared)  # made by its owner: trusted
    assert ModelCache(shared).usable()
    Unit.load(path, folder, store=ModelCache(shared))
    planted = sorted(shared.glob("*.npz"))
    assert planted
    shared.chmod(0o777)
    store = ModelCache(shared)
    for f in planted:
        f.write_bytes(b"planted")
    with caplog.at_level("WARNING", logger="diag_plugin.diagnose.modelcache"):
        loaded = Unit.load(path, folder, store=store)
        Unit.load(path, folder, store=store)
    assert not store.usable()
    said = [r.getMessage() for r in caplog.records if "not used" in r.getMessage()]
    assert len(said) == 1 and "777" in said[0], said
    assert all(f.read_bytes() == b"planted" for f in planted)  # nothing written over
    _same_models(Unit.load(path, folder), loaded)
    shared.chmod(0o700)


def test_the_key_covers_every_module_a_model_is_read_with(station, tmp_path):
    """Each module of the rule-base reader, the models' codecs and the fuzzy models that
    loading a unit imports is part of the key: a change to any of them is a new key."""
    import sys

    path, folder = station
    Unit.load(path, folder, store=ModelCache(tmp_path / "models"))
    root = Path(__file__).resolve().parents[1] / "diag_plugin"
    used = {
        Path(m.__file__).resolve().relative_to(root).as_posix()
        for name, m in list(sys.modules.items())
        if name.startswith(("diag_plugin.fuzzy.", "diag_plugin.models.", "diag_plugin.rulebase."))
        and getattr(m, "__file__", None)
    }
    assert used
    assert used <= set(ModelCache.code_files()), sorted(used - set(ModelCache.code_files()))


def test_an_entry_keeps_each_array_as_it_was():
    """An entry's arrays are one byte array and a layout (modelcache.pack: ~900 members of
    the bench's 45 entries were each opened and parsed): each comes back with its type,
    shape, memory order and values, its own writable copy; what would need a pickle is not
    kept, and a layout that does not fit its bytes is refused."""
    from diag_plugin.diagnose.modelcache import ALIGN, pack, unpack

    rng = np.random.default_rng(3)
    arrays = {
        "w": rng.normal(size=(5, 7)),
        "f": np.asfortranarray(rng.integers(-9, 9, size=(4, 3)).astype(np.int32)),
        "mask": rng.normal(size=9) > 0,
        "n": np.int64(41),
        "none": np.zeros((0, 3), np.float32),
        "strided": rng.normal(size=(6, 8))[:, ::3],
        "nan": np.array([np.nan, -0.0, np.inf]),
    }
    blob, layout = pack(arrays)
    assert blob.dtype == np.uint8 and all(at % ALIGN == 0 for *_, at in layout)
    back = unpack(blob, layout)
    assert list(back) == list(arrays)
    for k, a in arrays.items():
        a = np.asarray(a)
        b = back[k]
        assert (b.dtype, b.shape) == (a.dtype, a.shape), k
        assert b.tobytes(order="A") == np.asarray(a, order="A").tobytes(order="A"), k
        assert b.flags.writeable and b.flags.owndata, k
    assert back["f"].flags.f_contiguous and not back["f"].flags.c_contiguous
    with pytest.raises(ValueError):
        pack({"text": np.array(["a", "b"])})
    with pytest.raises(ValueError):
        unpack(blob[:-8], layout)
