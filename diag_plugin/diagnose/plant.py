"""A plant: many units evaluated together, one cycle at a time, vectorised across units.

Kościelny et al. (Sect. 2, Table 3) decompose a plant's diagnostic matrix into the
block-diagonal matrices of its units: each unit is diagnosed on its own, so one unit's failure
stays local. :class:`Plant` keeps that structure and evaluates every unit each cycle as arrays:

* the plant's tag vector and its recent history (a ring buffer as deep as the longest lag);
* every Wang–Mendel model in one stacked kernel call (:class:`WangMendelStack`: 1,000 units
  with their own rule bases cost one call), and one ``predict`` per distinct model object of
  the other methods over all the units that use it;
* the Butterworth filter, thresholds, on/off delays and holds over all (unit, test) residuals
  at once, and one matrix call per distinct matrix with units as rows.

A unit whose file, models or matrix are broken is reported CHECK_FUNCTION with Bad quality and
its ``file:line`` problems every cycle; the others go on. Derived inputs (``rate(T,L)``,
``diff(A,B)``, ``const``, ``hour()``, ``days()``, ``dir(T,h)``) are columns of the history
computed each cycle (:mod:`~diag_plugin.diagnose.derived`), read with their lags like tags.
Units whose models read ``dir(T)`` without its threshold, whose symptoms are fuzzy (N/0/P,
isolated by rules (10)–(14)), or that are judged only while they run (a run condition,
:mod:`~diag_plugin.diagnose.running`), are evaluated one by one with :meth:`Unit.evaluate` (same
result, slower). The alarm settings
``diag unit build`` writes on every unit (:mod:`~diag_plugin.diagnose.unitloops`) stay on the
fast path, their state carried per slot or unit across cycles: the running spread of a spread
test's residual (:class:`~diag_plugin.diagnose.unitloops.RunningSpread`, its last ``W − 1``
residuals and deviations), the deadband (:class:`~diag_plugin.diagnose.unitloops.Deadband`,
each test's last raw symptom) and the unit's own off-delay (samples since its last alarm
sample, and that sample's status, faults and tags). A unit with a combined
test or isolation to tags (:mod:`~diag_plugin.diagnose.unittags`) stays on the fast path: its
T² and tag shares are computed from its slice of the filtered residuals each cycle, and its
status's ``tags`` and message name the top tags on an alarm.
The fast path gives the same statuses as :meth:`Unit.evaluate` over the same rows (tested).
"""

from __future__ import annotations

import hashlib
import logging
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from diag_plugin.diagnose.combos import CombosGuard
from diag_plugin.diagnose.derived import DerivedInputs, stackable
from diag_plugin.diagnose.envelope import scaled
from diag_plugin.diagnose.fixed import FixedGuard
from diag_plugin.diagnose.isolation import IsolationHold
from diag_plugin.diagnose.manual import PlantGuard
from diag_plugin.diagnose.residuals import LowPass, supported
from diag_plugin.diagnose.settle import settle_guard
from diag_plugin.diagnose.symptoms import OnOffDelay
from diag_plugin.diagnose.unit import (
    PRIORITY,
    Unit,
    _hold_kernel,
    broken_status,
    held_text,
    spread_factor,
)
from diag_plugin.diagnose.unitfile import UnitError
from diag_plugin.diagnose.unitloops import (
    AlarmHold,
    Deadband,
    EpisodeHold,
    OscillationHold,
    PinnedValves,
    RunningSpread,
    _release_kernel,
    combined_release,
    oscillation_samples,
    spread_samples,
    warm_up,
    warming_up,
)
from diag_plugin.diagnose.unittags import with_ranked
from diag_plugin.fuzzy.stack import WangMendelStack
from diag_plugin.regressors import InputSpec, parse_specs
from diag_plugin.status import NE107, Quality, UnitStatus

log = logging.getLogger(__name__)


@dataclass
class _Slot:
    """One (unit, test) residual: where its model's inputs and output sit in the tag vector."""

    unit: int
    test: int
    model: object
    inputs: np.ndarray  # (d, 2): (lag, tag index)
    output: tuple[int, int]  # (lag, tag index)
    scale: float


def _stackable(unit: Unit) -> bool:
    """True when every model input and output is a plain tag with a lag or a derived input the
    fast path computes (:func:`~diag_plugin.diagnose.derived.stackable`: ``rate``, ``diff``,
    ``const``, ``hour``, ``days``, ``dir`` with its threshold)."""
    return all(
        stackable(s) for m in unit.models.values() for s in parse_specs([*m.inputs, m.output])
    )


def _crisp(unit: Unit) -> bool:
    """True for crisp symptoms and no run condition (the fast path); fuzzy N/0/P units, and
    units judged only while they run (``[running]``, :mod:`~diag_plugin.diagnose.running`),
    go one by one, as units with a piece of equipment's run condition (``[equipment]``,
    :mod:`~diag_plugin.diagnose.equipment`)."""
    crisp = unit.ev["symptoms"] == "crisp" and unit.file.running is None
    return crisp and not getattr(unit.file, "equipment", None)


