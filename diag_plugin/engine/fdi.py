"""The seed's whole engine FDI experiment (Laukonen et al., IEEE TCST 3(3), 1995, §§III–IV).

1. Fault-free runs of the simulated engine (:mod:`diag_plugin.simulate.engine`): one for
   identification, one to learn the thresholds, one per test case (different seeds: the
   seed's "similar tests run on different days").
2. The five models ``f_ω, f_ma, f_α, f_mf, f_TL`` (eqs. 2–6) with the regression vectors of
   eqs. 7–11, identified on measured data (series-parallel) with a chosen method: ``ts-fcm``
   (N = 10, m = 2, ε = 0.01, §III), ``narmax2`` (eq. 12) or ``wm-avg``.
3. Residuals ``ŷ − y`` (§IV) in free run where the method can simulate (``ts-fcm``,
   ``narmax2``): the regressors carry the estimates ω̂, m̂_a, α̂, m̂_f of the model's own earlier
   outputs and T̂_L of the load-torque model (eqs. 7, 8); ``wm-avg`` cannot, so its residuals
   are one step ahead (measured lags).
4. Post-processing (§IV): 4th-order Butterworth at π/100 (:class:`LowPass`), division by the
   signal's maximum over a fault-free run (:class:`MaxScaler`), thresholds learned from a
   fault-free run (:class:`LearnedThresholds`; the seed's Table III values belong to its engine)
   and latching (:class:`Latch`) over the seed's test window, revolutions 3000–5000.
5. Isolation by Table II (:class:`DiagnosticMatrix`, exact match, else nearest signature): by
   default the table as printed (:data:`TABLE_II`); ``matrix="derived"`` isolates by the table
   derived from eqs. 7–11 by the seed's own rule (:func:`derive_table_ii`), which reproduces the
   printed rows for m_a, α and m_f and gives ``1 0 0 1`` for the ω row (eq. 9 reads ω_dy, not
   ω; docs/explanation/engine.md, "The ω case"). Every case reports its isolation by both tables.

Plain functions, numpy/pandas in and out.
"""

from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd

from diag_plugin.diagnose.matrix import DiagnosticMatrix
from diag_plugin.diagnose.residuals import Latch, LowPass, MaxScaler
from diag_plugin.diagnose.symptoms import LearnedThresholds
from diag_plugin.engine.voltage import to_volts, volt_fault
from diag_plugin.simulate.engine import EngineFault, EngineParams, simulate_engine

__all__ = [
    "CASES",
    "DEFAULT_MATRIX",
    "ESTIMATED_INPUTS",
    "FDI_METHODS",
    "MATRICES",
    "MODELS",
    "RESIDUALS",
    "SIGNALS",
    "TABLE_II",
    "TABLE_III",
    "TABLE_II_DERIVED",
    "EngineModels",
    "Setup",
    "compare_methods",
    "derive_table_ii",
    "fault_case",
    "identify",
    "isolate",
    "matching_window",
    "new_estimator",
    "plot_residuals",
    "regressors",
    "residuals",
    "run_case",
    "run_fdi",
    "table_ii",
    "validation_errors",
]

#: methods engine-fdi can identify with
FDI_METHODS = ("ts-fcm", "narmax2", "wm-avg")

#: Eqs. 7–11: per model, its output column and its inputs ``(column, lag)``; an input on the
#: model's own output is its estimate in free run, ``T_L`` in eqs. 7–8 the estimate T̂_L.
MODELS: dict[str, tuple[str, tuple[tuple[str, int], ...]]] = {
    "omega": (  # eq. 7
        "omega",
        (("omega", 1), ("omega", 2), ("omega", 3), ("alpha", 1), ("alpha", 2), ("alpha", 3))
        + (("m_f", 1), ("m_f", 2), ("m_f", 3), ("T_L", 2)),
    ),
    "m_a": (  # eq. 8
        "m_a",
        (("m_a", 1), ("m_a", 2), ("m_a", 3), ("alpha", 1), ("alpha", 2), ("m_f", 1))
        + (("m_f", 2), ("m_f", 3), ("T_L", 1), ("T_L", 3)),
    ),
    "alpha": (  # eq. 9
        "alpha",
        (("alpha", 1), ("alpha", 2), ("alpha", 3), ("m_a", 1), ("m_a", 2), ("m_a", 3))
        + (("omega_dy", 1), ("omega_dy", 2)),
    ),
    "m_f": (  # eq. 10
        "m_f",
        (("m_f", 1), ("m_f", 2), ("m_f", 3), ("m_a", 1), ("m_a", 2), ("m_a", 3))
        + (("omega", 1), ("omega", 2), ("omega", 3)),
    ),
    "T_L": (  # eq. 11
        "T_L",
        (("T_L", 1), ("T_L", 2), ("T_L", 3), ("alpha", 1), ("alpha", 2), ("m_f", 1))
        + (("m_a", 1), ("m_a", 3), ("omega_dy", 1), ("omega_dy", 3)),
    ),
}

