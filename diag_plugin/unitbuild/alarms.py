"""The unit's off-delay from its tags and ISA-18.2's alarm rules (issue 34, item 6).

ISA-18.2 sets an alarm's off-delay by what its signal measures; the usual starting values
(the alarm-design report ISA-TR18.2.3, by signal type) are :data:`ISA_OFF_DELAY_S`: 15 s for
a flow or a pressure, 60 s for a level or a temperature. A unit raises one alarm for all
of its tests, so its off-delay is the longest of its tested tags' (:func:`isa_off_delay`);
a tag whose kind its name, description and unit do not tell (a vibration, a current, a
valve position) takes the range's upper end, :data:`ISA_OTHER_S`. The build keeps at
least the grid's own delay (three samples, :func:`~diag_plugin.unitbuild.build.
evaluation_for`): on a grid of minutes the samples are already averages over the period and
ISA's seconds are under one of them (3 min: 540 s, as before; 1 min: 180 s, 240 before).

Chatter (more than 3 episodes of one fault in :data:`~diag_plugin.unitbuild.build.
CHATTER_WINDOW_S`): a test's symptom stays on ``off`` samples after its residual is back
(:class:`~diag_plugin.diagnose.symptoms.OnOffDelay`) and the unit's alarm ``off`` samples more
(:class:`~diag_plugin.diagnose.unitloops.AlarmHold`), so two of the unit's alarm episodes
begin at least ``2 × off`` apart (:func:`chatter_note`). Where four such spacings fit in the
window (``3 × 2 × off`` under it: at 1 s and 15 s with ISA's delays) chatter is not ruled
out by the delays alone; a residual hovering at its threshold is held by the deadband and a
swing across both thresholds by the oscillation hold (:mod:`~diag_plugin.diagnose.unitloops`),
and the tests count the episodes (``tests/test_unit_loops.py``, ``tests/test_unit_offdelay.py``).
The build also writes the re-alarm hold (issue 34 H1, :func:`~diag_plugin.unitbuild.build.
realarm_off_delay`): an alarm raised again within the chatter window of its last end is held
the window, so no alarm raises more than 2 in it, while a first alarm keeps ISA's delay.
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping

from historian.taginfo import TagInfo

#: ISA-18.2's usual off-delays by what a tag measures (seconds)
ISA_OFF_DELAY_S = {"flow": 15.0, "pressure": 15.0, "level": 60.0, "temperature": 60.0}
#: the off-delay of a tag of another or an unknown kind: the upper end of ISA's usual range
ISA_OTHER_S = 60.0

_TEMPERATURE_UNITS = {"°c", "degc", "°f", "degf", "k", "°k"}
_ISA_T = re.compile(r"T[A-Z]{0,3}[-_ ]?\d+[A-Z]?", re.IGNORECASE)


def measured_kind(tag: str, info: TagInfo | None = None) -> str | None:
    """What ``tag`` measures as ISA-18.2's delays tell kinds apart: ``flow``, ``level`` or
    ``pressure`` (:func:`~diag_plugin.unitbuild.balance.tag_kind`), ``temperature`` (an
    ISA-5.1 name with ``T`` first, a description naming a temperature, a temperature's
    unit), None for anything else."""
    from diag_plugin.diagnose.unittags import is_set_point
    from diag_plugin.unitbuild.balance import tag_kind

    kind = tag_kind(tag, info)
    if kind is not None:
        return kind
    text = (info.description if info else "").lower()
    unit = (info.unit if info else "").strip().lower().replace(" ", "")
    if is_set_point(tag, info) or "output" in text or "valve" in text:
        return None
    if _ISA_T.fullmatch(tag.strip()) or "temperature" in text or unit in _TEMPERATURE_UNITS:
        return "temperature"
    return None


def isa_off_delay(
    tags: Iterable[str], info: Mapping[str, TagInfo | None]
) -> tuple[float, dict[str, list[str]]]:
    """The unit's off-delay by ISA-18.2 (seconds): the longest of its ``tags``' usual
    off-delays (:data:`ISA_OFF_DELAY_S`, :data:`ISA_OTHER_S` for another kind), and the tags
    per kind (``other`` for the rest) for the build's note. No tag: :data:`ISA_OTHER_S`."""
    kinds: dict[str, list[str]] = {}
    for t in tags:
        kinds.setdefault(measured_kind(t, info.get(t)) or "other", []).append(t)
    if not kinds:
        return ISA_OTHER_S, kinds
    return max(ISA_OFF_DELAY_S.get(k, ISA_OTHER_S) for k in kinds), kinds


def chatter_free(off_s: float, window_s: float) -> bool:
    """Whether the delays alone rule chatter out: the unit's alarm episodes begin at least
    ``2 × off_s`` apart (a test's off-delay, then the unit's hold), so more than 3 of them
    in ``window_s`` need three such spacings inside it."""
    return 3 * 2 * off_s >= window_s


def chatter_note(off_s: float, on_s: float, grid_s: float, isa_s: float,
                 kinds: Mapping[str, list[str]], window_s: float,
                 realarm_s: float = 0.0) -> str:  # fmt: skip
    """The build's note on the off-delay it chose (``off_s``) and why; ``realarm_s``: the
    re-alarm hold of an alarm raised again within ``window_s`` of its last end (0: none)."""
    said = "; ".join(
        f"{k} {ISA_OFF_DELAY_S.get(k, ISA_OTHER_S):g} s ({', '.join(v[:4])}"
        f"{', …' if len(v) > 4 else ''})"
        for k, v in sorted(kinds.items())
    )
    why = (
        f"ISA-18.2's off-delay for the unit's tags, the longest of theirs ({said})"
        if off_s == isa_s
        else f"the grid's own delay (3 samples of {grid_s:g} s), longer than ISA-18.2's "
        f"{isa_s:g} s for the unit's tags ({said})"
    )
    if realarm_s >= window_s > 0:
        chatter = (
            f"an alarm raised again within {window_s:g} s of its last end is held "
            f"{realarm_s:g} s (realarm_off_delay_s), so no alarm raises more than 2 in "
            f"{window_s:g} s"
        )
    elif chatter_free(off_s, window_s):
        chatter = (
            f"two alarm episodes begin at least {2 * off_s:g} s apart (the test's off-delay, "
            f"then the unit's), so no fault raises more than 3 in {window_s:g} s"
        )
    else:
        chatter = (
            f"two alarm episodes begin at least {2 * off_s:g} s apart (the test's off-delay, "
            f"then the unit's): more than 3 in {window_s:g} s are not ruled out by the delays "
            "alone; a residual hovering at its threshold is held by the deadband, a swing "
            "across both thresholds by the oscillation hold"
        )
    return (
        f"off_delay_s = {off_s:g} s (on-delay {on_s:g} s): {why}; an alarm ends "
        f"{off_s:g}–{2 * off_s:g} s after its fault; {chatter}"
    )
