"""A short window's joint test of a collinear group (issue 34, item 3; models/joint.py).

Two vibration sensors on one pump (physics written here, not a plant the build was tuned on):
both read the pump's vibration, each with its own gain and noise, beside a flow that has
nothing to do with it. From 400 samples at 1 s each sensor's test predicts it from the other
— a parity relation — so when the vibration rises (a rotor imbalance) both rise together and
each test stays quiet or goes unknown as its input leaves the window's range. The joint test
watches the pair's common direction (their score on the first principal component, as PCA's
T² does) and is what alarms. It fails on a build without joint tests (no such test, the
per-tag tests alone miss most of the rise). On fault-free continuations of unseen seeds the
unit's alarm share stays small, beside PCA T² + Q fitted on the same rows.
"""

from __future__ import annotations

import json

import numpy as np
import pandas as pd

from tests.test_any_plant_tour import diag
from tests.test_unit_short import _pca_share, _statuses, build_short_unit

ROWS = 400


def _ou(rng: np.random.Generator, n: int, tau_s: float) -> np.ndarray:
    """A unit-variance Ornstein–Uhlenbeck series at 1 s with time constant ``tau_s``."""
    a = np.exp(-1.0 / tau_s)
    e = rng.normal(0.0, np.sqrt(1 - a * a), n)
    x = np.empty(n)
    x[0] = rng.normal()
    for i in range(1, n):
        x[i] = a * x[i - 1] + e[i]
    return x


def pump(
    seed: int,
    n: int,
    rise_from: int | None = None,
    level: float = 0.25,
    flow_at: float = 32.0,
    start: str = "2026-05-04 08:00",
) -> pd.DataFrame:
    """A pump at 1 s: vibration ``V`` (g, RMS; ``level`` its mean) seen by two accelerometers
    of different sensitivity, and a flow (mean ``flow_at``) driven by its own demand. With
    ``rise_from`` the vibration rises from that sample on by 1 % of its level a minute (an
    imbalance growing)."""
    rng = np.random.default_rng([seed, 34])
    v = level + 0.004 * (level / 0.25) * _ou(rng, n, 3.0)
    if rise_from is not None:
        k = np.arange(n) - rise_from
        v = v + np.where(k > 0, level * 0.01 * k / 60.0, 0.0)
    flow = flow_at + 0.6 * _ou(rng, n, 4.0) + 0.1 * rng.normal(size=n)
    return pd.DataFrame(
        {
            "ACC1": 0.9 * v + 0.0012 * rng.normal(size=n),
            "ACC2": 1.3 * v + 0.0018 * rng.normal(size=n),
            "FLOW": flow,
        },
        index=pd.date_range(start, periods=n, freq="1s", name="ts"),
    )


def _build(tmp_path, frame: pd.DataFrame):
    return build_short_unit(tmp_path, frame.iloc[:ROWS])


def test_a_joint_test_sees_a_common_rise_the_parity_tests_miss(tmp_path):
    frame = pump(7, 1800, rise_from=ROWS + 200)
    g, text, unit = _build(tmp_path, frame)
    k = np.arange(len(frame))
    rise = k >= ROWS + 800  # ten minutes into the rise: 10 % of the vibration level
    before = (k >= ROWS) & (k < ROWS + 200)
    alarm, _, _ = _statuses(unit, frame)
    print(f"rise: unit in alarm {alarm[rise].mean():.2f}; before it: {alarm[before].mean():.2f}")
    assert alarm[rise].mean() > 0.9 and alarm[before].mean() < 0.1
    assert "jointly (their common direction)" in text, text
    rc, shown = diag(g, "unit", "show", "u")
    assert rc == 0 and "joint test of ACC1, ACC2" in shown, shown
    rc, out = diag(g, "diagnose", "u", "--json")  # diag diagnose runs the joint test
    assert rc == 0 and json.loads(out)["samples"] == ROWS, out[:2000]
    joint = [n for n, r in unit.file.build["tests"].items() if r.get("method") == "joint"]
    assert len(joint) == 1, unit.file.build["tests"]
    d = unit.reset().evaluate(frame)
    sym = d.symptoms.fillna(0).abs() > 0
    per_tag = sym[[c for c in sym.columns if c not in joint]].any(axis=1).to_numpy()
    by_joint = sym[joint[0]].to_numpy()
    print(f"joint test {by_joint[rise].mean():.2f}, per-tag tests {per_tag[rise].mean():.2f}")
    assert by_joint[rise].mean() > 0.9
    assert per_tag[rise].mean() < 0.5  # what the joint test adds
    # the alarm names the pair, not the flow
    top = d.top_tags["top1"].to_numpy()[rise & alarm]
    assert np.isin(top, ["ACC1", "ACC2"]).mean() > 0.9, pd.Series(top).value_counts()