#: the four residuals of Table II, ``ŷ − y`` (T̂_L only feeds eqs. 7–8)
RESIDUALS = ("omega", "m_a", "alpha", "m_f")

#: the residuals :func:`residuals` returns: Table II's four and T̂_L − T_L (plotted, not tested)
SIGNALS = (*RESIDUALS, "T_L")

#: Table II as printed, per fault its residual signature over :data:`RESIDUALS` ("x": the
#: seed's "-")
TABLE_II: dict[str, tuple[str, str, str, str]] = {
    "m_a": ("x", "1", "1", "1"),
    "omega": ("1", "0", "1", "1"),
    "alpha": ("1", "1", "1", "0"),
    "m_f": ("1", "1", "0", "1"),
}

#: Table III thresholds of the seed's engine (its scaling; for reference only)
TABLE_III: dict[str, float] = {"omega": 0.10, "m_a": 0.30, "alpha": 0.04, "m_f": 0.15}

#: the seed's calibration faults (§IV): signal(s) and gain. "to obtain a 20% ω calibration
#: fault, we multiply ω by 1.20": the engine speed sensor only — the dynamometer's tachometer
#: (ω_dy, eqs. 9 and 11) is another instrument
CASES: dict[str, tuple[tuple[str, ...], float]] = {
    "none": ((), 1.0),
    "omega": (("omega",), 1.2),
    "m_a": (("m_a",), 1.2),
    "alpha": (("alpha",), 1.2),  # actuator: the engine gets 1.2 × the command
    "m_f": (("m_f",), 1.4),  # actuator: injects 1.4 × the command
}

#: inputs that eqs. 7–11 read as another model's estimate, not as measured: T̂_L in eqs. 7–8
ESTIMATED_INPUTS = ("T_L",)


def derive_table_ii(
    faults: Mapping[str, Sequence[str]] | None = None,
    models: Mapping[str, tuple[str, tuple[tuple[str, int], ...]]] = MODELS,
    estimated: Sequence[str] = ESTIMATED_INPUTS,
    residuals: Sequence[str] = RESIDUALS,
) -> dict[str, tuple[str, ...]]:
    """Table II derived from the regression vectors, by the rule the seed states for it (§IV,
    the "indirect decoupling method"): a fault on recorded signals ``faults[f]`` makes the
    residual ``ŷ − y`` of a model (:data:`RESIDUALS`) non-zero ("1") when the signal is the
    model's output or one of its measured regressors; "-" ("x", don't care) when it reaches
    the model only through another model's estimate (``estimated`` inputs, each the output of
    the model of that name in ``models``) (T̂_L in eqs. 7–8 — the seed's "very
    weakly coupled through the load torque model" for the m_a fault's ω residual); else zero.
    The model's own lags are its estimates (free run), so they carry no fault.

    For eqs. 7–11 and the seed's faults this gives the printed rows for m_a, α and m_f, and
    for ω (multiplied alone, as the seed did) ``1 0 0 1``: eq. 9 reads ω_dy, not ω, so α̂ − α
    cannot move; the printed ``1 0 1 1`` holds only if ω_dy is faulty too, and then the rule
    gives "-" for m̂_a − m_a (eq. 11 reads ω_dy, eq. 8 reads T̂_L), not the printed zero."""
    faults = {f: sig for f, (sig, _) in CASES.items() if sig} if faults is None else faults
    measured = {  # per model, the regressors read as recorded (not its lags, not estimates)
        name: {c for c, _ in inputs if c != out and c not in estimated}
        for name, (out, inputs) in models.items()
    }
    table = {}
    for fault, signals in faults.items():
        bad = set(signals)
        moved = {name for name, cols in measured.items() if cols & bad}  # estimates it moves
        row = []
        for name in residuals:
            out, inputs = models[name]
            via = {c for c, _ in inputs if c != out and c in estimated} & moved
            row.append("1" if out in bad or measured[name] & bad else "x" if via else "0")
        table[fault] = tuple(row)
    return table


#: Table II as :func:`derive_table_ii` gives it for eqs. 7–11 (``matrix="derived"``)
TABLE_II_DERIVED: dict[str, tuple[str, ...]] = derive_table_ii()

