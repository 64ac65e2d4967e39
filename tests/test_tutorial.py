"""docs/tutorial/first-model.md reproduces: its commands run as written and print its numbers."""

import json
import re
import shlex
from pathlib import Path

import pytest
from helpers import run_diag

DOC = Path(__file__).resolve().parents[1] / "docs" / "tutorial" / "first-model.md"


def commands(text: str) -> list[list[str]]:
    return [shlex.split(m) for m in re.findall(r"^\$ diag (.+)$", text, flags=re.M)]


def staircase(text: str) -> list[tuple[str, list[str], float, float]]:
    """Step 4's table: version, inputs, held-out RMSE, the HGB baseline's."""
    rows = re.findall(r"^\| (\d+) \| ([^|]+) \| ([\d.]+) \| ([\d.]+) \|$", text, flags=re.M)
    return [
        (v, [s.strip() for s in inputs.split(", ")], float(e), float(h)) for v, inputs, e, h in rows
    ]


RULE = re.compile(r'^\s*\{ if = \["(CV\d\d)"\], then = ([\d.]+), .*lock = true \},$')


def hand_edit(path: Path, block: str) -> dict[str, float]:
    """Step 6's edit as a user makes it: each rule of the doc's block replaces ``then`` and
    ``lock`` of the file's rule with that premise (its n and sd kept), or is added at the top
    of the list with the comment above it. Returns the edited conclusions."""
    lines = path.read_text().splitlines()
    edits, comment = {}, []
    for ln in block.splitlines():
        m = RULE.match(ln)
        if m:
            edits[m.group(1)] = (float(m.group(2)), ln, comment)
            comment = []
        elif ln.strip().startswith("#"):
            comment = [ln]
    new = []
    for label, (then, ln, com) in edits.items():
        at = [k for k, x in enumerate(lines) if f'if = ["{label}"]' in x]
        if at:
            k = at[0]
            x = re.sub(r"then = [\d.]+", f"then = {then:.3f}", lines[k])
            lines[k] = x.replace("lock = false", "lock = true")
        else:
            new += [*com, ln]
    start = lines.index("list = [") + 1
    path.write_text("\n".join(lines[:start] + new + lines[start:]) + "\n")
    return {label: v[0] for label, v in edits.items()}


@pytest.mark.slow
def test_tutorial_reproduces(tmp_path):
    text = DOC.read_text()
    out = {}
    step6 = text[text.index("## 6. ") :]
    block = re.search(r"```toml\n(.*?)```", step6, flags=re.S).group(1)
    b1_text, edited = None, {}
    for args in commands(text):
        if args == ["rules", "check", "rulebases/model_b.toml"]:  # the hand edit first
            b1_text = (tmp_path / "rulebases/model_b.toml").read_text()
            edited = hand_edit(tmp_path / "rulebases/model_b.toml", block)
        p = run_diag(tmp_path, *args, COLUMNS="260")  # the explain table unwrapped
        assert p.returncode == 0, (args, p.stderr)
        out.setdefault(args[0], []).append(p.stdout + p.stderr)
    stated = re.search(
        r"valve v1: held-out RMSE ([\d.]+) % of span, MAE ([\d.]+) %.*; "
        r"([\d,]+) samples, (\d+) rules",
        text,
    )
    printed = re.search(
        r"valve v1: held-out RMSE ([\d.]+) % of span, MAE ([\d.]+) %.*; "
        r"([\d,]+) samples, (\d+) rules",
        out["train"][0],
    )
    assert printed, out["train"][0]
    for a, b in zip(stated.groups()[:2], printed.groups()[:2], strict=True):
        assert float(b) == pytest.approx(float(a), abs=0.05)
    assert printed.groups()[2:] == stated.groups()[2:]
    log = run_diag(tmp_path, "experiments", "valve", "--json")
    got = json.loads(log.stdout)["experiments"]
    want = staircase(text)
    assert len(want) == 2 == len(got)
    for (v, inputs, err, hgb), g in zip(want, got, strict=True):
        assert (g["version"], g["inputs"]) == (v, inputs)
        assert g["rmse_pct"] == pytest.approx(err, abs=0.05)
        assert g["hgb_baseline_rmse_pct"] == pytest.approx(hgb, abs=0.05)
    explained = out["explain"][0]
    assert (
        "diff(P1,P2)[k] would cut the error" in explained and "7.6 % to 1.3 % of span" in explained
    )
    assert (tmp_path / "valve.html").stat().st_size > 100_000

    # step 6: B.1 -> B.2 by hand; the checks, the locks kept by training, the stated errors
    assert len(edited) == 14 and b1_text is not None
    assert "model_b.toml: ok" in out["rules"][-2]
    for stated, printed in (
        (r"model_b v1: held-out RMSE ([\d.]+) %", out["train"][-2]),
        (r"model_b v2: held-out RMSE ([\d.]+) %", out["train"][-1]),
    ):
        want = float(re.search(stated, step6).group(1))
        assert float(re.search(stated, printed).group(1)) == pytest.approx(want, abs=0.05)
    for i, compared in enumerate((out["compare"][-2], out["compare"][-1])):
        said = re.findall(r"RMSE ([\d.]+) %  MAE ([\d.]+) %.*coverage ([\d.]+)%", step6)[i]
        got = re.search(r"RMSE ([\d.]+) %  MAE ([\d.]+) %.*coverage ([\d.]+)%", compared)
        assert [float(g) for g in got.groups()] == pytest.approx([float(v) for v in said], abs=0.05)
    from diag_plugin.rulebase.document import RuleBase

    b2 = RuleBase.load(tmp_path / "rulebases/model_b.toml")
    rules = {b2.inputs[0].set_label(r.premise[0]): r for r in b2.rules}
    assert {k: rules[k].then for k in edited} == edited and all(rules[k].lock for k in edited)
    assert sum(not r.lock for r in b2.rules) == 17
    values = [rules[f"CV{k:02d}"].then for k in range(31)]
    assert values == sorted(values)  # monotone
    # the doc's numbers are the code's: examples.expert_b2 on this B.1 gives the same edit
    from diag_plugin.examples.expert_b2 import expert_edit

    (tmp_path / "b1.toml").write_text(b1_text)
    b1 = RuleBase.load(tmp_path / "b1.toml")
    fit = expert_edit(b1)
    assert f"`A` = {fit['a']:.2f} t/h" in step6 and f"`R` = {fit['r']:.1f}" in step6
    assert {b1.inputs[0].set_label(r.premise[0]): r.then for r in b1.rules if r.lock} == edited
    # the table of held-out errors by region
    import numpy as np
    import pandas as pd

    from diag_plugin.regressors import build_design

    week = pd.read_parquet(tmp_path / "lowload.parquet")
    d = build_design(week, ["CV[k-1]"], "F[k]")
    cv = d.X[:, 0]
    table = {}
    for name, rb in (("B.1", RuleBase(b1_text)), ("B.2", b2)):
        r = 100 * (d.y - rb.to_model().extrapolate(d.X)) / 40
        table[name] = [
            float(np.sqrt(np.mean(r[s] ** 2))) for s in (cv < 100 * 9.5 / 30, cv >= 88.3)
        ]
    rows = re.findall(r"^\| low-load week, CV .*? \| ([\d.]+).*? \| ([\d.]+) \|$", step6, re.M)
    assert len(rows) == 2
    for k, (a, b) in enumerate(rows):
        assert table["B.1"][k] == pytest.approx(float(a), abs=0.01)
        assert table["B.2"][k] == pytest.approx(float(b), abs=0.01)