def test_the_joint_test_keeps_fault_free_alarms_near_the_budget(tmp_path):
    """Unseen seeds, fault-free: the unit with its joint test alarms on little of the
    continuation (the next 1,200 s), no more than PCA T² + Q fitted on the same 400 rows."""
    shares, pcas = [], []
    for seed in (101, 102, 103):
        frame = pump(seed, ROWS + 1200)
        (tmp_path / str(seed)).mkdir()
        _, _, unit = _build(tmp_path / str(seed), frame)
        assert any(r.get("method") == "joint" for r in unit.file.build["tests"].values())
        alarm, _, _ = _statuses(unit, frame)
        shares.append(alarm[ROWS:].mean())
        pcas.append(_pca_share(frame.iloc[:ROWS], frame.iloc[ROWS:], int(unit.ev["on_delay"])))
    print(f"fault-free alarm share: unit {np.round(shares, 3)}, PCA {np.round(pcas, 3)}")
    assert np.mean(shares) <= max(0.05, np.mean(pcas) + 0.02), (shares, pcas)


def test_the_joint_model_is_the_group_s_first_component_and_merges_exactly():
    """``y − ŷ`` is the group's score on its first principal component (up to scale), parts
    merge into the model of all rows, and it extrapolates (no span clips a common rise)."""
    from diag_plugin.models.joint import JointRegressor

    rng = np.random.default_rng(5)
    c = rng.normal(size=600)
    U = np.column_stack([2.0 + c + 0.3 * rng.normal(size=600), 5.0 + 3 * c + rng.normal(size=600)])
    X, y = U[:, :1], U[:, 1]
    spans = [(float(X.min()), float(X.max()))]
    m = JointRegressor(input_spans=spans).fit(X, y)
    Z = (U - U.mean(0)) / U.std(0)
    v = np.linalg.eigh(np.corrcoef(U.T))[1][:, -1]
    r = y - m.predict(X)
    assert abs(np.corrcoef(r, Z @ v)[0, 1]) > 0.999999
    a = JointRegressor(input_spans=spans).fit(X[:250], y[:250])
    b = JointRegressor(input_spans=spans).fit(X[250:], y[250:])
    assert np.allclose(a.merge(b).coef_, m.coef_, rtol=1e-9, atol=1e-9)
    # a common rise far beyond the window: both up by 10 of their sd, the residual grows
    far = np.array([[X.mean() + 10 * X.std()]])
    p = m.predict_detail(far)
    assert p.support[0] == 1.0 and p.reason[0] == 0
    rise = y.mean() + 10 * y.std() - p.y[0]
    assert abs(rise) > 10 * np.std(r)


