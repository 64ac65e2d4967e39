"""Input specs and lagged design matrices.

A model input is written as a *spec* (Kościelny et al., eqs. 7–9:
``F_k = f(U_{k-1}, P_k)`` is output ``F[k]`` with inputs ``U[k-1]``, ``P[k]``):

==================  ==========================================================
``TAG[k]``          the tag at the current sample
``TAG[k-d]``        the tag ``d`` samples earlier (dead time, dynamics)
``diff(A,B)[k-d]``  ``A − B``, e.g. the pressure drop ``diff(P1,P2)[k]``
``rate(TAG)[k-d]``  change per sample ``TAG[k] − TAG[k-1]``
``dir(TAG)[k-d]``   direction of the last significant move of TAG: +1, −1
                    (hysteresis, backlash); ``dir(TAG,0.5)`` sets the move
                    threshold in engineering units (default 0.5 % of the
                    tag's span)
``hour()[k]``       time of day in hours (0–24, UTC)
``days()[k]``       time in days since 2000-01-01 (slow drift)
==================  ==========================================================

Frames are pandas DataFrames indexed by a regular timestamp grid, one column
per tag (the historian's aligned window); lags count grid samples.
"""

from __future__ import annotations

import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numba as nb
import numpy as np
import pandas as pd

_SPEC = re.compile(
    r"^\s*(?:(?P<fn>[a-z]+)\((?P<args>[^()]*)\)|(?P<tag>[A-Za-z_][A-Za-z0-9_.:/-]*))"
    r"\s*\[\s*k\s*(?:-\s*(?P<lag>\d+)\s*)?\]\s*$"
)
FUNCTIONS = {"diff": 2, "rate": 1, "dir": 1, "hour": 0, "days": 0}
EPOCH = pd.Timestamp("2000-01-01", tz="UTC")
#: default move threshold of dir(): this share of the tag's span
DIR_THRESHOLD_SHARE = 0.005


@dataclass(frozen=True)
class InputSpec:
    """A parsed input spec: function (``""`` for a plain tag), tags, lag, parameter."""

    fn: str
    tags: tuple[str, ...]
    lag: int = 0
    param: float | None = None

    @classmethod
    def parse(cls, text: str) -> InputSpec:
        m = _SPEC.match(text)
        if not m:
            raise ValueError(
                f"bad input spec {text!r}: expected TAG[k], TAG[k-d] or FN(ARGS)[k-d], "
                "e.g. CV[k-1], diff(P1,P2)[k], dir(CV)[k-1]"
            )
        lag = int(m["lag"] or 0)
        if m["tag"]:
            return cls("", (m["tag"],), lag)
        fn = m["fn"]
        if fn not in FUNCTIONS:
            raise ValueError(
                f"bad input spec {text!r}: unknown function {fn!r} (known: {', '.join(FUNCTIONS)})"
            )
        args = [a.strip() for a in m["args"].split(",")] if m["args"].strip() else []
        param = None
        if fn == "dir" and len(args) == 2:
            try:
                param = float(args.pop())
            except ValueError:
                raise ValueError(f"bad input spec {text!r}: threshold must be a number") from None
        if len(args) != FUNCTIONS[fn]:
            raise ValueError(f"bad input spec {text!r}: {fn}() takes {FUNCTIONS[fn]} tag(s)")
        for a in args:
            if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.:/-]*", a):
                raise ValueError(f"bad input spec {text!r}: {a!r} is not a tag name")
        return cls(fn, tuple(args), lag, param)

    def __str__(self) -> str:
        lag = f"[k-{self.lag}]" if self.lag else "[k]"
        if not self.fn:
            return f"{self.tags[0]}{lag}"
        args = list(self.tags) + ([_fmt_num(self.param)] if self.param is not None else [])
        return f"{self.fn}({','.join(args)}){lag}"

    @property
    def base(self) -> str:
        """The spec without its lag, e.g. ``CV`` or ``dir(CV)``."""
        return str(self.with_lag(0))[: -len("[k]")]

    def with_lag(self, lag: int) -> InputSpec:
        return InputSpec(self.fn, self.tags, lag, self.param)