class Plant:
    """Units evaluated together each cycle (see module doc).

    ``units``: loaded units by name; ``broken``: unit name → its problems (``file:line``).
    Evaluation settings that must be shared by the stacked stages (low-pass cut-off and order,
    on/off delays, spread windows) may differ between units: units are stacked per setting.
    ``batched=False`` evaluates every unit one by one with :meth:`Unit.evaluate` (the
    reference the fast path is tested against).
    """

    def __init__(
        self,
        units: Mapping[str, Unit],
        broken: Mapping[str, list[str]] | None = None,
        *,
        batched: bool = True,
    ):
        self.units = dict(units)
        self.broken = dict(broken or {})
        self.fast = [n for n, u in self.units.items() if batched and _stackable(u) and _crisp(u)]
        self.slow = [n for n in self.units if n not in self.fast]
        self._versions = _versions(self.units)  # of the files as loaded, not as they become
        self._build()

    @classmethod
    def load(cls, paths: Iterable[str | Path], folder: str | Path = "rulebases") -> Plant:
        """Load unit files; a broken one is kept aside with its problems, never raised."""
        units: dict[str, Unit] = {}
        broken: dict[str, list[str]] = {}
        cache: dict = {}  # units reading the same rule-base file share its model
        for p in paths:
            name = Path(p).name.removesuffix(".unit.toml").removesuffix(".toml")
            try:
                u = Unit.load(p, folder, models_cache=cache)
            except UnitError as exc:
                broken[name] = exc.problems
                log.warning("unit %s not loaded:\n%s", name, "\n".join(exc.problems))
                continue
            units[u.name] = u
        return cls(units, broken)

    # ------------------------------------------------------------ structure
    def _build(self) -> None:
        units = [self.units[n] for n in self.fast]
        tags: dict[str, int] = {}
        derived = DerivedInputs()

        def column(u: Unit, s: InputSpec) -> int:
            """A tag's column, or −1 − the number of a derived feature (its column is known
            once every tag has one: after them)."""
            names = tuple(u.file.tags.get(t, t) for t in s.tags)
            for p in names:
                tags.setdefault(p, len(tags))
            return tags[names[0]] if s.fn == "" else -1 - derived.add(s, names)

        depth = 0
        slots: list[_Slot] = []
        for ui, u in enumerate(units):
            for ti, t in enumerate(u.file.tests):
                m = u.models[t.name]
                ins = []
                for s in parse_specs(m.inputs):
                    ins.append((s.lag, column(u, s)))
                    depth = max(depth, s.lag)
                o = parse_specs([m.output])[0]
                out = (o.lag, column(u, o))
                depth = max(depth, o.lag)
                scale = t.ymax if u.ev["scale"] == "max" and t.ymax else m.span
                slots.append(
                    _Slot(ui, ti, m.model, np.array(ins, np.intp).reshape(-1, 2), out, float(scale))
                )
        # the tags constant over each unit's build window (fixed.py): read, never modelled;
        # its discrete states, whose combinations it learned (combos.py)
        guards: dict[str, dict] = {"fixed": {}, "combos": {}}
        for ui, u in enumerate(units):
            for kind, cls in (("fixed", FixedGuard), ("combos", CombosGuard)):
                if (g := cls.of(u)) is not None:
                    cs = [tags.setdefault(p, len(tags)) for p in g.plant]
                    guards[kind][ui] = (g, np.array(cs, np.intp))
        self._fixed, self._combos = guards["fixed"], guards["combos"]
        n_tags = len(tags)
        for s in slots:  # the derived features' columns after the tags'
            s.inputs[:, 1] = _after(s.inputs[:, 1], n_tags)
            s.output = (s.output[0], int(_after(np.array([s.output[1]]), n_tags)[0]))
        self._manual = _manual_guard(units, slots, tags)
        derived.freeze(tags)
        self._derived = derived if len(derived) else None
        self.tag_names = list(tags)
        self.tag_index = tags
        self.depth = max(depth, derived.depth)
        self.slots = slots
        self._failing: set[int] = set()  # ids of models whose prediction raised (logged once)
        self._units = units
        n = len(slots)
        self._slot_unit = np.array([s.unit for s in slots], np.intp)
        # Wang–Mendel models: all stacked, one kernel call per cycle over every slot
        # (4,000 distinct rule bases cost one call, not 4,000)
        stacked: dict[int, int] = {}
        wm = [i for i, s in enumerate(slots) if WangMendelStack.accepts(s.model)]
        models = []
        for i in wm:
            if id(slots[i].model) not in stacked:
                stacked[id(slots[i].model)] = len(models)
                models.append(slots[i].model)
        self._stack = WangMendelStack.from_models(models) if models else None
        d_max = max((len(slots[i].inputs) for i in wm), default=0)
        self._wm_slots = np.array(wm, np.intp)
        self._wm_which = np.array([stacked[id(slots[i].model)] for i in wm], np.int64)
        self._wm_lags = np.zeros((len(wm), d_max), np.intp)
        self._wm_cols = np.zeros((len(wm), d_max), np.intp)
        for r, i in enumerate(wm):
            d = len(slots[i].inputs)
            self._wm_lags[r, :d] = slots[i].inputs[:, 0]
            self._wm_cols[r, :d] = slots[i].inputs[:, 1]
        # other methods: one predict per distinct model object over the slots it serves
        by_model: dict[int, list[int]] = {}
        for i, s in enumerate(slots):
            if id(s.model) not in stacked:
                by_model.setdefault(id(s.model), []).append(i)
        self._groups = []
        for idx in by_model.values():
            idx_a = np.array(idx, np.intp)
            lags = np.stack([slots[i].inputs[:, 0] for i in idx])
            cols = np.stack([slots[i].inputs[:, 1] for i in idx])
            self._groups.append((slots[idx[0]].model, idx_a, lags, cols))
        self._out_lag = np.array([s.output[0] for s in slots], np.intp)
        self._out_col = np.array([s.output[1] for s in slots], np.intp)
        self._scale = np.array([s.scale for s in slots])
        # residual scale of each rule level per slot (NaN: a level the unit never calibrated)
        tables = [units[s.unit].file.tests[s.test].levels or (1.0,) for s in slots]
        self._levels = np.full((n, max((len(t) for t in tables), default=1)), np.nan)
        for i, t in enumerate(tables):
            self._levels[i, : len(t)] = t
        self._min_support = np.array([units[s.unit].ev["min_support"] for s in slots])
        self._spread = np.array([units[s.unit].file.tests[s.test].spread for s in slots], bool)
        lims = [units[s.unit].file.tests[s.test].limits for s in slots]
        self._no_th = np.array([lim is None for lim in lims], bool)
        self._lo = np.array([-1.0 if lim is None else lim[0] for lim in lims])
        self._hi = np.array([1.0 if lim is None else lim[1] for lim in lims])
        # stages stacked per evaluation setting (filter, deadband, delays); a deadband of 0
        # is a plain threshold (unitloops.Deadband, its last symptom per test carried)
        self._stages = []
        keys: dict[tuple, list[int]] = {}
        for i, s in enumerate(slots):
            ev = units[s.unit].ev
            band = max(float(ev["deadband"] or 0.0), 0.0)
            keys.setdefault(
                (ev["lowpass"], ev["order"], band, ev["on_delay"], ev["off_delay"]), []
            ).append(i)
        # a spread test's filter restarts after a gap at its value, not at rest (LowPass)
        is_spread = np.array(
            [units[s.unit].file.tests[s.test].statistic == "spread" for s in slots], bool
        )
        # each slot's oscillation hold (unitloops.OscillationHold): its unit's window
        swing = np.array([oscillation_samples(units[s.unit].ev, units[s.unit].period)
                          for s in slots], np.int64)  # fmt: skip
        # and its settle's quiet time (a step's transient unseen by it, Unit._openings)
        quiet = [units[ui]._quiet_n() for ui in range(len(units))]
        #: each slot's unit: the group of its column in the holds' settle openings
        self._slot_unit = np.array([s.unit for s in slots], np.intp)
        for (wn, order, band, on, off), idx in keys.items():
            self._stages.append(
                (
                    np.array(idx, np.intp),
                    LowPass(wn, order, steady=is_spread[idx]) if wn > 0 else None,
                    Deadband(band, len(idx)),
                    OnOffDelay(on, off),
                    on - 1,
                    OscillationHold(
                        swing[idx], quiet=np.array([quiet[slots[k].unit] for k in idx], np.int64)
                    ),
                )
            )
        # the spread tests (statistic "spread"): a running spread per window length
        self._spreads = []
        by_window: dict[int, list[int]] = {}
        for i, s in enumerate(slots):
            u = units[s.unit]
            if u.file.tests[s.test].statistic == "spread":
                w = spread_samples(u.ev["spread_window_s"] or 600.0, u.period)
                by_window.setdefault(w, []).append(i)
        for w, idx in by_window.items():
            self._spreads.append((np.array(idx, np.intp), RunningSpread(w, len(idx))))
        # their release on a long window (unitloops.ReleaseHold): per slot its threshold
        # (NaN: none) and hold, a running spread per long window length
        self._release = np.full(n, np.nan)
        self._released = np.zeros(n, np.bool_)
        self._rel_left = np.zeros(n, np.int64)
        self._longs = []
        by_long: dict[int, list[int]] = {}
        # per slot its loop valve's column (-1: none) and span (unitloops.PinnedValves)
        valve = np.full(n, -1, np.intp)
        v_span = np.full((n, 2), np.nan)
        for i, s in enumerate(slots):
            u = units[s.unit]
            if u.release_hold is not None:
                k = np.flatnonzero(u.release_hold.cols == s.test)
                if k.size and np.isfinite(u.release_hold.release[k[0]]):
                    self._release[i] = u.release_hold.release[k[0]]
                    by_long.setdefault(u.release_hold.spread.window, []).append(i)
                    v = u.release_hold.valves[k[0]]
                    if v is not None and u.file.tags.get(v[0], v[0]) in tags:
                        valve[i] = tags[u.file.tags.get(v[0], v[0])]
                        v_span[i] = v[1:]
        for w, idx in by_long.items():
            ix = np.array(idx, np.intp)
            pin = PinnedValves(w, v_span[ix, 0], v_span[ix, 1])
            self._longs.append((ix, RunningSpread(w, len(idx)), pin, valve[ix]))
        self._long = np.full(n, np.nan)
        # the loops' own tests that raise their spread test's hold (ReleaseHold's
        # followers): per slot that spread test's slot (-1: none), and per unit its spread
        # slots, which the combined test's hold reads (ReleaseHold.combined)
        self._follows = np.full(n, -1, np.intp)
        self._rel_maps: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        at_slot = {(s.unit, s.test): i for i, s in enumerate(slots)}
        self._t2_rel: dict[int, np.ndarray] = {}
        for ui, u in enumerate(units):
            h = u.release_hold
            if h is None:
                continue
            spread_slots = [at_slot.get((ui, int(c)), -1) for c in h.cols]
            if all(k >= 0 and np.isfinite(self._release[k]) for k in spread_slots):
                self._t2_rel[ui] = np.array(spread_slots, np.intp)
            for j, k in zip(h.fcols, h.fwhich, strict=True):
                i, src = at_slot.get((ui, int(j)), -1), spread_slots[int(k)]
                if i >= 0 and src >= 0 and np.isfinite(self._release[src]):
                    self._follows[i] = src
        self._t2_held = np.zeros(len(units), np.bool_)
        self._t2_left = np.zeros(len(units), np.int64)
        self._opens = np.zeros((1, len(units)), np.int64)
        # the warm-up (unitloops.warm_up): per slot its longest lag, whether it is a spread
        # test, the known samples its spread window still needs and whether its residual was
        # known before the spread; per unit what each test waits for
        # (Unit.test_depth: the longest lag, a rate's samples added)
        self._slot_depth = np.array([units[s.unit].test_depth[s.test] for s in slots], np.int64)
        self._spread_test = np.zeros(n, bool)
        for idx, _ in self._spreads:
            self._spread_test[idx] = True
        self._spread_left = np.zeros(n, np.int64)
        self._raw_known = np.zeros(n, bool)
        self._labels = [u.warm_labels for u in units]
        # the unit's own off-delay (unitloops.AlarmHold): samples since its last alarm sample
        # and that sample's (status, faults, tags)
        self._alarm_hold = AlarmHold(
            np.array([u.ev["off_delay"] if u.ev["off_delay_s"] > 0 else 0 for u in units], np.int64)
        )
        self._last_alarm: dict[int, tuple[int, list[str], list[tuple[str, float]]]] = {}
        self._held = np.full(n, np.nan)
        self._run = np.zeros(n, np.int64)
        self._latched = np.zeros(n)
        self._latch = np.array([units[s.unit].ev["latch"] for s in slots], bool)
        # per distinct matrix: its units (rows) and their slots in matrix test order
        self._matrices = []
        by_matrix: dict[int, list[int]] = {}
        for ui, u in enumerate(units):
            if u.matrix is not None:
                by_matrix.setdefault(_matrix_key(u), []).append(ui)
        first_slot: dict[int, int] = {}
        for i, s in enumerate(slots):
            first_slot.setdefault(s.unit, i)
        self._first = first_slot
        self._has_th = [u.has_thresholds for u in units]
        # per unit the inputs its reasons judge: ((model tag, lag), plant tag) read by some unit
        # and the tags whose gaps it follows (OutsideLearned.watch), now
        self._judged = [
            [
                (key, p)
                for key in dict.fromkeys(
                    [*(r.key for r in u.outside.ranges), *((t, 0) for t in u.outside.watch)]
                )
                if (p := u.file.tags.get(key[0], key[0])) in tags
            ]
            for u in units
        ]
        # units with a combined test or isolation to tags: (unit, its model, delay, enabled)
        self._multi = [
            (ui, u.cmodel, OnOffDelay(u.ev["on_delay"], u.ev["off_delay"]), bool(u.ev["combined"]))
            for ui, u in enumerate(units)
            if u.cmodel is not None
        ]
        # per combined test with operating points, its point tags' columns of the history
        self._point_cols = {
            ui: np.array([self.tag_names.index(t) if t in self.tag_names else -1
                          for t in cm.point_tags], np.intp)
            for ui, cm, _, _ in self._multi
            if cm.centers is not None and cm.point_tags
        }  # fmt: skip
        # per unit with a measured input's excursion rule (unittags.Excursions): the history's
        # column of each model tag it judges (-1: not read)
        self._ex_cols = {
            ui: {t: (self.tag_names.index(p) if (p := units[ui].file.tags.get(t, t))
                     in self.tag_names else -1) for t in units[ui].excursions.ranges}
            for ui, _, _, _ in self._multi
            if units[ui].excursions is not None
        }  # fmt: skip
        # level tests with operating points of their own (Unit.at_points): per unit its
        # point tags' columns, the tests' slots and their centres and scales per point
        self._level_points = [
            (cm, self._point_cols.get(ui), first_slot[ui] + lp[0], lp[1], lp[2])
            for ui, cm, _, _ in self._multi
            if (lp := units[ui].level_points) is not None
        ]
        # the tags named, averaged over each alarm episode (unitloops.EpisodeHold)
        self._holds = {ui: EpisodeHold(len(cm.tags)) for ui, cm, _, _ in self._multi}
        self._test_holds = {ui: EpisodeHold(len(cm.tags)) for ui, cm, _, _ in self._multi}
        for uis in by_matrix.values():
            mx = units[uis[0]].matrix
            order = [units[uis[0]].tests.index(t) for t in mx.tests]
            cols = np.array([[first_slot[ui] + k for k in order] for ui in uis], np.intp)
            self._matrices.append(
                (
                    mx,
                    np.array(uis, np.intp),
                    cols,
                    np.array([units[ui].iso_certainty for ui in uis]),
                    np.array([units[ui].ev["hold_isolation"] for ui in uis], bool),
                    IsolationHold(len(uis), len(mx.tests), len(mx.faults)),
                )
            )
        # per unit with a settle guard (settle.py): it, and its set-points' columns
        self._settle = {
            ui: (g, np.array([tags[u.file.tags.get(lp.sp, lp.sp)] for lp in g.loops], np.intp))
            for ui, u in enumerate(units)
            if (g := settle_guard(u)) is not None
        }
        #: the same steps for the oscillation hold (its own state, Unit.transients)
        self._transients = {
            ui: (g, np.array([tags[u.file.tags.get(lp.sp, lp.sp)] for lp in g.loops], np.intp))
            for ui, u in enumerate(units)
            if (g := settle_guard(u)) is not None
        }
        self._hist = np.full((self.depth + 1, len(tags) + len(derived)), np.nan)
        self._cycles = 0
        self._ts: pd.Timestamp | None = None  # the last cycle's (saved with the state)

    @property
    def tags(self) -> list[str]:
        """Every plant tag any unit reads."""
        extra = [t for n in self.slow for t in self.units[n].tags]
        return list(dict.fromkeys([*self.tag_names, *extra]))

    @property
    def last_ts(self) -> pd.Timestamp | None:
        """The time of the last cycle evaluated (or restored by :meth:`load_state`); None
        for a fresh plant."""
        return self._ts

    def reset(self) -> Plant:
        self._build()
        for n in self.slow:
            self.units[n].reset()
        for u in self._units:
            u.outside.reset()
        return self

    # ------------------------------------------------------------ state
    def versions(self) -> dict[str, str]:
        """Per unit a SHA-256 of its unit file, its models' rule-base files and its matrix
        file, read when the plant was made: a state is restored only onto the same versions
        (:meth:`load_state`); a file edited while the plant runs does not change them."""
        return dict(self._versions)

    def to_state(self) -> dict[str, Any]:
        """Everything the plant carries from cycle to cycle, as JSON (arrays as lists, NaN as
        null): the tag history, each stage's filter, deadband and delays, the held and
        latched symptoms, the running spreads, the unit off-delays and their last alarms, the
        combined tests' delays, the episode and isolation holds, each unit's excursions
        outside what it learned, and the one-by-one units' own :meth:`Unit.to_state`.
        With :meth:`load_state` a restarted plant goes on where this one was."""
        ts = self._ts
        return {
            "format": 1,
            "versions": self.versions(),
            "ts": None if ts is None else ts.isoformat(),
            "cycles": self._cycles,
            "tags": self.tag_names,
            "hist": _json(self._hist),
            "derived": None if self._derived is None else _json(self._derived.carry),
            "stages": [
                {
                    "lowpass": None if lp is None else lp.to_state(),
                    "deadband": _json(band.state),
                    "delay": delay.to_state(),
                    "oscillation": swing.to_state(),
                }
                for _, lp, band, delay, _, swing in self._stages
            ],
            "held": _json(self._held),
            "run": self._run.tolist(),
            "latched": _json(self._latched),
            "spreads": [sp.to_state() for _, sp in self._spreads],
            "longs": [sp.to_state() for _, sp, _, _ in self._longs],
            "pinned": [pv.to_state() for _, _, pv, _ in self._longs],
            "released": self._released.tolist(),
            "release_left": self._rel_left.tolist(),
            "release_t2": [self._t2_held.tolist(), self._t2_left.tolist()],
            "alarm_hold": self._alarm_hold.to_state(),
            "last_alarm": {
                str(ui): [st, fa, [[t, v] for t, v in tg]]
                for ui, (st, fa, tg) in self._last_alarm.items()
            },
            "combined_delays": [d.to_state() for _, _, d, _ in self._multi],
            "episodes": {str(ui): h.to_state() for ui, h in self._holds.items()},
            "test_episodes": {str(ui): h.to_state() for ui, h in self._test_holds.items()},
            "isolation": [m[5].to_state() for m in self._matrices],
            "outside": {u.name: u.outside.to_state()["since"] for u in self._units},
            "gone": {u.name: u.outside.to_state()["gone"] for u in self._units},
            "slow": {n: self.units[n].to_state() for n in self.slow},
            "settle": {self._units[ui].name: g.to_state() for ui, (g, _) in self._settle.items()},
            "transients": {
                self._units[ui].name: g.to_state() for ui, (g, _) in self._transients.items()
            },
            "fixed": {self._units[ui].name: g.to_state() for ui, (g, _) in self._fixed.items()},
            "combos": {self._units[ui].name: g.to_state() for ui, (g, _) in self._combos.items()},
            "saturation": {
                u.name: u.saturation.to_state()
                for u in self._units
                if getattr(u, "saturation", None) is not None
            },
        }

    def load_state(self, state: Mapping[str, Any]) -> Plant:
        """Go on from :meth:`to_state` of a plant of the same unit versions; raises
        :class:`ValueError` saying why when the state does not fit (other units or versions,
        another layout), the plant then left as it was."""
        if state.get("format") != 1:
            raise ValueError(f"state format {state.get('format')!r}, not 1")
        mine, theirs = self.versions(), dict(state.get("versions", {}))
        if mine != theirs:
            changed = sorted(n for n in mine.keys() | theirs.keys() if mine.get(n) != theirs.get(n))
            raise ValueError(f"units changed since the state was saved: {', '.join(changed)}")
        hist = _array(state["hist"])
        layout = (
            state["tags"] == self.tag_names
            and hist.shape == self._hist.shape
            and len(state["stages"]) == len(self._stages)
            and len(state["spreads"]) == len(self._spreads)
            and len(state["combined_delays"]) == len(self._multi)
            and len(state["isolation"]) == len(self._matrices)
        )
        carry = _array(state.get("derived") or [])
        if self._derived is not None:
            layout = layout and self._derived.fits(carry)
        if not layout:
            raise ValueError("the state's layout differs from the plant's (tags or stages)")
        self._build()
        self._ts = None if state["ts"] is None else pd.Timestamp(state["ts"])
        self._cycles = int(state["cycles"])
        if self._derived is not None:  # a dir() input's carried reference and direction
            self._derived.load_carry(carry)
        self._hist = hist
        stages = []
        for (idx, _lp, band, _delay, hold, swing), st in zip(
            self._stages, state["stages"], strict=True
        ):
            lp = None if st["lowpass"] is None else LowPass.from_state(st["lowpass"])
            if lp is not None and _lp is not None:  # a state saved before it has no steady
                lp.steady = _lp.steady
            band.state = _array(st["deadband"])
            if "oscillation" in st:  # a state saved before it starts the hold from rest
                swing.load_state(st["oscillation"])
            stages.append((idx, lp, band, OnOffDelay.from_state(st["delay"]), hold, swing))
        self._stages = stages
        self._held = _array(state["held"])
        self._run = np.asarray(state["run"], np.int64)
        self._latched = _array(state["latched"])
        for (_, sp), st in zip(self._spreads, state["spreads"], strict=True):
            sp.load_state(st)
        if len(state.get("longs") or []) == len(self._longs):  # saved before it: from rest
            for (_, sp, _, _), st in zip(self._longs, state.get("longs") or [], strict=True):
                sp.load_state(st)
            pins = state.get("pinned") or []  # saved before it: at rest
            pins = pins if len(pins) == len(self._longs) else [None] * len(self._longs)
            for (_, _, pv, _), st in zip(self._longs, pins, strict=True):
                pv.load_state(st)
            if len(state.get("released") or []) == len(self._released):
                self._released = np.asarray(state["released"], np.bool_)
                left = state.get("release_left") or [0] * len(self._released)
                self._rel_left = np.asarray(left, np.int64)
            t2 = state.get("release_t2")  # saved before the combined test's hold: from rest
            if t2 is not None and len(t2[0]) == len(self._t2_held):
                self._t2_held = np.asarray(t2[0], np.bool_)
                self._t2_left = np.asarray(t2[1], np.int64)
        self._alarm_hold.load_state(state["alarm_hold"])
        self._last_alarm = {
            int(ui): (int(st), list(fa), [(str(t), float(v)) for t, v in tg])
            for ui, (st, fa, tg) in state["last_alarm"].items()
        }
        self._multi = [
            (ui, cm, OnOffDelay.from_state(d), en)
            for (ui, cm, _, en), d in zip(self._multi, state["combined_delays"], strict=True)
        ]
        for ui, st in state["episodes"].items():
            self._holds[int(ui)].load_state(st)
        for ui, st in state.get("test_episodes", {}).items():  # none saved before them
            self._test_holds[int(ui)].load_state(st)
        self._matrices = [
            (*m[:5], IsolationHold.from_state(st))
            for m, st in zip(self._matrices, state["isolation"], strict=True)
        ]
        for u in self._units:
            u.outside.load_state(
                {
                    "since": state["outside"].get(u.name, {}),
                    "gone": state.get("gone", {}).get(u.name, {}),
                }
            )
        for u in self._units:  # a valve named at its limit (states saved before it: none)
            st = state.get("saturation", {}).get(u.name)
            if st is not None and getattr(u, "saturation", None) is not None:
                u.saturation.load_state(st)
        for key, guards in (("settle", self._settle), ("transients", self._transients)):
            for ui, (g, _) in guards.items():  # states saved before it: from rest
                st = state.get(key, {}).get(self._units[ui].name)
                if st is not None:
                    g.load_state(st)
        for key, guards in (("fixed", self._fixed), ("combos", self._combos)):
            for ui, (g, _) in guards.items():  # states saved before it: from rest
                st = state.get(key, {}).get(self._units[ui].name)
                if st is not None:
                    g.load_state(st)
        for n in self.slow:
            self.units[n].reset().load_state(state["slow"][n])
        return self

    # ------------------------------------------------------------ one cycle
    def cycle(self, ts: pd.Timestamp, values: Mapping[str, float] | pd.Series) -> list[UnitStatus]:
        """Evaluate every unit on one sample (``values``: plant tag → value, NaN or absent for
        missing, stale or bad quality); returns one :class:`UnitStatus` per unit, broken ones
        included. Consecutive calls must be consecutive sampling periods."""
        ts = pd.Timestamp(ts)
        vec = np.full(self._hist.shape[1], np.nan)
        get = values.get
        for tag, i in self.tag_index.items():
            v = get(tag)
            if v is not None:
                vec[i] = float(v)
        self._hist = np.roll(self._hist, 1, axis=0)
        self._hist[0] = vec
        if self._derived is not None:  # the derived inputs' columns (derived.py)
            self._derived.update(self._hist, ts)
        self._cycles += 1
        self._ts = ts
        out = self._fast_cycle(ts) if self.slots else []
        if self.slow:
            row = pd.DataFrame({t: [float(values.get(t, np.nan))] for t in self.tags}, index=[ts])
            for n in self.slow:
                try:
                    out.append(self.units[n].evaluate(row).at(-1))
                except Exception as exc:  # noqa: BLE001 - one unit's failure stays local
                    out.append(broken_status(n, ts, f"evaluation failed: {exc}"))
        for n, problems in self.broken.items():
            out.append(broken_status(n, ts, "; ".join(problems)))
        return out

    def _fast_cycle(self, ts: pd.Timestamp) -> list[UnitStatus]:
        n = len(self.slots)
        yhat = np.full(n, np.nan)
        factor = np.ones(n)
        have = self._cycles - 1  # lags beyond the history seen so far are missing
        if self._stack is not None:
            X = self._hist[self._wm_lags, self._wm_cols]
            X[self._wm_lags > have] = np.nan
            pred = self._stack.predict_detail(self._wm_which, X)
            yhat[self._wm_slots] = supported(pred, self._min_support[self._wm_slots])
            lv = pred.level.astype(np.intp)
            ok = (lv >= 0) & (lv < self._levels.shape[1])
            got = self._levels[self._wm_slots, np.clip(lv, 0, self._levels.shape[1] - 1)]
            factor[self._wm_slots] = np.where(ok, got, np.nan) * np.where(
                self._spread[self._wm_slots], spread_factor(pred.spread), 1.0
            )
        for model, idx, lags, cols in self._groups:
            X = self._hist[lags, cols]
            X[(lags > have)] = np.nan
            ok = ~np.isnan(X).any(axis=1)
            if ok.any():
                try:
                    pred = model.predict_detail(X[ok])
                    yhat[idx[ok]] = supported(pred, self._min_support[idx[ok]])
                except Exception as exc:  # noqa: BLE001 - a broken model: its tests unknown
                    if id(model) not in self._failing:  # once per model, not every cycle
                        self._failing.add(id(model))
                        tests = ", ".join(self._slot_label(i) for i in idx)
                        log.warning("model prediction failed (%s unknown): %r", tests, exc)
        y = self._hist[self._out_lag, self._out_col]
        y[self._out_lag > have] = np.nan
        r = (y - yhat) / self._scale * 100.0 / factor  # Kościelny et al., eq. 6; levels
        if self._manual is not None:  # a hand valve outside its span: its tests unknown
            self._manual.blank(r, self._hist)
        for cm, cols, idx, center, scale in self._level_points:  # Unit.at_points
            p = 0
            if cols is not None:  # the operating point of this cycle's readings
                p = cm.nearest_point(np.where(cols >= 0, self._hist[0, cols], np.nan)[None, :])[0]
            r[idx] = (r[idx] - center[p]) / scale[p]
        s = np.full(n, np.nan)
        for idx, long, pin, valve in self._longs:  # a release reads its raw residual
            sp = long.transform(r[idx][None, :])
            act = np.where(valve >= 0, self._hist[0, valve], np.nan)[None, :]
            self._long[idx] = pin.mask(sp, act)[0]  # unknown where its valve is pinned
        for idx, spread in self._spreads:  # a spread test judges its residual's running spread
            self._raw_known[idx] = np.isfinite(r[idx])
            r[idx] = spread.transform(r[idx][None, :])[0]
            self._spread_left[idx] = spread.left_[0]
        rf = r.copy()
        opens = self._openings()
        self._opens = opens  # the combined test's hold reads them (_statuses)
        for idx, lp, band, delay, hold, swing in self._stages:
            x = r[idx][None, :]
            if lp is not None:
                x = lp.transform(x)
            rf[idx] = x[0]
            raw = band.transform(x, self._lo[idx], self._hi[idx])
            raw[:, self._no_th[idx]] = np.nan
            d = delay.transform(raw)
            rel = np.flatnonzero(np.isfinite(self._release[idx]))
            if rel.size:  # a spread test on held while its long window's spread is unusual
                at = idx[rel]
                kept, left = self._released[at], self._rel_left[at]
                fcols, fwhich = self._rel_map(idx, at)
                d = _release_kernel(np.ascontiguousarray(d, float), rel.astype(np.int64),
                                    self._long[at][None, :], self._release[at], kept, opens,
                                    self._slot_unit[idx], left, fcols, fwhich)  # fmt: skip
                self._released[at], self._rel_left[at] = kept, left
            d = swing.transform(d, opens, self._slot_unit[idx])
            held = self._held[idx]
            run = self._run[idx]
            d = _hold_kernel(np.ascontiguousarray(d), hold, held, run)
            self._held[idx], self._run[idx] = held, run
            s[idx] = d[0]
        if self._latch.any():
            on = self._latch & (self._latched == 0) & (np.nan_to_num(s) != 0)
            self._latched[on] = s[on]
            s = np.where(self._latch & (self._latched != 0), self._latched, s)
        return self._statuses(ts, rf, s)

    def _rel_map(self, idx: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A stage's followers for the release kernel (cached): the positions in ``idx`` of
        the slots that raise a spread slot's hold, and that slot's position in ``at``."""
        key = id(idx)
        if key not in self._rel_maps:
            pos = {int(a): k for k, a in enumerate(at)}
            src = self._follows[idx]
            f = [(p, pos[int(x)]) for p, x in enumerate(src) if int(x) in pos]
            self._rel_maps[key] = (np.array([p for p, _ in f], np.int64),
                                   np.array([k for _, k in f], np.int64))  # fmt: skip
        return self._rel_maps[key]

    def _openings(self) -> np.ndarray:
        """Per unit the bound in samples of a settle a set-point step opens on this cycle
        (0: none; :meth:`~.settle.SettleGuard.openings`), one row: what each slot's
        oscillation hold reads as its unit's known transient (as ``Unit._openings``)."""
        out = np.zeros((1, len(self._units)), np.int64)
        for ui, (g, cols) in self._transients.items():
            out[0, ui] = g.openings(self._hist[0, cols][None, :])[0]
        return out

    def _slot_label(self, i: int) -> str:
        """``unit.test`` of slot ``i``."""
        u = self._units[self.slots[i].unit]
        return f"{u.name}.{u.tests[self.slots[i].test]}"

    def _statuses(self, ts: pd.Timestamp, r: np.ndarray, s: np.ndarray) -> list[UnitStatus]:
        units = self._units
        nu = len(units)
        su = self._slot_unit
        known = ~np.isnan(s)
        fresh = known & ~np.isnan(r)  # evaluated on this sample, not held over a gap
        active_slot = np.nan_to_num(s) != 0
        active = np.bincount(su, weights=active_slot, minlength=nu) > 0
        n_known = np.bincount(su, weights=known, minlength=nu)
        n_tests = np.bincount(su, minlength=nu)
        all_known = n_known == n_tests
        tests_on = active.copy()
        c_on = np.zeros(nu, bool)
        multi: dict[int, tuple] = {}
        for ui, cm, delay, enabled in self._multi:
            a = self._first[ui]
            point = None
            if ui in self._point_cols:  # the operating point of this cycle's readings
                cols = self._point_cols[ui]
                x = np.where(cols >= 0, self._hist[0, cols], np.nan)[None, :]
                point = cm.nearest_point(x)
            b = a + len(units[ui].tests)
            t2, share = cm.evaluate(r[a:b][None, :], point)
            ru, sr = r[a:b][None, :], s[a:b][None, :]
            share = units[ui].test_names.name(share, ru, sr)  # a kept-out test: its tags
            on_v = units[ui].test_names.on_values(ru, sr)  # any test on (TestNames.fill)
            if ui in self._ex_cols:  # a measured input beyond what the unit learned
                ex_cols = self._ex_cols[ui]
                named = units[ui].excursions.name(
                    share, ru, sr, lambda t, c=ex_cols: self._hist[0, [c[t]]] if c[t] >= 0
                    else np.array([np.nan]), np.ones(1, bool),
                )  # fmt: skip
                share = units[ui].test_names.fill_named(named, share, on_v)
            s_t2 = np.nan
            if enabled and cm.high is not None:
                raw = np.nan if np.isnan(t2[0]) else float(t2[0] > cm.high)
                s_t2 = float(delay.transform(np.array([[raw]]))[0, 0])
                if ui in self._t2_rel:  # as Unit: ReleaseHold.combined
                    k = self._t2_rel[ui]
                    with np.errstate(invalid="ignore"):
                        q = self._long[k] / self._release[k]
                    ratio = np.array([np.where(np.isnan(q), -np.inf, q).max()])
                    held, left = self._t2_held[ui : ui + 1], self._t2_left[ui : ui + 1]
                    s_t2 = float(combined_release(np.array([[s_t2]]), ratio,
                                                  np.ascontiguousarray(self._opens[:, ui : ui + 1]),
                                                  held, left)[0])  # fmt: skip
                c_on[ui] = np.nan_to_num(s_t2) != 0
            multi[ui] = (t2[0], s_t2, share[0], on_v[0], cm.tags)
        active = active | c_on
        status = np.where(
            active, NE107.OFF_SPEC, np.where(all_known, NE107.NORMAL, NE107.CHECK_FUNCTION)
        ).astype(np.int8)
        all_fresh = np.bincount(su, weights=fresh, minlength=nu) == n_tests
        quality = np.where(
            all_fresh, Quality.GOOD, np.where(n_known > 0, Quality.UNCERTAIN, Quality.BAD)
        )
        certs: list[dict[str, float]] = [{} for _ in range(nu)]
        faults: list[list[str]] = [[] for _ in range(nu)]
        matrix_of: dict[int, tuple] = {}  # unit → its matrix and its tests' slots
        for mx, uis, cols, certainty, hold, isolation in self._matrices:
            sm = s[cols]  # units × tests (matrix order)
            c = mx.nearest(sm).certainties
            on = tests_on[uis]  # the combined test alone isolates nothing (Unit.certainties)
            c = np.where(on[:, None], c, 0.0)
            cz = np.nan_to_num(c, nan=0.0)
            best = cz.max(axis=1, keepdims=True)
            iso = on[:, None] & (cz >= certainty[:, None] - 1e-12) & (cz >= best - 1e-12)
            held = isolation.transform(iso[None], sm[None])[0]
            iso = np.where(hold[:, None], held, iso)
            for k, ui in enumerate(uis):
                u = units[ui]
                matrix_of[ui] = (mx, cols[k])
                certs[ui] = dict(zip(mx.faults, c[k].tolist(), strict=True))
                if iso[k].any():
                    names = [f for f, i in zip(mx.faults, iso[k], strict=True) if i]
                    faults[ui] = names
                    st = [u.file.fault_status.get(f, NE107.FAILURE) for f in names]
                    status[ui] = min(st, key=PRIORITY.index)
        tags: list[list[tuple[str, float]]] = [[] for _ in range(nu)]
        notes: list[list[str]] = [[] for _ in range(nu)]
        for ui, (t2, _s_t2, share, on_v, names) in multi.items():
            alarm = np.array([active[ui]])
            held = self._holds[ui].transform(share[None, :], alarm)
            held_on = self._test_holds[ui].transform(on_v[None, :], alarm)
            held = units[ui].test_names.fill(held, held_on)[0]
            if active[ui]:
                tags[ui] = _top(held, names, units[ui].untested)
            if c_on[ui]:
                notes[ui].append(f"combined test on (T² {t2:.3g})")
            if tags[ui]:
                notes[ui].append("tags: " + ", ".join(f"{t} {v:.2f}" for t, v in tags[ui]))
            u = units[ui]
            # the combined test alone, or (exact_only) symptoms no column explains
            if not faults[ui] and (u.exact_only and active[ui] or c_on[ui] and not tests_on[ui]):
                status[ui] = NE107.FAILURE
                faults[ui] = [tags[ui][0][0]] if u.tag_isolation and tags[ui] else ["unit"]
            elif faults[ui] and tags[ui] and u.exact_only:  # Unit.evaluate: with_ranked
                mx, at = matrix_of[ui]
                f = with_ranked(
                    mx,
                    np.array(["|".join(faults[ui])], object),
                    np.array([tags[ui][0][0]], object),
                    s[at][None, :],
                )
                faults[ui] = f[0].split("|")
        index = self.tag_index

        def value(tag: str, lag: int = 0) -> float:  # what a model reads, lag cycles back
            return float(self._hist[lag, index[tag]]) if tag in index else np.nan

        saturated = self._saturated_units(s, active, faults, tags, notes, value)
        # Unit.evaluate: [fixed] and [states] before the off-delay, which repeats only an
        # alarm the unit shows
        fixed = self._fixed_units(ts, status, faults, tags, notes, self._fixed)
        combos = self._fixed_units(ts, status, faults, tags, notes, self._combos)
        unknown = np.zeros(nu, bool)
        unknown[list({*fixed, *combos})] = True
        det_held = self._hold_alarms(active, status, faults, tags, notes, unknown)
        settling = self._settle_units(ts, r, active, det_held, status, faults)
        out = []

        for ui, u in enumerate(units):
            a = self._first[ui]
            b = a + len(u.tests)
            # CHECK_FUNCTION's reason, as Unit.evaluate gives it (its excursions carried);
            # a unit not in CHECK_FUNCTION with every input inside its ranges has none (1 ms a
            # unit saved: 100 units over 5,000 tags cost 147 ms a cycle, was 34 ms)
            why = ""
            checking = status[ui] == NE107.CHECK_FUNCTION
            if checking or not u.outside.idle(value):
                # the reason without a frame: the unit's judged inputs as one-value arrays
                cols = {key: np.array([value(p, key[1])]) for key, p in self._judged[ui]}
                unknown = np.isnan(s[a:b])[None, :]
                warm, left = warm_up(
                    unknown,
                    self._raw_known[a:b][None, :],
                    self._cycles - 1,
                    self._slot_depth[a:b],
                    self._spread_left[a:b][None, :],
                    self._spread_test[a:b],
                )
                report = np.array([checking])
                why = u.outside.columns(cols, [ts], unknown & ~warm, report)
                if warm.any():
                    why = warming_up(why, warm, left, report, self._labels[ui], u.period_s)
                why = why[0]
            if ui in settling:  # Unit.evaluate: the settle's text first
                why = f"{settling[ui]}; {why}" if why else settling[ui]
            if ui in saturated:  # Unit.evaluate: a valve at its limit (after [fixed], [states])
                why = f"{saturated[ui]}; {why}" if why else saturated[ui]
            for said in (combos, fixed):  # Unit.evaluate: the states in a combination never
                if ui in said:  # learned, a constant tag moved: their texts first
                    why = f"{said[ui]}; {why}" if why else said[ui]
            if det_held[ui] and status[ui] != NE107.CHECK_FUNCTION:  # an alarm held on
                why = f"{why}; {held_text(u.ev)}" if why else held_text(u.ev)
            msg = "; ".join([why, *notes[ui]] if why else notes[ui])
            st = NE107(int(status[ui]))
            if not self._has_th[ui]:
                st, msg = NE107.CHECK_FUNCTION, f"no thresholds: run `diag unit learn {u.name}`"
                msg = "; ".join([msg, *notes[ui]])
            det = None if not active[ui] and not all_known[ui] else bool(active[ui])
            if det_held[ui]:
                det = True
            if ui in fixed or ui in combos:  # the diagnosis unknown (Unit.evaluate: NaN)
                det = None
            out.append(
                UnitStatus(
                    unit=u.name,
                    ts=ts,
                    status=st,
                    quality=Quality(int(quality[ui])),
                    residuals=dict(zip(u.tests, r[a:b].tolist(), strict=True)),
                    symptoms=dict(zip(u.tests, s[a:b].tolist(), strict=True)),
                    certainties=certs[ui],
                    detected=det,
                    faults=faults[ui],
                    message=msg,
                    tags=tags[ui],
                )
            )
        return out

    def _saturated_units(self, s, active, faults, tags, notes, value) -> dict[int, str]:
        """Each unit's loop valve at its limit on this cycle (:mod:`~.saturation`, as
        :meth:`Unit.evaluate` names it), in place on ``faults``, ``tags`` and the ``tags:``
        note: per unit whose valve is named, the why."""
        out = {}
        for ui, u in enumerate(self._units):
            sat = getattr(u, "saturation", None)
            if sat is None:
                continue
            a = self._first[ui]
            row = _OneRow({lp.model_tag: value(lp.actuator) for lp in sat.loops})
            on = (np.nan_to_num(s[a : a + len(u.tests)]) != 0)[None, :]
            which, text, first = sat.transform(row, on, np.array([bool(active[ui])]))
            if which[0] < 0:
                continue
            act = sat.loops[which[0]].actuator
            if first[0]:
                faults[ui] = [act]
            ranked = dict(tags[ui]) if tags[ui] else {}
            if tags[ui] and (first[0] or act not in ranked):
                # first, or (giving way to another tag's test) listed second: as name_first
                rest = [x for x in tags[ui] if x[0] != act]
                at = 0 if first[0] or not rest else 1
                fill = tags[ui][at][1] if at < len(tags[ui]) else rest[-1][1]
                rest.insert(at, (act, ranked.get(act, fill)))
                tags[ui] = rest[: len(tags[ui]) if first[0] else max(len(tags[ui]), 2)]
                notes[ui] = [
                    "tags: " + ", ".join(f"{t} {v:.2f}" for t, v in tags[ui])
                    if n.startswith("tags: ")
                    else n
                    for n in notes[ui]
                ]
            out[ui] = str(text[0])
        return out

    def _settle_units(self, ts, r, active, det_held, status, faults) -> dict[int, str]:
        """The units' settle guards (:mod:`~diag_plugin.diagnose.settle`) on this cycle, in
        place on ``status`` and ``faults``: per unit whose alarm is suppressed, the why."""
        out = {}
        index = pd.DatetimeIndex([ts])
        for ui, (g, cols) in self._settle.items():
            a = self._first[ui]
            u = None
            if g.envelope is not None:  # a start's envelope (envelope.py) reads every test
                lo, hi = self._units[ui]._limits()
                u = scaled(r[a : a + lo.size], lo, hi)[None, :]
            sup, why = g.transform(
                index,
                self._hist[0, cols][None, :],
                r[a + g.tests][None, :],
                active[ui : ui + 1],
                np.array([bool(active[ui] or det_held[ui])]),
                u,
            )
            if sup[0]:
                status[ui], faults[ui], out[ui] = NE107.CHECK_FUNCTION, [], why[0]
            elif why[0]:  # the alarm an envelope raised: its why
                out[ui] = why[0]
        return out

    def _fixed_units(self, ts, status, faults, tags, notes, guards) -> dict[int, str]:
        """The units' constant-tag guards (:mod:`~diag_plugin.diagnose.fixed`) or state
        combination guards (:mod:`~diag_plugin.diagnose.combos`) on this cycle, in place on
        ``status``, ``faults`` and the tags named: per unit held, the why."""
        out: dict[int, str] = {}
        for ui, (g, cols) in guards.items():
            x = self._hist[0, cols]
            if g.idle(x):  # every tag at its value, none in a run outside: nothing to do
                continue
            held, why = g.transform(pd.DatetimeIndex([ts]), x[None, :])
            if held[0]:
                status[ui], faults[ui], tags[ui], out[ui] = NE107.CHECK_FUNCTION, [], [], why[0]
                notes[ui] = [n for n in notes[ui] if not n.startswith("tags: ")]
        return out

    def _hold_alarms(
        self,
        active: np.ndarray,
        status: np.ndarray,
        faults: list[list[str]],
        tags: list[list[tuple[str, float]]],
        notes: list[list[str]],
        unknown: np.ndarray,
    ) -> np.ndarray:
        """The units' own off-delay (:class:`~diag_plugin.diagnose.unitloops.AlarmHold`), in
        place: a unit out of alarm for fewer than its off-delay's samples repeats its last
        alarm sample's status, faults and tags. Returns where a unit was held. ``unknown``:
        the units made CHECK_FUNCTION by ``[fixed]`` or ``[states]`` on this cycle (already
        applied): an alarm there is not shown, so neither repeated nor repeating."""
        has = self._alarm_hold.off > 0
        if not has.any():
            return np.zeros(len(has), bool)
        active = active & ~unknown
        held = self._alarm_hold.sources(active[None, :])[0] == -1  # one row: the last cycle's
        for ui in np.flatnonzero(held):
            last = self._last_alarm.get(int(ui))
            if last is None:
                held[ui] = False
                continue
            if unknown[ui]:  # held, but its diagnosis unknown (Unit.evaluate: CHECK_FUNCTION)
                continue
            status[ui], faults[ui], tags[ui] = last[0], list(last[1]), list(last[2])
            notes[ui] = [n for n in notes[ui] if not n.startswith("tags: ")]
            if tags[ui]:
                notes[ui].append("tags: " + ", ".join(f"{t} {v:.2f}" for t, v in tags[ui]))
        for ui in np.flatnonzero(has & active):
            self._last_alarm[int(ui)] = (int(status[ui]), list(faults[ui]), list(tags[ui]))
        return held


def _manual_guard(units: list[Unit], slots: list[_Slot], tags: dict[str, int]) -> PlantGuard | None:
    """Every unit's hand-valve guard (:class:`~diag_plugin.diagnose.manual.ManualGuard`) on
    the fast path's slots (``tags``: plant tag → column); None where no unit has one."""
    rows, valves, first = [], [], 0
    for ui, u in enumerate(units):
        if u.manual is not None:
            got, vs = u.manual.slots(first, [s.inputs for s in slots[first:]],
                                     lambda t, u=u: tags[u.file.tags.get(t, t)],
                                     [s.output for s in slots[first:]])  # fmt: skip
            rows.extend(got)
            valves.append((ui, vs))
        first += len(u.tests)
    if not rows:
        return None
    return PlantGuard(rows, valves, np.array([s.unit for s in slots], np.intp))


def _after(cols: np.ndarray, n_tags: int) -> np.ndarray:
    """Columns with each derived feature's ``−1 − number`` turned into its column after the
    ``n_tags`` tags' (:class:`~diag_plugin.diagnose.derived.DerivedInputs`)."""
    return np.where(cols < 0, n_tags - 1 - cols, cols)


def _top(share: np.ndarray, names: list[str], untested=None) -> list[tuple[str, float]]:
    """The top tags by share, as :func:`~diag_plugin.diagnose.unittags.top_tags` ranks them
    (``untested``: the unit's :class:`~diag_plugin.diagnose.unittags.Untested`)."""
    from diag_plugin.diagnose.unittags import TOP, rank

    s = np.nan_to_num(np.atleast_2d(share), nan=-1.0)
    key = untested.key(s) if untested is not None else None
    order = rank(s if key is None else key)[0, :TOP]
    s = s[0]
    return [(names[k], float(s[k])) for k in order if s[k] > 0]


def _matrix_key(u: Unit) -> tuple:
    mx = u.matrix
    assert mx is not None
    return (
        tuple(mx.tests),
        tuple(mx.faults),
        tuple(map(tuple, mx.entries.tolist())),
        tuple(u.tests),
    )


def _versions(units: Mapping[str, Unit]) -> dict[str, str]:
    """See :meth:`Plant.versions`."""
    out = {}
    for name, u in units.items():
        h = hashlib.sha256()
        for f in [u.file.path, *(m.path for m in u.models.values()), u.file.matrix_path]:
            h.update(str(Path(f).name).encode() if f is not None else b"-")
            h.update(Path(f).read_bytes() if f is not None and Path(f).exists() else b"-")
        out[name] = h.hexdigest()
    return out


def _json(a: np.ndarray) -> list:
    """An array as nested lists, NaN as None (JSON has no NaN)."""
    x = np.asarray(a, float)
    return np.where(np.isnan(x), None, x.astype(object)).tolist()


def _array(v: list) -> np.ndarray:
    """Back from :func:`_json`."""
    a = np.array(v, dtype=object)
    return np.where(a == None, np.nan, a).astype(float)  # noqa: E711 - elementwise


class _OneRow:
    """One cycle's readings as :class:`~.unit.Columns` gives a piece's: ``values(tag)``."""

    def __init__(self, row: dict[str, float]) -> None:
        self.row = row

    def values(self, tag: str) -> np.ndarray:
        return np.array([self.row.get(tag, np.nan)], float)
