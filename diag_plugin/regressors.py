"""Input specs and lagged design matrices.

A model input is written as a *spec* (Kościelny et al., eqs. 7–9:
``F_k = f(U_{k-1}, P_k)`` is output ``F[k]`` with inputs ``U[k-1]``, ``P[k]``):

==================  ==========================================================
``TAG[k]``          the tag at the current sample
``TAG[k-d]``        the tag ``d`` samples earlier (dead time, dynamics)
``diff(A,B)[k-d]``  ``A − B``, e.g. the pressure drop ``diff(P1,P2)[k]``
``rate(TAG)[k-d]``  change per sample ``TAG[k] − TAG[k-1]``; ``rate(TAG,L)``
                    over ``L`` samples, ``(TAG[k] − TAG[k-L]) / L`` (a slow
                    tag's rate, judged over its decorrelation time)
``mean(TAG,L)[k-d]`` the mean of ``TAG[k-L+1] … TAG[k]``: a flow over the samples
                    a ``rate(LEVEL,L)`` spans, so a balance sees both sides through
                    the same window (its integral form)
``dir(TAG)[k-d]``   direction of the last significant move of TAG: +1, −1
                    (hysteresis, backlash); ``dir(TAG,0.5)`` sets the move
                    threshold in engineering units (default 0.5 % of the
                    tag's span)
``hour()[k]``       time of day in hours (0–24, UTC)
``days()[k]``       time in days since 2000-01-01 (slow drift)
``const(120.4)[k]`` a fixed number: the set-point of a loop whose set-point
                    is not a tag (``diag unit build --loop PV=120.4:OUT``)
``share(X,R1,…)``   ``X / (1 + n)``, ``n`` how many of the run tags ``R1, …``
                    are at 1 (running): a load ``X`` shared by a declared piece
                    and the other pieces that run (``diag unit build --running``;
                    NaN where a run tag is)
==================  ==========================================================

Frames are pandas DataFrames indexed by a regular timestamp grid, one column
per tag (the historian's aligned window); lags count grid samples.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import pandas as pd

from historian.errors import UserError

FUNCTIONS = {"diff": 2, "rate": 1, "mean": 1, "dir": 1, "hour": 0, "days": 0, "const": 0,
             "share": 2}  # fmt: skip
#: the functions taking at least, not exactly, their number of tags
VARIADIC = ("share",)
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
        """Parse ``TAG[k-d]``, ``"a tag"[k]`` or ``FN(ARGS)[k-d]`` (the module docstring);
        a spec that does not parse raises :class:`SpecError` showing where."""
        return _SpecParser(text).spec()

    def __str__(self) -> str:
        lag = f"[k-{self.lag}]" if self.lag else "[k]"
        if not self.fn:
            return f"{quote_tag(self.tags[0])}{lag}"
        args = [quote_tag(t) for t in self.tags]
        if self.param is not None:
            args.append(f"{self.param:.12g}" if self.fn == "const" else _fmt_num(self.param))
        return f"{self.fn}({','.join(args)}){lag}"

    @property
    def base(self) -> str:
        """The spec without its lag, e.g. ``CV`` or ``dir(CV)``."""
        return str(self.with_lag(0))[: -len("[k]")]

    def with_lag(self, lag: int) -> InputSpec:
        return InputSpec(self.fn, self.tags, lag, self.param)


def _fmt_num(v: float) -> str:
    return f"{v:g}"


#: a tag name written bare in a spec: a letter or ``_`` (any alphabet), then letters, digits
#: and ``_ . : / -``; any other name is written in double quotes, e.g. ``"Flow (t/h)"[k]``
BARE_TAG = re.compile(r"[^\W\d][\w.:/-]*")


def quote_tag(name: str) -> str:
    """``name`` as a spec writes it: bare when it can be, else in double quotes."""
    return name if BARE_TAG.fullmatch(name) else f'"{name}"'


class SpecError(UserError, ValueError):
    """An input spec that does not parse; the message shows the spec and a caret at the
    position (0-based ``pos``) where it goes wrong."""

    def __init__(self, text: str, pos: int, what: str):
        self.text, self.pos, self.what = text, pos, what
        super().__init__(
            f"bad input spec {text!r}: {what} (at character {pos + 1})\n"
            f"  {text}\n  {' ' * pos}^\n"
            '  specs: TAG[k], TAG[k-d], "a tag name"[k-d], diff(A,B)[k], rate(TAG)[k-1], '
            "mean(TAG,8)[k], dir(TAG)[k], dir(TAG,0.5)[k], hour()[k], days()[k], const(120.4)[k], "
            "share(LOAD,B_RUN)[k]"
        )


class _SpecParser:
    """A small recursive-descent parser of one spec, so an error can say where."""

    def __init__(self, text: str):
        self.text, self.i = text, 0

    def fail(self, what: str, at: int | None = None):
        raise SpecError(self.text, self.i if at is None else at, what)

    def skip(self) -> None:
        while self.i < len(self.text) and self.text[self.i].isspace():
            self.i += 1

    def peek(self) -> str:
        self.skip()
        return self.text[self.i] if self.i < len(self.text) else ""

    def expect(self, c: str, what: str) -> None:
        if self.peek() != c:
            self.fail(f"expected {what}")
        self.i += 1

    def name(self) -> tuple[str, bool]:
        """A bare or double-quoted name, and whether it was quoted."""
        self.skip()
        if self.peek() == '"':
            start = self.i
            end = self.text.find('"', self.i + 1)
            if end < 0:
                self.fail("a quoted tag name without its closing double quote", start)
            name = self.text[self.i + 1 : end]
            if not name:
                self.fail("an empty tag name", start)
            self.i = end + 1
            return name, True
        m = BARE_TAG.match(self.text, self.i)
        if not m:
            c = self.peek()
            self.fail(
                "expected a tag name"
                + (f", not {c!r}" if c else " (the spec is empty)")
                + (
                    ' (write a name with spaces or brackets in double quotes: "a tag")'
                    if c and not c.isspace()
                    else ""
                )
            )
        self.i = m.end()
        return m.group(), False

    def spec(self) -> InputSpec:
        name, quoted = self.name()
        name_end = self.i
        fn, args, param = "", [name], None
        if not quoted and self.text[self.i : self.i + 1] == "(":
            fn, fn_at = name, self.i - len(name)
            if fn not in FUNCTIONS:
                self.fail(
                    f"unknown function {fn!r} (known: {', '.join(FUNCTIONS)}; a tag name "
                    'with brackets is written in double quotes, "a (tag)"[k])',
                    fn_at,
                )
            self.i += 1
            args = []
            while self.peek() not in (")", ""):
                if args or param is not None:
                    self.expect(",", "',' between arguments")
                if (fn in ("dir", "rate", "mean") and len(args) == 1) or fn == "const":
                    m = re.compile(r"\s*([-+]?(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?)").match(
                        self.text, self.i
                    )
                    if not m:
                        self.fail(
                            "expected the move threshold of dir() as a number"
                            if fn == "dir"
                            else f"expected the samples of {fn}() as a whole number"
                            if fn in ("rate", "mean")
                            else "expected the value of const() as a number"
                        )
                    param, self.i = float(m.group(1)), m.end()
                    if fn in ("rate", "mean") and (param < 1 or param != int(param)):
                        self.fail(f"{fn}(TAG,L) takes a whole number of samples L ≥ 1")
                    continue
                args.append(self.name()[0])
            self.expect(")", "')' closing the arguments")
            if fn in VARIADIC and len(args) < FUNCTIONS[fn]:
                self.fail(f"{fn}() takes at least {FUNCTIONS[fn]} tags, got {len(args)}", fn_at)
            if fn not in VARIADIC and len(args) != FUNCTIONS[fn]:
                self.fail(f"{fn}() takes {FUNCTIONS[fn]} tag(s), got {len(args)}", fn_at)
            if fn == "mean" and param is None:
                self.fail("mean() takes its samples, e.g. mean(FLOW,8)[k]", fn_at)
            if fn == "const" and param is None:
                self.fail("const() takes a number, e.g. const(120.4)[k]", fn_at)
        if self.peek() != "[" and not quoted and not fn:
            self.fail(
                "expected '[' after the tag name (an input is written with its sample, e.g. "
                'CV[k-1]; a name with spaces or brackets in double quotes, "a tag"[k])',
                name_end,
            )
        self.expect("[", "'[' (an input is written with its sample, e.g. CV[k] or CV[k-1])")
        self.expect("k", "'k' (the current sample) after '['")
        lag = 0
        if self.peek() == "-":
            self.i += 1
            m = re.compile(r"\s*(\d+)").match(self.text, self.i)
            if not m:
                self.fail("expected a whole number of samples after 'k-', e.g. [k-1]")
            lag, self.i = int(m.group(1)), m.end()
        elif self.peek() == "+":
            self.fail("a future sample cannot be an input: lags count back, e.g. [k-1]")
        self.expect("]", "']' closing the sample")
        if self.peek():
            self.fail("unexpected text after the spec")
        return InputSpec(fn, tuple(args), lag, param)


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
    """Samples of history the specs need (``rate(TAG,L)`` needs ``L`` more, ``rate(TAG)``
    one, ``mean(TAG,L)`` ``L − 1``)."""
    return max((s.lag + history_samples(s) for s in parse_specs(specs)), default=0)


def history_samples(spec: InputSpec) -> int:
    """The samples before ``k`` one value of ``spec``'s base reads: ``L`` for ``rate(TAG,L)``
    (1 for ``rate(TAG)``), ``L − 1`` for ``mean(TAG,L)``, none for the others."""
    if spec.fn == "rate":
        return rate_samples(spec)
    if spec.fn == "mean":
        return rate_samples(spec) - 1
    return 0


def rate_samples(spec: InputSpec) -> int:
    """The samples ``L`` a ``rate(TAG,L)`` or ``mean(TAG,L)`` spans (1 for ``rate(TAG)``)."""
    return int(spec.param) if spec.param is not None else 1


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


@functools.cache
def _compiled_direction():
    """:func:`_direction` compiled by numba at its first use (numba is imported here, not with
    this module: a training whose inputs have no ``dir()`` never loads it)."""
    import numba as nb

    return nb.njit(cache=True)(_direction)


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
    return _compiled_direction()(np.ascontiguousarray(x, dtype=np.float64), float(threshold), carry)


def feature(
    frame: pd.DataFrame, spec: InputSpec, spans: Mapping[str, tuple[float, float]] | None = None
) -> np.ndarray:
    """Unlagged values of one spec over the frame (NaN where undefined), from a fresh start."""
    return _FeatureState(spec, spans).compute(frame)


class Columns:
    """A piece's columns read once: one float array (columns contiguous) over the piece's
    index, each tag's values a view of it.

    :meth:`DesignBuilder.transform` takes it in place of a frame. A unit replaying a piece
    through tens of design builders reads the piece once, not each tag of each builder from
    pandas (issue 34: about 0.3 ms of column reads per builder and 7-day piece).
    ``names`` maps the names the builders ask for to the frame's columns (default: the
    frame's columns as they are).
    """

    def __init__(self, frame: pd.DataFrame, names: Mapping[str, str] | None = None) -> None:
        names = dict(names) if names is not None else {str(c): c for c in frame.columns}
        have = [n for n, c in names.items() if c in frame.columns]
        cols = [names[n] for n in have]
        check_regular(frame.index)  # once for all the builders
        self.index = frame.index
        rows = len(frame.index)
        #: the first, second (None for one row) and last timestamps: what a builder joins
        #: pieces by
        self.ends: tuple = ()
        if rows:
            ts = frame.index
            second = pd.Timestamp(ts[1]) if rows > 1 else None
            self.ends = (pd.Timestamp(ts[0]), second, pd.Timestamp(ts[-1]))
        block, at = _float_block(frame, cols) if cols else (np.empty((rows, 0)), [])
        #: each name's column in the values (those of the whole frame where they are a view)
        self.columns = {n: int(j) for n, j in zip(have, at, strict=True)}
        self._values = block
        self._values.flags.writeable = False

    def __len__(self) -> int:
        return len(self.index)

    def values(self, tag: str) -> np.ndarray:
        """The tag's values (a view: not to be written)."""
        return self._values[:, self.columns[tag]]