def test_the_joint_output_is_the_tag_with_the_largest_loading():
    """A group whose first tag (in the tests' order) barely loads on the component: ``A``
    joins through its parity test with ``B`` but is nearly uncorrelated with the pair ``B``,
    ``C`` that carries the common direction. The output is then the tag with the largest
    |loading| (its coefficients divide by that loading): with ``A`` as output they were
    ~1 / 0 (the 1e-9 floor) — here over 1,000 times the chosen model's."""
    from diag_plugin.models.joint import JointRegressor, first_component
    from diag_plugin.unitbuild.short import joint_groups

    rng = np.random.default_rng(11)
    n = 600
    c = np.cumsum(rng.normal(size=n)) * 0.05 + rng.normal(size=n)
    cols = {
        "B": 3.0 + c + 0.1 * rng.normal(size=n),
        "C": 7.0 + 2 * c + 0.2 * rng.normal(size=n),
    }
    # A: noise with its sample correlation to B and C removed, so its loading is ~0
    P = np.column_stack([np.ones(n), cols["B"], cols["C"]])
    a = rng.normal(size=n)
    cols["A"] = 5.0 + a - P @ np.linalg.lstsq(P, a, rcond=None)[0]
    pairs = [("A", ["B"]), ("B", ["A", "C"]), ("C", ["B"])]
    U = np.column_stack([cols[t] for t in "ABC"])
    _, _, v = first_component(np.c_[np.ones(n), U].T @ np.c_[np.ones(n), U])
    assert abs(v[0]) < 1e-6 and abs(v[1]) > 0.5  # the first tag's loading is ~0
    [(group, _, why)] = joint_groups(pairs, lambda t: cols[t])
    assert not why and sorted(group) == ["A", "B", "C"]
    assert group[0] == "ABC"[int(np.argmax(np.abs(v)))], (group, v)
    assert group[0] != "A"

    def model(out: str) -> JointRegressor:
        ins = [t for t in group if t != out]
        X = np.column_stack([cols[t] for t in ins])
        spans = [(float(x.min()), float(x.max())) for x in X.T]
        return JointRegressor(input_spans=spans).fit(X, cols[out]), X

    chosen, X = model(group[0])
    Z = (U - U.mean(0)) / U.std(0)
    r = cols[group[0]] - chosen.predict(X)
    assert abs(np.corrcoef(r, Z @ v)[0, 1]) > 0.999999  # still the component's score
    assert np.all(np.isfinite(chosen.coef_)) and np.max(np.abs(chosen.coef_[1:])) < 10
    first, _ = model("A")  # the old choice: the group's first tag
    assert np.max(np.abs(first.coef_[1:])) > 1000 * np.max(np.abs(chosen.coef_[1:]))


