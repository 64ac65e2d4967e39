"""A start's envelope: a fault present at a state change is not hidden until the settle's
bound (issue 34, items 5 and 6; docs/how-to/unit-loops.md, "A start's envelope").

After a state change (a pump's start, the run condition's start, a piece's start) the settle
guard (:mod:`~.settle`, :mod:`~.equipment`) forgives the unit's alarms until no test has been
on for the quiet time, at most the build's bound. A fault present at the start keeps a test
on, so it was hidden for the whole bound (the air-handling unit: 8.5 h or more after every
onset, docs/explanation/acceptance-ahu.md). A plant engineer forgives a start's transient, not
a residual far beyond what the fault-free starts ever showed *at that age*.

``diag unit build`` learns, from the window's own fault-free changes (those
:func:`~diag_plugin.unitbuild.loops.state_settle_max` and
:func:`~diag_plugin.unitbuild.loops.piece_settle_bounds` measure), per test the largest
``|residual|`` in units of its threshold (:func:`scaled`) in a few age bins after the change
(edges: the quartiles of the settling times, the first bin cut in four), widened by a margin
from the number of starts seen, at least a tolerance bound (a Gumbel law fitted to the
changes' peaks, its quantile for one fault-free change in a hundred beyond any of the
envelope's tests × bins, plus its standard error from the number of starts:
:func:`~diag_plugin.unitbuild.loops.envelope_bound`), and writes it to the unit file.
The residuals are the cross-fitted, held-out ones the thresholds
are learned from (:class:`~diag_plugin.unitbuild.loops.HeldOut`), and ``diag unit accept``
learns the envelope again over every window it learned::

    [envelope.state]  # written by `diag unit build`: ...
    starts = 14           # the fault-free changes it rests on
    age_s = [0.0, 1200.0, 2400.0, 4800.0]   # each bin's first age (seconds after the change)
    tests = { C2_TD = [4.1, 1.6, 1.0, 1.0], ... }  # per bin, in units of the threshold
    quiet_s = 60.0        # a settle of these changes ends after this long with no test on

``state`` is the unit-wide settle's (every ``[build] states`` tag and the run condition
pooled); ``[envelope.NAME]`` a piece's (``[equipment.NAME]``, its own tests). A bin the
changes seen reached fewer than :data:`MIN_STARTS` times is not written (no envelope there).

At run time, during a settle, a test whose filtered residual stays beyond its envelope at
that age for the on-delay ends the settle: the unit's alarm is raised (FAILURE), its why
``C2_TD beyond what 14 starts of C2 showed 20 min after its start (3.2 × its threshold, at
most 1.9 there)`` (the unit-wide settle's: ``… what 8 state changes showed 12 min after a
change …``). ``quiet_s`` (the unit-wide settle's, where the build wrote it): a settle of
these changes ends once no test has been on for it and the alarm dropped, not the unit's
quiet time: the window's changes never paused longer than it before a symptom came back
(:func:`~diag_plugin.unitbuild.loops.start_quiet`). A piece's envelope is learned at the ages
its own settle judges (:func:`~diag_plugin.diagnose.equipment.piece_ages`), as the state's
(:func:`~diag_plugin.diagnose.settle.settle_replay`). Without an envelope (old unit files,
too few starts) the settle is as before.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numba
import numpy as np

#: a bin (and an envelope) needs at least this many fault-free changes that reached it: the
#: largest of fewer says little of the next one's
MIN_STARTS = 5
#: the envelope of the unit-wide settle (every state tag, the run condition)
STATE = "state"


@dataclass(frozen=True)
class Envelope:
    """Per test the largest residual (threshold units) the window's ``starts`` fault-free
    changes showed in each age bin (``age_s``: each bin's first age, seconds)."""

    starts: int
    age_s: tuple[float, ...]
    tests: Mapping[str, tuple[float, ...]]
    #: the quiet time (s) that ends a settle of these changes: learned from their own lulls
    #: (:func:`~diag_plugin.unitbuild.loops.start_quiet`); None: the unit's quiet time
    quiet_s: float | None = None

    def as_table(self) -> dict[str, object]:
        """The unit file's ``[envelope.KEY]`` row (module doc)."""
        out: dict[str, object] = {
            "starts": int(self.starts),
            "age_s": [float(a) for a in self.age_s],
            "tests": {t: [float(f"{v:.4g}") for v in b] for t, b in self.tests.items()},
        }
        if self.quiet_s is not None:
            out["quiet_s"] = float(self.quiet_s)
        return out

    def arrays(self, names: Sequence[str], period_s: float) -> tuple[np.ndarray, np.ndarray]:
        """Each bin's first age in samples, and bins × ``names`` the envelope (inf: none)."""
        edges = np.ceil(np.asarray(self.age_s, float) / period_s - 1e-9).astype(np.int64)
        out = np.full((len(edges), len(names)), np.inf)
        for j, t in enumerate(names):
            if t in self.tests:
                out[:, j] = self.tests[t]
        return edges, out


def read_envelopes(
    table: Mapping, error: Callable[[int, str], None], line_of: Callable[[str], int]
) -> dict[str, Envelope]:
    """The ``[envelope]`` tables of a unit file (module doc); none without one; problems
    reported through ``error(line, text)``."""
    out = {}
    for key, row in (table or {}).items():
        what = f"[envelope.{key}]"
        ages = row.get("age_s") if isinstance(row, Mapping) else None
        tests = row.get("tests") if isinstance(row, Mapping) else None
        starts = row.get("starts") if isinstance(row, Mapping) else None
        ok = (
            isinstance(ages, list) and ages and all(isinstance(a, int | float) for a in ages)
            and all(b > a for a, b in zip(ages, ages[1:], strict=False))
            and isinstance(tests, Mapping) and isinstance(starts, int)
            and all(isinstance(v, list) and len(v) == len(ages)
                    and all(isinstance(x, int | float) and x > 0 for x in v)
                    for v in tests.values())
        )  # fmt: skip
        if not ok:
            error(line_of(key), f"{what} needs starts (an integer), age_s (ascending seconds) "
                                "and tests (per test one number > 0 per age)")  # fmt: skip
            continue
        quiet = row.get("quiet_s")
        if quiet is not None and (isinstance(quiet, bool) or not isinstance(quiet, int | float)
                                  or not quiet > 0):  # fmt: skip
            error(line_of(key), f"{what} quiet_s must be a number of seconds > 0")
            continue
        bins = {str(t): tuple(float(x) for x in v) for t, v in tests.items()}
        out[str(key)] = Envelope(int(starts), tuple(float(a) for a in ages), bins,
                                 None if quiet is None else float(quiet))  # fmt: skip
    return out


def scaled(r: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """``|r|`` in units of the threshold on its side (``r / hi`` above 0, ``r / lo`` below;
    NaN where a test has none): above 1 is beyond the threshold."""
    r = np.asarray(r, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(r >= 0, r / hi, -r / np.abs(lo))


@numba.njit(cache=True, nogil=True)
def beyond(u, edges, env, age, over, on_n):  # pragma: no cover - numba
    """The test whose ``u`` (one sample, threshold units) has been beyond its envelope at
    ``age`` (samples since the change) for ``on_n`` samples in a row (``over``: per test the
    count so far, updated in place), else -1."""
    b = -1
    for k in range(edges.size):
        if age >= edges[k]:
            b = k
    hit = -1
    for t in range(u.size):
        if b >= 0 and u[t] > env[b, t]:  # NaN: never
            over[t] += 1
            if over[t] >= on_n and hit < 0:
                hit = t
        else:
            over[t] = 0
    return hit


def age_words(seconds: float) -> str:
    """An age as the why says it: ``45 s``, ``20 min``, ``2.5 h``."""
    if seconds < 120:
        return f"{seconds:.0f} s"
    if seconds < 2 * 3600:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def says(test: str, env: Envelope, age_s: float, u: float, bound: float, what: str,
         after: str) -> str:  # fmt: skip
    """The why of a settle an envelope ended (module doc): ``what`` the changes it learned
    from (``state changes``, ``starts of C2``), ``after`` one of them (``a change``, ``its
    start``)."""
    a, b = f"{u:.2g}", f"{bound:.2g}"
    if a == b:  # 2.13 beyond 2.08: not "2.1 × its threshold, at most 2.1 there"
        a, b = f"{u:.3g}", f"{bound:.3g}"
    return (
        f"{test} beyond what {env.starts} {what} showed {age_words(age_s)} after {after} "
        f"({a} × its threshold, at most {b} there)"
    )