def _float_block(frame: pd.DataFrame, cols: list) -> tuple[np.ndarray, np.ndarray]:
    """``frame[cols]`` as floats (NaN missing), columns contiguous, and each one's column in
    it: the frame's own values where they convert whole to one float array with contiguous
    columns (a frame of floats, or a piece of rows of one: a view, no copy, the columns at
    their places in the frame), else a copy of ``cols`` (in order) from the converted frame
    or, where it does not convert, from pandas. The same numbers either
    way; ``frame[cols].to_numpy()`` cost 1.3 ms a 7-day piece of 46 of 50 tags, the view
    none, and no copy of the piece is held while the unit evaluates it (issue 34). The
    frame is converted whole only where ``cols`` are at least half its columns (a wide plant
    frame of mixed types is not converted for a few)."""
    if 2 * len(cols) >= frame.shape[1] and frame.columns.is_unique:
        try:
            whole = frame.to_numpy(dtype=float, na_value=np.nan)
        except (TypeError, ValueError):  # a column that is not a number: pandas' way
            whole = None
        if whole is not None:
            at = frame.columns.get_indexer(cols)
            if len(whole) <= 1 or whole.strides[0] == whole.itemsize:  # columns contiguous
                return whole, at
            return np.asfortranarray(whole[:, at]), np.arange(len(cols))
    block = np.asfortranarray(frame[cols].to_numpy(dtype=float, na_value=np.nan))
    return block, np.arange(len(cols))