def _fmt_num(v: float) -> str:
    return f"{v:g}"


def parse_specs(specs: Sequence[str | InputSpec]) -> list[InputSpec]:
    return [s if isinstance(s, InputSpec) else InputSpec.parse(s) for s in specs]


def needed_tags(specs: Sequence[str | InputSpec]) -> list[str]:
    """Tags a set of specs reads, in first-use order."""
    out: dict[str, None] = {}
    for s in parse_specs(specs):
        for t in s.tags:
            out[t] = None
    return list(out)


def max_lag(specs: Sequence[str | InputSpec]) -> int:
    """Samples of history the specs need (rate() needs one more)."""
    return max(
        (s.lag + (1 if s.fn == "rate" else 0) for s in parse_specs(specs)),
        default=0,
    )


def dir_threshold(
    tag: str, spans: Mapping[str, tuple[float, float]], frame: pd.DataFrame | None
) -> float:
    """Move threshold of ``dir(TAG)``: 0.5 % of the tag's span (nominal, else observed).

    Written into the spec (``dir(CV,0.5)``) so training, inference and the
    live plug-in use the same value.
    """
    if tag in spans:
        lo, hi = spans[tag]
    elif frame is None:
        raise ValueError(f"no span known for {tag}: give dir() a threshold, e.g. dir({tag},0.5)")
    else:
        v = frame[tag].to_numpy(float)
        lo, hi = np.nanmin(v), np.nanmax(v)
    return float(f"{DIR_THRESHOLD_SHARE * (hi - lo):.3g}")


@nb.njit(cache=True)
def _direction(x, threshold, carry):  # pragma: no cover - compiled
    out = np.empty(x.shape[0])
    ref = carry[0]
    state = carry[1]
    for i in range(x.shape[0]):
        v = x[i]
        if np.isnan(v):
            out[i] = np.nan
            ref = np.nan
            state = np.nan
            continue
        if np.isnan(ref):
            ref = v
        elif v - ref > threshold:
            state = 1.0
            ref = v
        elif ref - v > threshold:
            state = -1.0
            ref = v
        out[i] = state
    carry[0] = ref
    carry[1] = state
    return out


def direction(x: np.ndarray, threshold: float, carry: np.ndarray | None = None) -> np.ndarray:
    """Direction of the last move larger than ``threshold``: +1 up, −1 down.

    A backlash/hysteresis play operator: the reference follows the signal only
    once it has moved by more than the threshold. NaN until the first move
    and after a gap (the direction is unknown then). ``carry`` (reference,
    direction), NaN for a fresh start, is read and updated in place, so a
    signal fed in pieces gives the same values as one pass.
    """
    if carry is None:
        carry = np.full(2, np.nan)
    return _direction(np.ascontiguousarray(x, dtype=np.float64), float(threshold), carry)


def feature(
    frame: pd.DataFrame, spec: InputSpec, spans: Mapping[str, tuple[float, float]] | None = None
) -> np.ndarray:
    """Unlagged values of one spec over the frame (NaN where undefined), from a fresh start."""
    return _FeatureState(spec, spans).compute(frame)


