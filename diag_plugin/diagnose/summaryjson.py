"""The text of ``diag diagnose --json``: ``json.dumps(summary, indent=2)``, the same bytes,
with the timeline's intervals encoded column by column.

``json.dumps`` with an indent runs the standard library's pure-Python encoder, and the
intervals went through ``DataFrame.to_dict("records")`` first: 6,045 intervals of 200,000 rows
(``benchmarks/bench_diagnose_cli.py``) cost ~0.3 CPU s of the command (issue 34). Here each
column's values are boxed once (``Series.tolist``) and encoded by the encoder's own C string
function, and each record is joined from precomputed ``"key": `` prefixes. A column holding
anything but strings, integers, floats, booleans or None (or a frame whose text could differ
in another way) is left to ``json.dumps`` as before.
"""

from __future__ import annotations

import json
from json.encoder import encode_basestring_ascii
from typing import Any

#: json.dumps's indent, as ``diag diagnose --json`` writes it
INDENT = 2


def summary_text(summary: dict[str, Any], key: str, records) -> str:
    """``json.dumps({**summary, key: rows}, indent=2)`` where ``rows`` is the list of
    ``records`` (a DataFrame) as ``to_dict("records")`` gives it, the values of its time
    columns as their ``isoformat()`` text; ``key`` comes last."""
    records = _times_as_text(records)
    cols = _encoded_columns(records) if len(records) else None
    text = json.dumps({**summary, key: []}, indent=INDENT)
    one, two, three = (" " * (INDENT * k) for k in (1, 2, 3))
    name = encode_basestring_ascii(key)
    tail = f"{one}{name}: []\n}}"
    if cols is None or not text.endswith(tail):  # (not last: ``key`` already in ``summary``)
        return json.dumps({**summary, key: records.to_dict("records")}, indent=INDENT)
    prefixes = [f"{three}{encode_basestring_ascii(k)}: " for k in records.columns]
    first, last = f"{two}{{\n", f"\n{two}}}"
    rows = [
        first + ",\n".join(map(str.__add__, prefixes, row)) + last
        for row in zip(*cols, strict=True)
    ]
    return f"{text[: -len(tail)]}{one}{name}: [\n" + ",\n".join(rows) + f"\n{one}]\n}}"


def _times_as_text(frame):
    """``frame`` with each time column's values as their ``isoformat()`` text: UTC times on
    whole seconds (every interval of a replay at a period of whole seconds) formatted at once
    (:func:`_utc_seconds`), others as before, a Timestamp boxed once per value, as ``to_dict``
    boxes it (31,079 intervals of 1,000,000 rows: 62,158 Timestamps, issue 34)."""
    times = [c for c in frame.columns if frame[c].dtype.kind == "M"]
    if not times:
        return frame
    out = {}
    for c in times:
        text = _utc_seconds(frame[c])
        out[c] = [t.isoformat() for t in frame[c].tolist()] if text is None else text
    return frame.assign(**out)


def _utc_seconds(col) -> list[str] | None:
    """``[t.isoformat() for t in col]`` for a column of UTC times on whole seconds, none
    missing (``2026-06-01T00:03:00+00:00``); None for any other column."""
    import numpy as np

    per_s = {"s": 1, "ms": 1_000, "us": 1_000_000, "ns": 1_000_000_000}.get(col.dt.unit)
    if str(col.dt.tz) != "UTC" or not per_s or col.isna().any():
        return None
    values = col.dt.tz_localize(None).to_numpy()
    if (values.view(np.int64) % per_s).any():
        return None
    return [t + "+00:00" for t in np.datetime_as_string(values, unit="s").tolist()]


def _encoded_columns(frame) -> list[list[str]] | None:
    """Each column's values as ``json.dumps`` writes them; None when a column holds another
    kind of value (left to ``json.dumps``) or a column's name is not text."""
    if not all(type(k) is str for k in frame.columns):
        return None
    out = []
    for name in frame.columns:
        values = frame[name].tolist()
        kinds = set(map(type, values))
        if kinds == {str}:
            out.append(list(map(encode_basestring_ascii, values)))
        elif kinds == {int}:
            out.append(list(map(int.__repr__, values)))
        elif kinds <= {str, int, float, bool, type(None)}:
            out.append(list(map(_scalar, values)))
        else:
            return None
    return out


def _scalar(v: str | int | float | bool | None) -> str:
    """One value as ``json.dumps`` writes it (NaN and infinities as it does)."""
    if isinstance(v, str):
        return encode_basestring_ascii(v)
    if v is None:
        return "null"
    if v is True:
        return "true"
    if v is False:
        return "false"
    if isinstance(v, int):
        return int.__repr__(v)
    if v != v:
        return "NaN"
    if v == float("inf"):
        return "Infinity"
    if v == -float("inf"):
        return "-Infinity"
    return float.__repr__(v)