def _values(frame: pd.DataFrame | Columns, tag: str) -> np.ndarray:
    """A tag's values as floats, from a frame or from :class:`Columns`."""
    if isinstance(frame, Columns):
        return frame.values(tag)
    return frame[tag].to_numpy(dtype=float)


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
        # rate, mean: its last L samples (oldest first); dir: (reference, direction)
        wide = spec.fn in ("rate", "mean")
        self.carry = np.full(max(2, rate_samples(spec)) if wide else 2, np.nan)

    def compute(self, frame: pd.DataFrame | Columns) -> np.ndarray:
        spec = self.spec
        for t in spec.tags:
            if t not in frame.columns:
                raise KeyError(f"tag {t!r} (needed by {spec}) is not in the data")
        if spec.fn == "":
            return _values(frame, spec.tags[0])
        if spec.fn == "diff":
            return _values(frame, spec.tags[0]) - _values(frame, spec.tags[1])
        if spec.fn == "share":
            return shared(_values(frame, spec.tags[0]),
                          [_values(frame, t) for t in spec.tags[1:]])  # fmt: skip
        if spec.fn == "rate":
            x = _values(frame, spec.tags[0])
            n = rate_samples(spec)
            if n == 1:
                out = np.diff(x, prepend=self.carry[0]) if x.size else x
                if x.size:
                    self.carry[0] = x[-1]
                return out
            xx = np.concatenate([self.carry[-n:], x])  # the last L samples before x
            out = (xx[n:] - xx[:-n]) / n
            self.carry[-n:] = xx[-n:]
            return out
        if spec.fn == "mean":
            x = _values(frame, spec.tags[0])
            n = rate_samples(spec)
            xx = np.concatenate([self.carry[len(self.carry) - n + 1 :], x])  # L − 1 before x
            out = window_mean(xx, n)
            if n > 1:
                self.carry[len(self.carry) - n + 1 :] = xx[len(xx) - n + 1 :]
            return out
        if spec.fn == "dir":
            x = _values(frame, spec.tags[0])
            if self.threshold is None:  # frozen at the first piece: the same for all pieces
                v = x[np.isfinite(x)]
                self.threshold = DIR_THRESHOLD_SHARE * float(np.ptp(v)) if v.size else 0.0
            return direction(x, self.threshold, self.carry)
        if spec.fn == "const":
            return np.full(len(frame), float(spec.param))
        return clock(frame.index, spec.fn)