class _FeatureState:
    """One unlagged feature (a spec's base) with the state it carries between pieces.

    Plain tags, differences and clock features need none; ``rate`` carries the
    previous sample of its tag, ``dir`` its play-operator reference and
    direction (unbounded memory: a valve that holds still for days keeps its
    last direction).
    """

    def __init__(self, spec: InputSpec, spans: Mapping[str, tuple[float, float]] | None):
        self.spec = spec.with_lag(0)
        self.threshold = spec.param
        if spec.fn == "dir" and spec.param is None and spec.tags[0] in (spans or {}):
            lo, hi = spans[spec.tags[0]]
            self.threshold = DIR_THRESHOLD_SHARE * (hi - lo)
        self.carry = np.full(2, np.nan)  # rate: (previous sample, –); dir: (reference, dir)

    def compute(self, frame: pd.DataFrame) -> np.ndarray:
        spec = self.spec
        for t in spec.tags:
            if t not in frame.columns:
                raise KeyError(f"tag {t!r} (needed by {spec}) is not in the data")
        if spec.fn == "":
            return frame[spec.tags[0]].to_numpy(dtype=float)
        if spec.fn == "diff":
            return frame[spec.tags[0]].to_numpy(float) - frame[spec.tags[1]].to_numpy(float)
        if spec.fn == "rate":
            x = frame[spec.tags[0]].to_numpy(float)
            out = np.diff(x, prepend=self.carry[0]) if x.size else x
            if x.size:
                self.carry[0] = x[-1]
            return out
        if spec.fn == "dir":
            x = frame[spec.tags[0]].to_numpy(float)
            if self.threshold is None:  # frozen at the first piece: the same for all pieces
                v = x[np.isfinite(x)]
                self.threshold = DIR_THRESHOLD_SHARE * float(np.ptp(v)) if v.size else 0.0
            return direction(x, self.threshold, self.carry)
        idx = pd.DatetimeIndex(frame.index)
        if idx.tz is None:
            idx = idx.tz_localize("UTC")
        if spec.fn == "hour":
            return ((idx - idx.normalize()) / pd.Timedelta(hours=1)).to_numpy(float)
        if spec.fn == "days":
            return ((idx - EPOCH) / pd.Timedelta(days=1)).to_numpy(float)
        raise AssertionError(spec.fn)


@dataclass
class Design:
    """A design matrix ready for a model.

    ``X`` (rows × inputs) and ``y`` hold only complete rows; ``index`` their
    timestamps; ``dropped`` counts the rows left out and why.
    """

    X: np.ndarray
    y: np.ndarray | None
    index: pd.DatetimeIndex
    inputs: list[str]
    output: str | None
    n_rows: int
    dropped: dict[str, int] = field(default_factory=dict)

    @property
    def n_dropped(self) -> int:
        return self.n_rows - len(self.index)


def check_regular(index: pd.Index) -> None:
    """Lags count samples, so the frame must sit on a regular time grid."""
    if len(index) > 2:
        d = np.diff(np.asarray(index, dtype="datetime64[ns]").astype(np.int64))
        bad = np.flatnonzero((d != d[0]) | (d <= 0))
        if bad.size:
            raise ValueError(
                f"data are not on a regular, increasing time grid at {index[bad[0] + 1]} "
                f"(after {index[bad[0]]}; lags count samples): align them first, "
                "e.g. with the historian's window()"
            )


