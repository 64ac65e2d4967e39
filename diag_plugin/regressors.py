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
def _direction(x: np.ndarray, threshold: float) -> np.ndarray:  # pragma: no cover - compiled
    out = np.empty(x.shape[0])
    ref = np.nan
    state = np.nan
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
    return out


def direction(x: np.ndarray, threshold: float) -> np.ndarray:
    """Direction of the last move larger than ``threshold``: +1 up, −1 down.

    A backlash/hysteresis play operator: the reference follows the signal only
    once it has moved by more than the threshold. NaN until the first move
    and after a gap (the direction is unknown then).
    """
    return _direction(np.ascontiguousarray(x, dtype=np.float64), float(threshold))


def feature(
    frame: pd.DataFrame, spec: InputSpec, spans: Mapping[str, tuple[float, float]] | None = None
) -> np.ndarray:
    """Unlagged values of one spec over the frame (NaN where undefined)."""
    for t in spec.tags:
        if t not in frame.columns:
            raise KeyError(f"tag {t!r} (needed by {spec}) is not in the data")
    if spec.fn == "":
        return frame[spec.tags[0]].to_numpy(dtype=float)
    if spec.fn == "diff":
        return frame[spec.tags[0]].to_numpy(float) - frame[spec.tags[1]].to_numpy(float)
    if spec.fn == "rate":
        x = frame[spec.tags[0]].to_numpy(float)
        return np.r_[np.nan, np.diff(x)]
    if spec.fn == "dir":
        x = frame[spec.tags[0]].to_numpy(float)
        th = spec.param
        if th is None:
            lo, hi = (spans or {}).get(spec.tags[0]) or (np.nanmin(x), np.nanmax(x))
            th = DIR_THRESHOLD_SHARE * (hi - lo)
        return direction(x, th)
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


def build_design(
    frame: pd.DataFrame,
    inputs: Sequence[str | InputSpec],
    output: str | InputSpec | None = None,
    *,
    quality: pd.DataFrame | None = None,
    spans: Mapping[str, tuple[float, float]] | None = None,
    context: int = 0,
) -> Design:
    """Lagged design matrix from a timestamp-indexed frame (Kościelny et al., eqs. 7–9).

    Rows where any needed value is NaN, of bad quality (``quality`` non-zero,
    same shape as ``frame``), or before the history the lags need, are
    dropped and counted per reason (a row missing two tags counts under both).
    The first ``context`` rows are history only (the tail of the previous
    chunk): they feed the lags but are neither returned nor counted.
    """
    check_regular(frame.index)
    specs = parse_specs(inputs)
    out_spec = None if output is None else parse_specs([output])[0]
    if quality is not None:
        bad = quality.reindex(index=frame.index, columns=frame.columns).fillna(0).to_numpy() != 0
        frame = frame.mask(bad)
    n = len(frame)
    all_specs = specs + ([out_spec] if out_spec is not None else [])
    cols = []
    cache: dict[str, np.ndarray] = {}
    for s in all_specs:
        base = s.base
        if base not in cache:
            cache[base] = feature(frame, s, spans)
        v = cache[base]
        if s.lag:
            v = np.r_[np.full(min(s.lag, n), np.nan), v[: max(n - s.lag, 0)]]
        cols.append(v)
    M = np.column_stack(cols) if cols else np.empty((n, 0))
    ok = ~np.isnan(M).any(axis=1)
    is_ctx = np.zeros(n, bool)
    is_ctx[: min(context, n)] = True
    dropped: dict[str, int] = {}
    warm = max_lag(all_specs)
    in_warmup = np.zeros(n, bool)
    in_warmup[: min(warm, n)] = True
    in_warmup &= ~is_ctx
    if in_warmup.any():
        dropped["history for the lags"] = int(in_warmup.sum())
    attributed = in_warmup | is_ctx
    for tag in needed_tags(all_specs):
        raw = frame[tag].isna().to_numpy()
        miss = np.zeros(n, bool)
        for s in all_specs:
            if tag in s.tags and s.lag < n:
                miss[s.lag :] |= raw[: n - s.lag]
        miss &= ~ok & ~attributed
        if miss.any():
            dropped[f"{tag} missing or bad"] = int(miss.sum())
            attributed |= miss
    other = int((~ok & ~attributed).sum())
    if other > 0:
        dropped["derived value undefined"] = other
    ok &= ~is_ctx
    Mok = M[ok]
    d = len(specs)
    return Design(
        X=np.ascontiguousarray(Mok[:, :d]),
        y=Mok[:, d].copy() if out_spec is not None else None,
        index=pd.DatetimeIndex(frame.index[ok]),
        inputs=[str(s) for s in specs],
        output=None if out_spec is None else str(out_spec),
        n_rows=n - int(is_ctx.sum()),
        dropped=dropped,
    )