def window_mean(x: np.ndarray, n: int) -> np.ndarray:
    """The mean of each ``n`` consecutive values of ``x`` (``len(x) − n + 1`` of them, the
    last ending at ``x[-1]``); NaN where the window holds a NaN. Summed oldest first, one
    sample at a time, as the live plant's fast path sums its history's rows
    (:class:`~diag_plugin.diagnose.derived.DerivedInputs`): the same numbers bit for bit."""
    x = np.asarray(x, float)
    m = x.size - n + 1
    if m <= 0:
        return np.empty(0)
    out = x[:m].copy()
    for j in range(1, n):
        out += x[j : j + m]
    return out / n


def shared(x: np.ndarray, runs: Sequence[np.ndarray]) -> np.ndarray:
    """``share(X,R1,…)``: ``x / (1 + n)``, ``n`` how many of ``runs`` (run tags, 1 running,
    0 stopped: nearer 1 than 0) run; NaN where ``x`` or a run tag is."""
    n = np.ones_like(np.asarray(x, float))
    with np.errstate(invalid="ignore"):
        for r in runs:
            r = np.asarray(r, float)
            n = n + np.where(np.isfinite(r), r > 0.5, np.nan)
    return x / n


def clock(index: pd.Index, fn: str) -> np.ndarray:
    """``hour()`` (hours since midnight, 0–24) or ``days()`` (days since :data:`EPOCH`) at
    each timestamp of ``index``; a naive index is taken as UTC. The one computation of both,
    for a frame's rows and for the live plant's one timestamp a cycle."""
    idx = pd.DatetimeIndex(index)
    if idx.tz is None:
        idx = idx.tz_localize("UTC")
    if fn == "hour":
        return ((idx - idx.normalize()) / pd.Timedelta(hours=1)).to_numpy(float)
    if fn == "days":
        return ((idx - EPOCH) / pd.Timedelta(days=1)).to_numpy(float)
    raise AssertionError(fn)