class DesignBuilder:
    """Design matrices from consecutive pieces of one time series of frames.

    Every derived feature's state (``dir`` direction, ``rate``'s previous
    sample) and the recent history the lags need are carried from piece to
    piece, so training chunk by chunk, validating after training and the live
    loop cycle by cycle give exactly the rows one pass over all data gives
    (Kościelny et al., eqs. 7–9). :meth:`to_state` / :meth:`load_state` carry
    it between processes as plain numbers (JSON-able).

    Lags count samples of a regular grid, also across pieces: a piece that
    starts later than one ``period`` after the last one (a missed cycle) is
    joined as if the samples in between were missing, exactly as one pass over
    the grid would see them; a piece that starts earlier is an error.
    ``period`` is taken from the first piece of two or more rows if not given.
    """

    def __init__(
        self,
        inputs: Sequence[str | InputSpec],
        output: str | InputSpec | None = None,
        spans: Mapping[str, tuple[float, float]] | None = None,
        period: str | pd.Timedelta | None = None,
    ) -> None:
        self.period = None if period is None else pd.Timedelta(period)
        self.last: pd.Timestamp | None = None
        self.specs = parse_specs(inputs)
        self.out_spec = None if output is None else parse_specs([output])[0]
        self.all_specs = self.specs + ([self.out_spec] if self.out_spec is not None else [])
        self.tags = needed_tags(self.all_specs)
        self.history = max_lag(self.all_specs)
        self.features: dict[str, _FeatureState] = {}
        self.depth: dict[str, int] = {}  # lag history kept per feature
        for s in self.all_specs:
            self.features.setdefault(s.base, _FeatureState(s, spans))
            self.depth[s.base] = max(self.depth.get(s.base, 0), s.lag)
        self.tag_depth = {t: max(s.lag for s in self.all_specs if t in s.tags) for t in self.tags}
        self.tails = {b: np.full(h, np.nan) for b, h in self.depth.items()}
        self.nan_tails = {t: np.zeros(h, bool) for t, h in self.tag_depth.items()}
        self.seen = 0

    @property
    def unbounded(self) -> bool:
        """True when a feature's state depends on all history (``dir``), not just the lags."""
        return any(f.spec.fn == "dir" for f in self.features.values())

    def _columns(self, frame: pd.DataFrame) -> dict[str, np.ndarray]:
        return {b: f.compute(frame) for b, f in self.features.items()}

    def _join(self, index: pd.Index) -> None:
        """Check that a piece continues the last one; a gap counts as missing samples."""
        if not len(index):
            return
        if self.period is None and len(index) > 1:
            self.period = pd.Timedelta(index[1] - index[0])
        first = pd.Timestamp(index[0])
        if self.last is not None and self.period is not None:
            step = (first - self.last) / self.period
            if step < 1 or step != round(step):
                raise ValueError(
                    f"data at {first} do not continue the previous piece (last sample "
                    f"{self.last}, period {self.period}): pieces must follow each other "
                    "on one time grid"
                )
            self._skip(int(round(step)) - 1)
        self.last = pd.Timestamp(index[-1])

    def _skip(self, n: int) -> None:
        """``n`` samples nobody delivered: missing values for the lags, state restarts."""
        if n <= 0:
            return
        for b, f in self.features.items():
            self.tails[b] = _keep_tail(self.tails[b], np.full(min(n, self.tails[b].size), np.nan))
            f.carry[:] = np.nan
        for t in self.tags:
            k = min(n, self.nan_tails[t].size)
            self.nan_tails[t] = _keep_tail(self.nan_tails[t], np.ones(k, bool))
        self.seen += n

    def transform(self, frame: pd.DataFrame, quality: pd.DataFrame | None = None) -> Design:
        """The design matrix of the next piece; rows needing data before the first piece
        ever seen, or a NaN, bad-quality or undefined value, are dropped and counted."""
        check_regular(frame.index)
        missing = [t for t in self.tags if t not in frame.columns]
        if missing:
            raise KeyError(f"tag(s) {', '.join(missing)} needed by the model are not in the data")
        self._join(frame.index)
        if quality is not None:
            bad = quality.reindex(index=frame.index, columns=frame.columns).fillna(0).to_numpy()
            frame = frame.mask(bad != 0)
        n = len(frame)
        feats = self._columns(frame)
        cols = [_lagged(self.tails[s.base], feats[s.base], s.lag) for s in self.all_specs]
        M = np.column_stack(cols) if cols else np.empty((n, 0))
        ok = ~np.isnan(M).any(axis=1)
        pos = self.seen + np.arange(n)
        dropped: dict[str, int] = {}
        attributed = pos < self.history
        if attributed.any():
            dropped["history for the lags"] = int(attributed.sum())
        raw_nan = {}
        for tag in self.tags:
            raw = frame[tag].isna().to_numpy()
            raw_nan[tag] = raw
            miss = np.zeros(n, bool)
            for s in self.all_specs:
                if tag in s.tags:
                    miss |= _lagged(self.nan_tails[tag], raw, s.lag)
            miss &= ~ok & ~attributed
            if miss.any():
                dropped[f"{tag} missing or bad"] = int(miss.sum())
                attributed |= miss
        other = int((~ok & ~attributed).sum())
        if other > 0:
            dropped["derived value undefined"] = other
        for b, v in feats.items():
            self.tails[b] = _keep_tail(self.tails[b], v)
        for t, v in raw_nan.items():
            self.nan_tails[t] = _keep_tail(self.nan_tails[t], v)
        self.seen += n
        Mok = M[ok]
        d = len(self.specs)
        return Design(
            X=np.ascontiguousarray(Mok[:, :d]),
            y=Mok[:, d].copy() if self.out_spec is not None else None,
            index=pd.DatetimeIndex(frame.index[ok]),
            inputs=[str(s) for s in self.specs],
            output=None if self.out_spec is None else str(self.out_spec),
            n_rows=n,
            dropped=dropped,
        )

    def advance(self, frame: pd.DataFrame) -> None:
        """Take a piece as history only (carried state and lags), building no rows."""
        missing = [t for t in self.tags if t not in frame.columns]
        if missing:
            raise KeyError(f"tag(s) {', '.join(missing)} needed by the model are not in the data")
        check_regular(frame.index)
        self._join(frame.index)
        for b, v in self._columns(frame).items():
            self.tails[b] = _keep_tail(self.tails[b], v)
        for t in self.tags:
            self.nan_tails[t] = _keep_tail(self.nan_tails[t], frame[t].isna().to_numpy())
        self.seen += len(frame)

    def prime(self, history: pd.DataFrame) -> None:
        """Take the data just before the first piece as history, without the leading rows
        where every tag is missing (before the data start)."""
        if len(history):
            has = history[self.tags].notna().any(axis=1).to_numpy()
            if has.any():
                self.advance(history.iloc[int(np.argmax(has)) :])

    def to_state(self) -> dict:
        """The carried state as plain numbers and lists (JSON-able)."""
        return {
            "seen": self.seen,
            "last": None if self.last is None else self.last.isoformat(),
            "period": None if self.period is None else str(self.period),
            "features": {
                b: {
                    "tail": _plain(self.tails[b]),
                    "carry": _plain(f.carry),
                    "threshold": f.threshold,
                }
                for b, f in self.features.items()
            },
            "missing": {t: v.astype(int).tolist() for t, v in self.nan_tails.items()},
        }

    def load_state(self, state: Mapping) -> DesignBuilder:
        """Continue from a state of :meth:`to_state` (same specs)."""
        self.seen = int(state["seen"])
        self.last = None if state["last"] is None else pd.Timestamp(state["last"])
        self.period = None if state["period"] is None else pd.Timedelta(state["period"])
        for b, f in self.features.items():
            st = state["features"][b]
            self.tails[b] = np.array(st["tail"], float).reshape(-1)
            f.carry = np.array(st["carry"], float)
            f.threshold = st["threshold"]
        for t in self.tags:
            self.nan_tails[t] = np.array(state["missing"][t], bool).reshape(-1)
        return self


