"""Expert edits are never lost (issue 22): a structural edit of a model's inputs carries every
locked rule whose premise still exists to the new grid, refuses (unless drop_locks) when one
cannot be carried, and keeps the previous file as a numbered backup that `diag experiments`
names."""

from __future__ import annotations

import re

import pytest
from test_workbench_core import INFO, plant, trained

from diag_plugin.cli import main
from diag_plugin.rulebase.backups import backups
from diag_plugin.rulebase.document import RuleBase
from diag_plugin.workbench.model_edit import (
    LocksNotCarried,
    add_input,
    remove_input,
    set_input,
)


def lock(rb: RuleBase, labels: list[str], then: float) -> RuleBase:
    """Lock the rule with these premise labels at ``then`` by editing the file's text, as an
    expert does."""
    text = rb.path.read_text()
    want = "[" + ", ".join(f'"{x}"' for x in labels) + "]"
    lines = text.splitlines(keepends=True)
    for i, ln in enumerate(lines):
        if f"if = {want}" in ln:
            ln = re.sub(r"then = [^,]+", f"then = {then}", ln)
            lines[i] = ln.replace("lock = false", "lock = true")
            break
    else:
        raise AssertionError(f"no rule {want}")
    rb.path.write_text("".join(lines))
    return RuleBase.load(rb.path)


def locked(rb: RuleBase) -> dict[tuple[str, ...], float]:
    return {
        tuple(v.set_label(i) for v, i in zip(rb.inputs, r.premise, strict=True)): r.then
        for r in rb.rules
        if r.lock
    }


def test_adding_an_input_carries_a_lock_across_all_sets_of_the_new_input(tmp_path):
    f = plant(3, 5)
    rb, _ = trained(tmp_path, f, ["CV[k-1]"])
    label = rb.inputs[0].set_label(rb.rules[3].premise[0])
    rb = lock(rb, [label], 12.5)
    before = rb.path.read_text()
    rb = add_input(rb, "P1[k]", frame=f, tag_info=INFO)
    kept = locked(rb)
    assert len(kept) == rb.inputs[1].sets and set(kept.values()) == {12.5}
    assert {k[0] for k in kept} == {label}
    assert f"{rb.inputs[1].sets} locked rule(s) carried" in rb.training["status"]
    (bak,) = backups(rb.path)
    assert bak.name == "m.toml.~1~" and bak.read_text() == before
    # and the retraining keeps them
    from diag_plugin.training.chunked import train

    a, b = f.index[0], f.index[-1]
    res = train(rb, lambda x, y: f[(f.index >= x) & (f.index < y)], a, b)
    rb.apply_training(res.model)
    rb.save()
    assert set(locked(RuleBase.load(rb.path)).values()) == {12.5}


def test_a_resize_carries_locks_inside_the_new_span_and_refuses_to_lose_the_others(tmp_path):
    f = plant(3, 5)
    rb, _ = trained(tmp_path, f, ["CV[k-1]", "P1[k]"])
    p1 = rb.inputs[1]
    step = (p1.span[1] - p1.span[0]) / (p1.sets - 1)
    rules = sorted(rb.rules, key=lambda r: r.premise)
    inside = next(r for r in rules if 620 < p1.span[0] + r.premise[1] * step < 720)
    outside = next(r for r in rules if p1.span[0] + r.premise[1] * step < 590)
    labels = lambda r: [v.set_label(i) for v, i in zip(rb.inputs, r.premise, strict=True)]  # noqa: E731
    rb = lock(rb, labels(inside), 20.0)
    rb = lock(rb, labels(outside), 5.0)
    text = rb.path.read_text()
    with pytest.raises(LocksNotCarried, match=r"m\.toml:\d+: .*outside the new span 600..800"):
        set_input(rb, "P1[k]", span=(600.0, 800.0), sets=11)
    assert rb.path.read_text() == text and backups(rb.path) == []  # nothing changed
    rb = set_input(RuleBase.load(rb.path), "P1[k]", span=(600.0, 800.0), sets=11, drop_locks=True)
    assert list(locked(rb).values()) == [20.0]
    (_, p) = next(iter(locked(rb)))
    centre = 600 + int(p.removeprefix("P1_")) * 20
    old_centre = p1.span[0] + inside.premise[1] * step
    assert abs(centre - old_centre) <= 10  # the nearest new set
    assert "1 lock(s) dropped (--drop-locks)" in rb.training["status"]


def test_removing_an_input_merges_agreeing_locks_and_refuses_conflicting_ones(tmp_path):
    f = plant(3, 5)
    rb, _ = trained(tmp_path, f, ["CV[k-1]", "P1[k]"])
    by_cv: dict[int, list] = {}
    for r in rb.rules:
        by_cv.setdefault(r.premise[0], []).append(r)
    cv, pair = next((k, v) for k, v in sorted(by_cv.items()) if len(v) >= 2)
    labels = lambda r: [v.set_label(i) for v, i in zip(rb.inputs, r.premise, strict=True)]  # noqa: E731
    rb = lock(rb, labels(pair[0]), 7.0)
    rb = lock(rb, labels(pair[1]), 9.0)
    with pytest.raises(LocksNotCarried, match="meet in one cell of the new grid"):
        remove_input(rb, "P1[k]")
    rb = lock(RuleBase.load(rb.path), labels(pair[1]), 7.0)
    rb = remove_input(rb, "P1[k]")
    assert locked(rb) == {(rb.inputs[0].set_label(cv),): 7.0}


def test_cli_refuses_with_exit_2_and_experiments_name_the_backups(tmp_path, capsys):
    from historian import Historian

    f = plant(2, 7)
    db = f"sqlite:///{tmp_path / 'd.db'}"
    with Historian(db) as h:
        h.write_samples(f)
    g = ["--db", db, "--rulebases", str(tmp_path)]
    rb, _ = trained(tmp_path, f, ["CV[k-1]", "P1[k]"])
    r = sorted(rb.rules, key=lambda r: r.premise)[0]
    rb = lock(rb, [v.set_label(i) for v, i in zip(rb.inputs, r.premise, strict=True)], 3.0)
    capsys.readouterr()
    assert main([*g, "model", "set-input", "m", "P1[k]", "--span", "700", "900"]) == 2
    err = capsys.readouterr().err
    assert "cannot be carried" in err and "--drop-locks" in err
    assert main([*g, "model", "add-input", "m", "P2[k]"]) == 0
    out = capsys.readouterr().out
    assert "locked rule(s) carried" in out and "m.toml.~1~" in out
    assert main([*g, "experiments", "m"]) == 0
    assert "earlier file kept:" in capsys.readouterr().out