@dataclass
class Design:
    """A design matrix ready for a model.

    ``X`` (rows × inputs) and ``y`` hold only complete rows; ``index`` their
    timestamps (None from a lean :meth:`DesignBuilder.transform`); ``dropped`` counts the
    rows left out and why; ``positions`` (when the builder gives them) the complete rows'
    positions in the piece.
    """

    X: np.ndarray
    y: np.ndarray | None
    index: pd.DatetimeIndex | None
    inputs: list[str]
    output: str | None
    n_rows: int
    dropped: dict[str, int] = field(default_factory=dict)
    positions: np.ndarray | None = None

    @property
    def n_dropped(self) -> int:
        kept = len(self.index) if self.index is not None else len(self.X)
        return self.n_rows - kept


def check_regular(index: pd.Index) -> None:
    """Lags count samples, so the frame must sit on a regular time grid."""
    if len(index) > 2:
        if isinstance(index, pd.DatetimeIndex):  # its integers as they are (no conversion)
            d = np.diff(index.asi8)
        else:
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
        self.input_names = [str(s) for s in self.specs]
        self.out_spec = None if output is None else parse_specs([output])[0]
        self.all_specs = self.specs + ([self.out_spec] if self.out_spec is not None else [])
        self._bases = [s.base for s in self.all_specs]  # each spec's feature, once
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

    def _columns(self, frame: pd.DataFrame | Columns) -> dict[str, np.ndarray]:
        return {b: f.compute(frame) for b, f in self.features.items()}

    def _join(self, index: pd.Index | tuple) -> None:
        """Check that a piece continues the last one; a gap counts as missing samples.
        ``index``: the piece's index, or its first, second and last timestamps
        (:attr:`Columns.ends`)."""
        if not len(index):
            return
        if isinstance(index, tuple):
            first, second, last = index
        else:
            first, second, last = index[0], index[1] if len(index) > 1 else None, index[-1]
        first = pd.Timestamp(first)
        if self.period is None and second is not None:
            self.period = pd.Timedelta(second - first)
        if (
            self.last is not None
            and self.period is not None
            and first.value - self.last.value == self.period.value
        ):  # the next sample of the grid (nanoseconds, exact): nothing skipped
            self.last = pd.Timestamp(last)
            return
        if self.last is not None and self.period is not None:
            step = (first - self.last) / self.period
            if step < 1 or step != round(step):
                raise ValueError(
                    f"data at {first} do not continue the previous piece (last sample "
                    f"{self.last}, period {self.period}): pieces must follow each other "
                    "on one time grid"
                )
            self._skip(int(round(step)) - 1)
        self.last = pd.Timestamp(last)

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

    def transform(
        self,
        frame: pd.DataFrame | Columns,
        quality: pd.DataFrame | None = None,
        *,
        lean: bool = False,
    ) -> Design:
        """The design matrix of the next piece; rows needing data before the first piece
        ever seen, or a NaN, bad-quality or undefined value, are dropped and counted. With
        ``lean=True`` (a replay, which needs only the rows) neither counted per reason nor
        given an index: ``X``, ``y`` and ``positions`` only (``index`` is None). ``frame``
        may be the piece's :class:`Columns` (read once for many builders), without
        ``quality``."""
        if not isinstance(frame, Columns):  # Columns checked it once
            check_regular(frame.index)
        missing = [t for t in self.tags if t not in frame.columns]
        if missing:
            raise KeyError(f"tag(s) {', '.join(missing)} needed by the model are not in the data")
        self._join(frame.ends if isinstance(frame, Columns) else frame.index)
        if quality is not None:
            if isinstance(frame, Columns):
                raise TypeError("quality needs the piece as a frame, not as Columns")
            bad = quality.reindex(index=frame.index, columns=frame.columns).fillna(0).to_numpy()
            frame = frame.mask(bad != 0)
        n = len(frame)
        feats = self._columns(frame)
        cols = [
            _lagged(self.tails[b], feats[b], s.lag)
            for s, b in zip(self.all_specs, self._bases, strict=True)
        ]
        ok = np.ones(n, bool)
        nan = np.empty(n, bool)
        for c in cols:  # a row is complete without a NaN in any column
            ok &= ~np.isnan(c, out=nan)
        dropped: dict[str, int] = {}
        if not lean:  # a replay counts no reasons
            attributed = self.seen + np.arange(n) < self.history
            if attributed.any():
                dropped["history for the lags"] = int(attributed.sum())
        raw_nan = {}
        for tag in self.tags:
            if lean and not self.nan_tails[tag].size:
                continue  # read for the reasons and the carried NaN tails only: neither here
            if isinstance(frame, Columns):
                raw = np.isnan(frame.values(tag))
            else:
                raw = pd.isna(frame[tag].to_numpy())  # as Series.isna, without the Series
            raw_nan[tag] = raw
            if lean:
                continue
            miss = np.zeros(n, bool)
            for s in self.all_specs:
                if tag in s.tags:
                    miss |= _lagged(self.nan_tails[tag], raw, s.lag)
            miss &= ~ok & ~attributed
            if miss.any():
                dropped[f"{tag} missing or bad"] = int(miss.sum())
                attributed |= miss
        other = 0 if lean else int((~ok & ~attributed).sum())
        if other > 0:
            dropped["derived value undefined"] = other
        for b, v in feats.items():
            self.tails[b] = _keep_tail(self.tails[b], v)
        for t, v in raw_nan.items():
            self.nan_tails[t] = _keep_tail(self.nan_tails[t], v)
        self.seen += n
        positions = np.flatnonzero(ok)
        d = len(self.specs)
        every = positions.size == n  # every row complete: the columns as they are
        X = np.empty((positions.size, d))
        for j, c in enumerate(cols[:d]):  # written into one C-ordered array, no stacking
            X[:, j] = c if every else c[positions]
        return Design(
            X=X,
            y=np.array(cols[d] if every else cols[d][positions], float)
            if self.out_spec is not None
            else None,
            index=None if lean else pd.DatetimeIndex(frame.index[positions]),
            inputs=list(self.input_names),
            output=None if self.out_spec is None else str(self.out_spec),
            n_rows=n,
            dropped=dropped,
            positions=positions,
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
    if v.size >= h:  # the piece alone holds the new tail (no copy of the whole piece)
        return v[v.size - h :].copy()
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