def _plain(v: np.ndarray) -> list:
    return [None if not np.isfinite(x) else float(x) for x in v]


def _lagged(tail: np.ndarray, v: np.ndarray, lag: int) -> np.ndarray:
    """``v`` shifted by ``lag`` samples, the first ``lag`` taken from the carried tail."""
    if lag == 0:
        return v
    return np.concatenate([tail[tail.size - lag :], v])[: v.size]


def _keep_tail(tail: np.ndarray, v: np.ndarray) -> np.ndarray:
    h = tail.size
    if h == 0:
        return tail
    return np.concatenate([tail, v])[-h:]


def build_design(
    frame: pd.DataFrame,
    inputs: Sequence[str | InputSpec],
    output: str | InputSpec | None = None,
    *,
    quality: pd.DataFrame | None = None,
    spans: Mapping[str, tuple[float, float]] | None = None,
) -> Design:
    """Lagged design matrix of one frame taken alone (Kościelny et al., eqs. 7–9).

    Rows where any needed value is NaN, of bad quality (``quality`` non-zero,
    same shape as ``frame``), or before the history the lags need, are
    dropped and counted per reason (a row missing two tags counts under both).
    For consecutive pieces use one :class:`DesignBuilder`.
    """
    return DesignBuilder(inputs, output, spans).transform(frame, quality)
