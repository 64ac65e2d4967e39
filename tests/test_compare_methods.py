"""``diag compare-methods``: each row trains the method it names (issue 36).

Kościelny et al. (seed 001, Sect. 4.1–4.2) keep, of conflicting rules, the one with the largest
weight (classic Wang–Mendel, eq. 2 and step 4) and find it "sensitive to measurement
disturbances"; their modification averages the conclusions (eq. 5). On noisy data the ``wm``
row must therefore be a different model from ``wm-avg``'s, and a worse one.
"""

import json

import numpy as np
import pandas as pd
import pytest
from helpers import cv_flow_historian

from diag_plugin.cli import main
from diag_plugin.engine import method_compare
from diag_plugin.rulebase.document import RuleBase


def _rows(g: list[str], name: str, capsys) -> dict[str, dict]:
    capsys.readouterr()
    assert main([*g, "compare-methods", name, "--json"]) == 0
    return {r["method"]: r for r in json.loads(capsys.readouterr().out)["methods"]}


def _trained_rmse(g: list[str], name: str, capsys) -> float:
    capsys.readouterr()
    assert main([*g, "train", name, "--json"]) == 0
    return json.loads(capsys.readouterr().out)["validation"]["rmse_pct"]


@pytest.mark.parametrize("seed", [3, 8])
def test_the_wm_row_is_classic_wm_and_averaging_wins_on_noisy_data(tmp_path, capsys, seed):
    """Noise of 5 % of span: the ``wm`` row is the file trained as ``wm`` (the same held-out
    error as ``diag train`` of a ``wm`` file), the ``wm-avg`` row a ``wm-avg`` one, and the
    average beats the max-weight winner (seed 001's argument for eq. 5). The rows do not
    depend on the method the compared file names (a ts-fcm file gives the same)."""
    g = cv_flow_historian(tmp_path, noise=2.0, seed=seed)
    for name, method in (("avg", "wm-avg"), ("classic", "wm"), ("tsk", "ts-fcm")):
        # one shape for all three files (model new would choose it per method): the files
        # differ in their method alone
        assert main([*g, "model", "new", name, "--output", "F", "--input", "CV[k-1]",
                     "--method", method, "--shape", "trapezoidal"]) == 0  # fmt: skip
    rows = _rows(g, "avg", capsys)
    assert rows["wm-avg"]["rmse_pct"] == pytest.approx(_trained_rmse(g, "avg", capsys))
    assert rows["wm"]["rmse_pct"] == pytest.approx(_trained_rmse(g, "classic", capsys))
    # noise of 5 % of span is the floor of both; the winner's own noise comes on top
    assert 5.0 < rows["wm-avg"]["rmse_pct"] < 5.3
    assert rows["wm"]["rmse_pct"] > 1.1 * rows["wm-avg"]["rmse_pct"], rows
    from_tsk = _rows(g, "tsk", capsys)
    for m in ("wm-avg", "wm", "ts-fcm", "narmax2"):
        assert from_tsk[m]["rmse_pct"] == pytest.approx(rows[m]["rmse_pct"]), m


def test_an_attribute_the_view_lacks_is_an_error_not_the_files_value(tmp_path, monkeypatch):
    """The view of a file as another method forwards nothing it does not name: a codec without
    ``default_options`` fails loudly instead of training the file's own method."""
    from diag_plugin.workbench.model_edit import new_model
    from historian.taginfo import TagInfo

    info = {"CV": TagInfo("CV", "%", 0.0, 100.0), "F": TagInfo("F", "t/h", 0.0, 40.0)}
    idx = pd.date_range("2026-03-01", periods=50, freq="10s", tz="UTC", name="ts")
    frame = pd.DataFrame({"CV": np.linspace(0, 100, 50), "F": np.linspace(0, 30, 50)}, idx)
    rb = new_model(tmp_path / "m.toml", "m", "F[k]", ["CV[k-1]"], frame=frame, tag_info=info)
    view = method_compare.AsMethod(rb, "wm")
    assert view.spec.method == "wm" and view.new_model().method == "wm"
    with pytest.raises(AttributeError):
        view.rules  # noqa: B018 - the file's rules are not the compared method's

    class NoDefaults:
        def new_estimator(self, spec):  # pragma: no cover - never reached
            raise AssertionError

    monkeypatch.setattr(method_compare, "get_method", lambda name: NoDefaults())
    with pytest.raises(AttributeError, match="default_options"):
        method_compare.AsMethod(rb, "wm")
    assert isinstance(RuleBase.load(tmp_path / "m.toml"), RuleBase)