def _two_points(seed: int, n: int = 3000):
    """Rows of two operating points far apart (the second at 4× the first along the group's
    common direction, as SKAB's pump in its calibration run), each with its own fault-free
    co-variation, the second noisier."""
    rng = np.random.default_rng(seed)
    out = []
    for k, (centre, sd) in enumerate([((0.25, 0.36), 1.0), ((1.0, 1.45), 4.0)]):
        c = 0.004 * sd * rng.normal(size=n // 2)
        a = centre[0] + 0.9 * c + 0.0012 * sd * rng.normal(size=n // 2)
        b = centre[1] + 1.3 * c + 0.0018 * sd * rng.normal(size=n // 2)
        out.append(np.column_stack([a, b, np.full(n // 2, k)]))
    return np.vstack(out)


def test_a_joint_test_over_two_points_keeps_each_points_component_and_merges_exactly():
    """Two operating points: the model's component is the one of fault-free variation
    *within* the points (not the line between them, the pooled total covariance's), each
    point's residuals are centred on its own mean, and the models of the two windows merged
    are the model of the union fitted at once (``diag unit accept``'s exact merge)."""
    from diag_plugin.models.joint import JointRegressor, within_component

    U = _two_points(3)
    X, y, at = U[:, :1], U[:, 1], U[:, 2].astype(int)
    spans = [(0.2, 1.1)]
    points = [[U[at == k, 0].mean(), U[at == k, 1].mean()] for k in (0, 1)]
    whole = JointRegressor(input_spans=spans, points=points).fit(X, y)
    parts = [JointRegressor(input_spans=spans, points=points).fit(X[at == k], y[at == k])
             for k in (0, 1)]  # fmt: skip
    merged = parts[0].merge(parts[1])
    assert np.allclose(merged.coef_, whole.coef_, rtol=1e-9, atol=1e-12)
    assert np.allclose(merged.shifts_, whole.shifts_, rtol=1e-9, atol=1e-12)
    # the slope is the within-point one (1.3 / 0.9 in the tags' common direction) ...
    _, _, v, _ = within_component(
        [
            np.c_[np.ones(n), W].T @ np.c_[np.ones(n), W]
            for W in (U[at == 0, :2], U[at == 1, :2])
            for n in [len(W)]
        ]
    )
    r = y - whole.predict(X)
    for k in (0, 1):
        Z = U[at == k, :2] - U[at == k, :2].mean(0)
        assert abs(np.corrcoef(r[at == k], Z @ (v / U[:, :2][at == 0].std(0)))[0, 1]) > 0.9
        # ... and each point's residuals are centred on its own mean, at the scale of the
        # point's own variation, not half the distance between the points
        assert abs(r[at == k].mean()) < 1e-9 + 1e-6 * abs(points[1][1] - points[0][1])
    assert r[at == 0].std() < 0.01 * abs(points[1][1] - points[0][1])
    pooled = JointRegressor(input_spans=spans).fit(X, y)  # one point: the old model
    r1 = y - pooled.predict(X)
    assert abs(r1[at == 0].mean()) > 10 * r[at == 0].std()  # each point at one end
    # the file's form: the terms and each point's shift give the same prediction
    from diag_plugin.models.joint import JointRegressor as J

    back = J.from_state(whole.to_state())
    assert np.allclose(back.predict(X), whole.predict(X))
    coded = J(input_spans=spans, points=points).init(1).set_coefficients(whole.coef_)
    coded.set_shifts(whole.shifts_)
    assert np.allclose(coded.predict(X), whole.predict(X), rtol=1e-9, atol=1e-12)


def _accept_second_point(tmp_path, first: pd.DataFrame):
    """The pump's unit built from ``first``'s first 400 s, then an hour at a second operating
    point (vibration 4×, flow 45) accepted: the second point's run (an hour and 1,200 s),
    the unit as built and as accepted."""
    from diag_plugin.diagnose.unit import Unit
    from tests.test_any_plant_tour import fmt, import_csv

    second = pump(42, 3600 + 1200, level=1.0, flow_at=45.0, start="2026-05-06 08:00")
    g, _, built = _build(tmp_path, first)
    import_csv(g, first.iloc[ROWS:], tmp_path / "rest.csv")
    import_csv(g, second, tmp_path / "second.csv")
    hour = second.index[3600]
    rc, text = diag(g, "unit", "accept", "u", "--from", fmt(second.index[0]), "--to", fmt(hour))
    assert rc == 0, text
    return second, built, Unit.load(tmp_path / "rb" / "u.unit.toml", tmp_path / "rb")


def test_after_accepting_a_second_point_the_first_point_stays_quiet(tmp_path):
    """A unit from 400 s of the pump (its accelerometers a joint test), then an hour at a
    second operating point confirmed with ``diag unit accept`` (vibration 4×, more flow: as
    SKAB's calibration run beside its valve runs). Back at the first point, fault-free, the
    unit stays quiet, and at the second point too; a vibration rise at the first point is
    still seen. Before, the accepted joint test took its component and mean from both points
    pooled — the line between them — and alarmed on most fault-free samples at either."""
    first = pump(41, ROWS + 1800, rise_from=ROWS + 900)
    second, built, unit = _accept_second_point(tmp_path, first)
    assert any(r.get("method") == "joint" for r in built.file.build["tests"].values())
    alarm, cf, _ = _statuses(unit, first)
    quiet = slice(ROWS, ROWS + 900)
    k = np.arange(len(first))
    rise = k >= ROWS + 1500  # ten minutes into the rise
    alarm2, cf2, _ = _statuses(unit, second.iloc[3600:])
    print(f"first point fault-free: alarm {alarm[quiet].mean():.3f}, CF {cf[quiet].mean():.3f}; "
          f"rise {alarm[rise].mean():.2f}; second point: alarm {alarm2.mean():.3f}")  # fmt: skip
    assert alarm[quiet].mean() < 0.05 and alarm2.mean() < 0.05
    assert alarm[rise].mean() > 0.5


def test_after_accepting_a_second_point_the_combined_test_still_detects(tmp_path):
    """The combined T² after ``diag unit accept`` (the pump at two operating points as above:
    vibration 4× and noisier, flow 45 instead of 32 at the second). Each test's residual is
    centred and scaled at its sample's nearest point and the covariance is the pooled
    within-point one, so the T²'s threshold stays of the order it had (38 before the accept,
    24 after), fault-free samples at both points stay under it, and a bias of the flow at the
    first point (2 m³/h, a tag no model predicts: a level test against its window's mean) is
    seen by the combined test. Before, its centre and covariance were taken once across both
    points (the flow 32 against 45 m³/h, its level test against the build window's mean):
    the threshold grew to 272,200 and the combined test saw none of the bias (95 % before the
    accept)."""
    first = pump(41, ROWS + 1800)
    second, built, unit = _accept_second_point(tmp_path, first)
    high0 = built.file.combined.high
    spec = unit.file.combined
    assert len(spec.point_center) == len(spec.point_scale) == 2, spec
    assert "FLOW" in spec.point_tags

    def combined(frame: pd.DataFrame) -> np.ndarray:
        return unit.reset().evaluate(frame).combined["s_T2"].to_numpy() > 0

    quiet1, quiet2 = combined(first)[ROWS:], combined(second.iloc[3600:])
    biased = first.copy()
    biased.iloc[ROWS + 600 :, biased.columns.get_loc("FLOW")] += 2.0
    seen = combined(biased)[ROWS + 660 :]  # a minute after the bias starts
    print(f"combined test: high {high0:.3g} -> {spec.high:.3g}; fault-free in alarm "
          f"{quiet1.mean():.3f} (first point), {quiet2.mean():.3f} (second); flow bias "
          f"seen {seen.mean():.2f}")  # fmt: skip
    assert spec.high < 10 * high0, (high0, spec.high)
    assert quiet1.mean() < 0.05 and quiet2.mean() < 0.05, (quiet1.mean(), quiet2.mean())
    assert seen.mean() > 0.9, seen.mean()


def test_a_parity_test_over_two_points_keeps_the_within_point_slope_and_merges_exactly():
    """A linear (parity) test given a second operating point by ``diag unit accept``
    (:class:`~diag_plugin.models.joint.PointLinearRegressor`): the slope is fitted within
    the points, each point keeps its own constant, and the models of the two windows merged
    are the model of the union. One least-squares line over both is the line between them
    (a slope of 5 here, where the tag moves 2 per unit of its input at each point), and its
    residuals at each point carry the input's noise times the wrong slope."""
    from diag_plugin.models.joint import PointLinearRegressor
    from diag_plugin.models.linear import LinearRegressor

    rng = np.random.default_rng(7)
    rows = []
    for k, (x0, y0) in enumerate([(10.0, 20.0), (12.0, 30.0)]):
        x = x0 + 0.3 * rng.normal(size=1500)
        rows.append(np.column_stack([x, y0 + 2.0 * (x - x0) + 0.05 * rng.normal(size=1500),
                                     np.full(1500, k)]))  # fmt: skip
    U = np.vstack(rows)
    X, y, at = U[:, :1], U[:, 1], U[:, 2].astype(int)
    spans = [(8.0, 14.0)]
    points = [[U[at == k, 0].mean(), U[at == k, 1].mean()] for k in (0, 1)]
    whole = PointLinearRegressor(input_spans=spans, points=points).fit(X, y)
    parts = [PointLinearRegressor(input_spans=spans, points=points).fit(X[at == k], y[at == k])
             for k in (0, 1)]  # fmt: skip
    merged = parts[0].merge(parts[1])
    assert np.allclose(merged.coef_, whole.coef_, rtol=1e-9, atol=1e-12)
    assert np.allclose(merged.shifts_, whole.shifts_, rtol=1e-9, atol=1e-12)
    r = y - whole.predict(X)
    for k in (0, 1):
        assert abs(r[at == k].mean()) < 0.01 and r[at == k].std() < 0.06, (k, r[at == k].std())
    pooled = LinearRegressor(input_spans=spans).fit(X, y)
    rp = y - pooled.predict(X)
    assert rp[at == 0].std() > 5 * r[at == 0].std()
    # the file's form: the terms and each point's shift and spread give the same prediction
    coded = PointLinearRegressor(input_spans=spans, points=points).init(1)
    coded.set_coefficients(whole.coef_).set_shifts(whole.shifts_)
    assert np.allclose(coded.predict(X), whole.predict(X), rtol=1e-9, atol=1e-12)