#: the matrices :func:`run_fdi` can isolate by; the first is the default (the seed's table)
MATRICES = {"printed": TABLE_II, "derived": TABLE_II_DERIVED}
DEFAULT_MATRIX = "printed"

N_REV = 7000  # the seed's cut IM240 cycle (§III)
WINDOW = (3000, 5000)  # the seed's test window, revolutions (§IV)


@dataclass(frozen=True)
class Setup:
    """How a run departs from the default experiment (the leads of issue 26,
    docs/explanation/engine.md, "The printed ω row: three leads"). Defaults: the simulator as it
    is, signals in its engineering units, faults × gain on those, thresholds learned from
    fault-free runs.

    * ``params``: the simulator's :class:`EngineParams` for every run (e.g. the automatic
      transmission, ``EngineParams(converter=True)``).
    * ``volts``: signals, models, residuals, scaling and thresholds on the seed's sensor
      voltage scale (:mod:`diag_plugin.engine.voltage`, Figs. 3–7's axes).
    * ``fault_volts``: a recorded calibration fault multiplies the sensor's voltage, offset
      and all (:func:`~diag_plugin.engine.voltage.volt_fault`), not the physical value.
    * ``table_iii``: threshold the scaled residuals at Table III's printed values instead of
      learning them (meaningful on the voltage scale, the seed's).
    * ``omega_signals``: the signals the ω case multiplies (default ω alone, as the seed;
      ``("omega", "omega_dy")`` for the engine speed read wrong by both instruments).
    * ``window``: ``"seed"`` the seed's revolutions 3000–5000 (:data:`WINDOW`); ``"matching"``
      the 2000 revolutions where the fault-free residuals are smallest
      (:func:`matching_window`, the seed's own reason for its window), the fault from its start.
    """

    params: EngineParams | None = None
    volts: bool = False
    fault_volts: bool = False
    table_iii: bool = False
    omega_signals: tuple[str, ...] = field(default=("omega",))
    window: str = "seed"

    def simulate(self, n_rev: int, seed: int, faults: Sequence[EngineFault] = ()) -> pd.DataFrame:
        """A run as the FDI sees it: simulated, recorded faults on the voltage where
        ``fault_volts``, in volts where ``volts``."""
        on_volts = [f for f in faults if self.fault_volts and f.kind == "sensor"]
        rest = [f for f in faults if f not in on_volts]
        df = simulate_engine(n_rev, seed=seed, faults=rest, params=self.params)
        for f in on_volts:
            df = volt_fault(df, {f.signal: f.gain}, f.onset)
        return to_volts(df) if self.volts else df


@dataclass
class EngineModels:
    """The five identified models (eqs. 2–6), keyed like :data:`MODELS`. ``one_step``: estimate
    one step ahead on measured data even where the method can free-run (not the seed's mode;
    for comparison, docs/explanation/engine.md)."""

    method: str
    models: dict[str, Any]
    fit_seconds: dict[str, float]
    one_step: bool = False


def table_ii(table: Mapping[str, Sequence[str]] = TABLE_II) -> DiagnosticMatrix:
    """Table II (by default as printed, :data:`TABLE_II`; or as derived,
    :func:`derive_table_ii`) as a :class:`DiagnosticMatrix` (tests = :data:`RESIDUALS`)."""
    faults = list(table)
    rows = [[table[f][t] for f in faults] for t in range(len(RESIDUALS))]
    return DiagnosticMatrix(list(RESIDUALS), faults, rows, name="seed 000 Table II")


def fault_case(
    case: str, onset: int, kind: str = "recorded", omega_signals: Sequence[str] | None = None
) -> list[EngineFault]:
    """The calibration fault(s) of a case (Laukonen et al. §IV, Table I) from ``onset`` on.

    ``kind="recorded"`` multiplies the recorded signal, as the seed simulated its faults
    ("multiplying the experimental data for a specific fault by the desired calibration fault
    value"); ``"physical"`` makes α and m_f actuator faults the engine feels (the closed loops
    react). ``omega_signals`` replaces the ω case's signals (:class:`Setup`)."""
    if kind not in ("recorded", "physical"):
        raise ValueError(f"kind must be 'recorded' or 'physical', got {kind!r}")
    signals, gain = CASES[case]
    if case == "omega" and omega_signals is not None:
        signals = tuple(omega_signals)
    k = "sensor" if kind == "recorded" else None
    return [EngineFault(s, gain, onset, kind=k) for s in signals]


def regressors(df: pd.DataFrame, model: str) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Regression matrix of eqs. 7–11 for ``model`` from the columns of ``df``, its target and
    the output lags (per input the lag if it is the model's own output, else 0)."""
    out, inputs = MODELS[model]
    X = np.column_stack([df[col].shift(lag).to_numpy(float) for col, lag in inputs])
    lags = [lag if col == out else 0 for col, lag in inputs]
    return X, df[out].to_numpy(float), lags


def new_estimator(
    method: str, output_lags: Sequence[int], random_state: int = 0, weight_power: float = 2.0
) -> Any:
    """An untrained estimator: ``ts-fcm`` with the seed's N = 10, m = 2, ε = 0.01 (§III) and
    its consequents weighted by μ^``weight_power`` (2: eq. 24, 1: eq. 23), ``narmax2``
    (eq. 12) or ``wm-avg``."""
    if method == "ts-fcm":
        from diag_plugin.fuzzy.ts_fcm import TakagiSugenoRegressor

        return TakagiSugenoRegressor(
            n_clusters=10,
            m=2.0,
            eps=0.01,
            random_state=random_state,
            weight_power=weight_power,
            output_lags=output_lags,
        )
    if method == "narmax2":
        from diag_plugin.models.narmax import Narmax2Regressor

        return Narmax2Regressor(output_lags=output_lags)
    if method == "wm-avg":
        from diag_plugin.fuzzy.wang_mendel import WangMendelRegressor

        # the fine grid alone (no coarser levels behind it), as the experiment was designed and
        # documented (docs/explanation/engine.md): its thresholds are learned on the models'
        # own residuals
        return WangMendelRegressor(n_sets=9, output_sets=31, method="wm-avg", levels=0)
    raise ValueError(f"unknown method {method!r} (known: {', '.join(FDI_METHODS)})")


def _with_estimates(X: np.ndarray, lags: Sequence[int], yhat: np.ndarray) -> np.ndarray:
    """``X`` with each own-lag column replaced by the estimate ``yhat`` that many rows earlier
    (measured where there is no estimate yet)."""
    X = X.copy()
    for j, d in enumerate(lags):
        if d > 0:
            est = np.r_[np.full(d, np.nan), yhat[:-d]]
            X[:, j] = np.where(np.isfinite(est), est, X[:, j])
    return X


def _fit_one(
    method: str, X: np.ndarray, y: np.ndarray, lags: list[int], refits: int, **opts: Any
) -> Any:
    """Fit on measured lags, then ``refits`` times on the previous fit's own estimates in the
    lag columns (the seed's ŷ(k−1..3), eqs. 7–11); keep the fit whose free run is closest to
    the training data (a model trained on measured lags may lean on y(k−1) and drift when
    fed its own output)."""
    model = new_estimator(method, lags, **opts).fit(X, y)
    if not getattr(model.capabilities, "free_run", False):
        return model
    best, best_sse = model, float("inf")
    for i in range(refits + 1):
        sim = model.simulate(X)
        e = (sim - y)[np.isfinite(sim)]
        if e.size and float(e @ e) < best_sse:
            best, best_sse = model, float(e @ e)
        if i < refits:
            model = new_estimator(method, lags, **opts).fit(_with_estimates(X, lags, sim), y)
    return best


def identify(
    train: pd.DataFrame, method: str = "ts-fcm", refits: int = 2, weight_power: float = 2.0
) -> EngineModels:
    """Identify the five models of eqs. 7–11 on fault-free data (Laukonen et al. §III): see
    :func:`_fit_one`; the ω and m_a models (eqs. 7–8) are trained with T̂_L, the free run of
    the load-torque model (eq. 11), in place of T_L where the method can simulate.
    ``weight_power``: ts-fcm's consequent weights μ^p (2: eq. 24, 1: eq. 23)."""
    models, secs = {}, {}
    fed = train
    for name in ("T_L", *RESIDUALS):
        X, y, lags = regressors(fed, name)
        t0 = time.perf_counter()
        models[name] = _fit_one(method, X, y, lags, refits, weight_power=weight_power)
        secs[name] = time.perf_counter() - t0
        if name == "T_L" and getattr(models[name].capabilities, "free_run", False):
            est = models[name].simulate(X)
            fed = train.assign(T_L=np.where(np.isfinite(est), est, train["T_L"]))
    return EngineModels(method, {k: models[k] for k in MODELS}, secs)


def free_runs(em: EngineModels) -> bool:
    """Whether the estimates are free run (the seed's ω̂(k−1), …, T̂_L): the method simulates
    its own lags and ``em.one_step`` is off."""
    can = all(getattr(m.capabilities, "free_run", False) for m in em.models.values())
    return can and not em.one_step


def _estimate(model: Any, X: np.ndarray, free: bool) -> np.ndarray:
    return model.simulate(X) if free else model.extrapolate(X)


def estimates(em: EngineModels, df: pd.DataFrame) -> pd.DataFrame:
    """Estimates ω̂, m̂_a, α̂, m̂_f, T̂_L over a run (eqs. 2–6): free run where the method can
    (:func:`free_runs`), with T̂_L in place of T_L in eqs. 7–8; else one step ahead on measured
    data (measured lags and the measured T_L)."""
    free = free_runs(em)
    X, _, _ = regressors(df, "T_L")
    out = {"T_L": _estimate(em.models["T_L"], X, free)}
    fed = df.assign(T_L=np.where(np.isfinite(out["T_L"]), out["T_L"], df["T_L"])) if free else df
    for name in RESIDUALS:
        X, _, _ = regressors(fed, name)
        out[name] = _estimate(em.models[name], X, free)
    return pd.DataFrame(out, index=df.index)[[*RESIDUALS, "T_L"]]


def residuals(em: EngineModels, df: pd.DataFrame, scaler: MaxScaler) -> pd.DataFrame:
    """Filtered, scaled residuals ``ŷ − y`` (§IV: Butterworth 4th order at π/100, divided by
    the signal maximum over a fault-free cycle) of :data:`SIGNALS`: Table II's four and
    T̂_L − T_L (``scaler`` fitted on the five signals). NaN warm-up rows count as zero."""
    est = estimates(em, df)[list(SIGNALS)]
    raw = (est - df[list(SIGNALS)]).fillna(0.0)
    return scaler.transform(LowPass(wn=0.01, order=4).transform(raw))


def _window(df: pd.DataFrame, window: tuple[int, int]) -> pd.DataFrame:
    rev = df["rev"].to_numpy() if "rev" in df else np.arange(len(df))
    return df[(rev >= window[0]) & (rev < window[1])]


def isolate(
    latched: pd.DataFrame,
    onset_time: pd.Timestamp,
    min_certainty: float = 0.75,
    table: Mapping[str, Sequence[str]] = TABLE_II,
) -> tuple[str, float, bool]:
    """Isolation by Table II (``table``: :data:`TABLE_II` as printed, the default, or derived)
    over latched symptoms (§IV): the exact match at the end of the
    window, else the nearest signature — fewest constrained residuals that do not fit — if it
    is the only one that near and its certainty (share of its constrained residuals that fit)
    is at least ``min_certainty``, else ``"unknown"`` (detected, not isolated). A tie is no
    isolation: in the printed table the ω, α and m_f signatures are two residuals apart and
    m_a's is one from each (its don't care), so a pattern one residual off one signature is as
    near another; in the derived one ω and m_f differ in m̂_a − m_a alone. Time: from the onset
    to the first sample from which the decision holds to the end. Returns ``(fault, "unknown"
    or "none"; seconds or NaN; exact)``."""
    m = table_ii(table)
    s = latched[list(RESIDUALS)].to_numpy(float)
    if not len(s):
        return "none", float("nan"), True
    match = m.match(s).matched
    exact = match.sum(axis=1) == 1
    sig = np.array([[np.nan if v == "x" else float(v) for v in table[f]] for f in m.faults])
    rel = np.isfinite(sig)[None, :, :] & np.isfinite(s)[:, None, :]  # samples × faults × tests
    miss = (rel & (s[:, None, :] != sig[None, :, :])).sum(axis=2)
    n_rel = rel.sum(axis=2)
    best, best_miss = miss.argmin(axis=1), miss.min(axis=1)
    unique = (miss == best_miss[:, None]).sum(axis=1) == 1
    with np.errstate(invalid="ignore", divide="ignore"):
        cert = 1.0 - best_miss / np.take_along_axis(n_rel, best[:, None], axis=1)[:, 0]
    ok_near = unique & (np.nan_to_num(cert, nan=0.0) >= min_certainty)
    detected = (np.nan_to_num(s) != 0).any(axis=1)
    decision = np.where(exact, match.argmax(axis=1), np.where(ok_near, best, -1))
    decision = np.where(detected, np.where(decision < 0, -2, decision), -1)  # -2: unknown
    last = int(decision[-1])
    if last == -1:
        return "none", float("nan"), True
    differ = np.flatnonzero(decision != last)
    first = int(differ[-1]) + 1 if differ.size else 0
    seconds = (latched.index[first] - onset_time).total_seconds()
    name = "unknown" if last == -2 else m.faults[last]
    return name, float(seconds), bool(exact[-1])


def run_case(
    em: EngineModels,
    case: str,
    *,
    seed: int,
    scaler: MaxScaler,
    thresholds: pd.Series,
    onset: int = WINDOW[0],
    window: tuple[int, int] = WINDOW,
    kind: str = "recorded",
    keep_residuals: bool = False,
    table: Mapping[str, Sequence[str]] = TABLE_II,
    setup: Setup = Setup(),
) -> dict[str, Any]:
    """One test (§IV, Figs. 8–12): simulate the case, residuals, thresholds, latch, isolate
    (by ``table``; ``"isolated_by"`` also names the isolation by every table of
    :data:`MATRICES`, from the same latched residuals).
    Per residual its peak |r| over the window and the revolution it latched at (None: never);
    with ``keep_residuals`` also ``"residuals"``, the window's frame of :data:`SIGNALS` and
    ``rev`` (for :func:`plot_residuals`). ``setup``: the run's departures (:class:`Setup`)."""
    df = setup.simulate(window[1], seed, fault_case(case, onset, kind, setup.omega_signals))
    full = _window(residuals(em, df, scaler).assign(rev=df["rev"]), window)
    r = full[list(RESIDUALS)]
    latched = Latch(thresholds).transform(r)
    t_onset = df.index[df["rev"] == onset][0]
    fault, secs, exact = isolate(latched, t_onset, table=table)
    by = {name: isolate(latched, t_onset, table=t) for name, t in MATRICES.items()}
    on = latched.to_numpy() == 1.0
    revs = full["rev"].to_numpy()
    out = {
        "injected": case,
        "isolated": fault,
        "time_s": None if np.isnan(secs) else round(secs, 3),
        "exact": exact,
        "isolated_by": {name: {"isolated": f, "exact": e} for name, (f, _, e) in by.items()},
        "peak": {c: round(float(r[c].abs().max()), 4) for c in RESIDUALS},
        "latched_rev": {
            c: int(revs[on[:, j].argmax()]) if on[:, j].any() else None
            for j, c in enumerate(RESIDUALS)
        },
    }
    if keep_residuals:
        out["residuals"] = full
    return out


def validation_errors(em: EngineModels, val: pd.DataFrame) -> dict[str, dict[str, float]]:
    """Per model, Figs. 3–7: the sum of squared errors Σe² over the validation run and the RMSE
    in % of the signal's range, of the estimates the FDI uses (free run where it can)."""
    est = estimates(em, val)
    out = {}
    for name in MODELS:
        e = (est[name] - val[name]).to_numpy(float)[10:]
        e = e[np.isfinite(e)]
        span = float(val[name].max() - val[name].min())
        out[name] = {
            "sse": float(e @ e),
            "rmse_pct": float(100 * np.sqrt(np.mean(e**2)) / span),
            "fit_s": round(em.fit_seconds[name], 3),
        }
    return out


def matching_window(
    frames: Sequence[pd.DataFrame], length: int = WINDOW[1] - WINDOW[0], step: int = 250
) -> tuple[int, int]:
    """The test window where "the best model matching occurred" (§IV, the seed's reason for
    revolutions 3000–5000): of the windows of ``length`` revolutions starting on a ``step``
    grid, the one with the smallest sum over Table II's residuals of the largest |filtered,
    scaled residual| over the fault-free runs ``frames`` (:func:`residuals` with ``rev``).
    Chosen on fault-free data only, before any fault is seen."""
    last = min(int(f["rev"].max()) for f in frames) + 1
    best, best_score = None, float("inf")
    for a in range(0, last - length + 1, step):
        w = (a, a + length)
        peak = pd.concat([_window(f, w)[list(RESIDUALS)] for f in frames]).abs().max()
        if float(peak.sum()) < best_score:
            best, best_score = w, float(peak.sum())
    if best is None:
        raise ValueError(f"runs of {last} revolutions hold no window of {length}")
    return best


def learn_thresholds(
    em: EngineModels,
    clean: Sequence[pd.DataFrame],
    scaler: MaxScaler,
    window: tuple[int, int] = WINDOW,
) -> pd.Series:
    """Thresholds from fault-free runs (§IV, Table III: "computed empirically by analyzing the
    deviation of the residuals from zero during no fault operation"): the largest |r| in the
    test window over all the runs, times 1.5 (:class:`LearnedThresholds`, quantile 1)."""
    parts = [
        _window(residuals(em, df, scaler).assign(rev=df["rev"]), window)[list(RESIDUALS)]
        for df in clean
    ]
    return LearnedThresholds(quantile=1.0, margin=1.5).fit(pd.concat(parts)).thresholds_


def run_fdi(
    seed: int = 0,
    method: str = "ts-fcm",
    *,
    cases: Sequence[str] = tuple(CASES),
    n_rev: int = N_REV,
    window: tuple[int, int] = WINDOW,
    kind: str = "recorded",
    n_clean: int = 4,
    keep_residuals: bool = False,
    one_step: bool = False,
    matrix: str = DEFAULT_MATRIX,
    weight_power: float = 2.0,
    setup: Setup = Setup(),
) -> dict[str, Any]:
    """The seed's whole experiment (§§III–IV) for one seed: identification on a fault-free run
    (simulator seed ``seed``), scaling from a second fault-free run (``seed + 1000``),
    thresholds over it and ``n_clean − 1`` more (``seed + 1001``, …; the seed's "similar tests
    run on different days": with two runs, narmax2's tight free-run m_f thresholds were crossed
    without a fault on the test run of seeds 3 and 17), each case on a third run
    (``seed + 2000``) with the fault from the start of the test window. Returns
    ``{"method", "seed", "fault_kind", "residual_mode", "matrix", "thresholds", "validation",
    "cases"}``; ``keep_residuals`` keeps each case's residual frame (:func:`run_case`);
    ``one_step`` computes every residual one step ahead (:class:`EngineModels`), not the seed's
    free run; ``matrix`` names the Table II to isolate by (:data:`MATRICES`: ``"printed"``, the
    default, or ``"derived"`` from eqs. 7–11); each case also carries ``"isolated_by"``, its
    isolation by both. ``weight_power``: ts-fcm's consequent weights μ^p (2: eq. 24, the
    default; 1: eq. 23). ``setup``: the leads of docs/explanation/engine.md (:class:`Setup`).
    """
    if matrix not in MATRICES:
        raise ValueError(f"matrix must be one of {', '.join(MATRICES)}, got {matrix!r}")
    if setup.window not in ("seed", "matching"):
        raise ValueError(f"window must be 'seed' or 'matching', got {setup.window!r}")
    train = setup.simulate(n_rev, seed)
    em = identify(train, method, weight_power=weight_power)
    em.one_step = one_step
    clean = setup.simulate(n_rev, seed + 1000)
    scaler = MaxScaler().fit(clean[list(SIGNALS)])
    matching = setup.window == "matching"
    more_rev = n_rev if matching else window[1]
    more = [setup.simulate(more_rev, seed + 1000 + i) for i in range(1, n_clean)]
    if matching:
        frames = [residuals(em, c, scaler).assign(rev=c["rev"]) for c in (clean, *more)]
        window = matching_window(frames, window[1] - window[0])
    thr = learn_thresholds(em, [clean, *more], scaler, window)
    if setup.table_iii:
        thr = pd.Series(TABLE_III)[list(RESIDUALS)]
    results = [
        run_case(
            em,
            c,
            seed=seed + 2000,
            scaler=scaler,
            thresholds=thr,
            onset=window[0],
            window=window,
            kind=kind,
            keep_residuals=keep_residuals,
            table=MATRICES[matrix],
            setup=setup,
        )
        for c in cases
    ]
    return {
        "method": method,
        "seed": seed,
        "fault_kind": kind,
        "residual_mode": "free run" if free_runs(em) else "one step ahead",
        "matrix": matrix,
        "weight_power": weight_power,
        "window": list(window),
        "thresholds": {k: round(float(v), 4) for k, v in thr.items()},
        "validation": validation_errors(em, clean),
        "cases": results,
    }


def compare_methods(
    seed: int = 0,
    methods: Sequence[str] = FDI_METHODS,
    n_rev: int = N_REV,
    *,
    weight_power: float = 2.0,
    one_step: bool = False,
    setup: Setup = Setup(),
) -> dict[str, dict[str, dict[str, float]]]:
    """Figs. 3–7 for every method: identify on run ``seed``, validate on ``seed + 1000``
    (free run where the method can, unless ``one_step``; ts-fcm's consequents weighted by
    μ^``weight_power``; the runs as ``setup`` makes them, e.g. in volts as the seed's
    figures)."""
    train = setup.simulate(n_rev, seed)
    val = setup.simulate(n_rev, seed + 1000)
    out = {}
    for m in methods:
        em = identify(train, m, weight_power=weight_power)
        em.one_step = one_step
        out[m] = validation_errors(em, val)
    return out


#: the seed's figure per case (Figs. 8–12) and a readable name
FIGURES: dict[str, tuple[int, str]] = {
    "none": (8, "no fault"),
    "alpha": (9, "20 % throttle (α) calibration fault"),
    "m_a": (10, "20 % mass air (m_a) calibration fault"),
    "m_f": (11, "40 % mass fuel (m_f) calibration fault"),
    "omega": (12, "20 % engine speed (ω) calibration fault"),
}

_PANEL_TITLES = {
    "omega": "ω̂ − ω (eq. 7)",
    "m_a": "m̂_a − m_a (eq. 8)",
    "alpha": "α̂ − α (eq. 9)",
    "m_f": "m̂_f − m_f (eq. 10)",
    "T_L": "T̂_L − T_L (eq. 11; feeds eqs. 7–8, not in Table II)",
}


def plot_residuals(res: dict[str, Any], outdir: str | Any) -> list[Any]:
    """Residual plots like the seed's Figs. 8–12 from a :func:`run_fdi` result with
    ``keep_residuals=True``: one SVG per case, ``{method}-seed{seed}-fig{n}-{case}.svg`` in
    ``outdir``, one panel per model (eqs. 7–11): the filtered, scaled residual over revolutions
    (§IV), the no-fault case's in grey behind a fault's, ± the learned threshold (our Table
    III), ± the seed's Table III value for reference, and the revolution each Table II residual
    latched. Residuals one step ahead add ``-one-step`` to the method in the name. Returns the
    paths written."""
    from pathlib import Path

    from diag_plugin.engine import svgplot as sp

    out = Path(outdir)
    out.mkdir(parents=True, exist_ok=True)
    by_case = {c["injected"]: c for c in res["cases"]}
    base = by_case.get("none", {}).get("residuals")
    paths = []
    for case, c in by_case.items():
        r = c["residuals"]
        rev = r["rev"].to_numpy(float)
        panels = []
        for k in SIGNALS:
            traces = []
            if base is not None and case != "none":
                traces.append(
                    sp.Trace(base["rev"], base[k], "no fault", color="#b0b0b0", width=1.0)
                )
            traces.append(sp.Trace(rev, r[k], FIGURES[case][1]))
            hlines, vlines = [], []
            if k in RESIDUALS:
                thr = float(res["thresholds"][k])
                hlines += [sp.HLine(v, "learned threshold ±") for v in (thr, -thr)]
                hlines += [
                    sp.HLine(
                        v,
                        "seed's Table III ± (its scaling)",
                        color="#888",
                        dash="1 3",
                        autoscale=False,
                    )
                    for v in (TABLE_III[k], -TABLE_III[k])
                ]
                if c["latched_rev"][k] is not None:
                    vlines.append(sp.VLine(c["latched_rev"][k], "latched"))
            panels.append(sp.Panel(_PANEL_TITLES[k], traces, hlines, vlines))
        n, name = FIGURES[case]
        title = (
            f"Residuals with {name} (like seed Fig. {n}): {res['method']} "
            f"({res['residual_mode']}), seed {res['seed']}, "
            f"Table II {res.get('matrix', DEFAULT_MATRIX)}, isolated: {c['isolated']}"
        )
        svg = sp.figure(
            panels,
            title=title,
            xlabel=f"engine revolution (fault from {res.get('window', WINDOW)[0]})",
            xlim=(float(rev[0]), float(rev[-1])),
            note="filtered (4th-order Butterworth, π/100) residual ŷ − y divided by the "
            "signal's maximum over a fault-free cycle (dimensionless)",
        )
        mode = "" if res["residual_mode"] == "free run" else "-one-step"
        path = out / f"{res['method']}{mode}-seed{res['seed']}-fig{n}-{case}.svg"
        path.write_text(svg, encoding="utf-8")
        paths.append(path)
    return paths


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m diag_plugin.engine.fdi --plot DIR [--seed N] [--method M] [--matrix T]``: run
    the experiment and write the residual plots (Figs. 8–12) as SVG files."""
    import argparse

    ap = argparse.ArgumentParser(prog="python -m diag_plugin.engine.fdi")
    ap.add_argument("--plot", required=True, metavar="DIR", help="folder for the SVG files")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--method", choices=FDI_METHODS, default="ts-fcm")
    ap.add_argument("--faults", choices=("recorded", "physical"), default="recorded")
    ap.add_argument(
        "--one-step",
        action="store_true",
        help="residuals one step ahead on measured data (not the seed's free run)",
    )
    ap.add_argument("--matrix", choices=tuple(MATRICES), default=DEFAULT_MATRIX)
    args = ap.parse_args(argv)
    res = run_fdi(
        args.seed,
        args.method,
        kind=args.faults,
        keep_residuals=True,
        one_step=args.one_step,
        matrix=args.matrix,
    )
    for p in plot_residuals(res, args.plot):
        print(p)
    for c in res["cases"]:
        print(f"{c['injected']:6} -> {c['isolated']:8} peaks {c['peak']}")
    print("thresholds", res["thresholds"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
