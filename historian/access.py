"""Historian access for the workbench and training jobs.

Small functions that open the historian, read an aligned window with the
tags' metadata, and log experiments; the callers (CLI commands) stay free of
database code.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field

import pandas as pd

from historian.sampling import Sampling
from historian.store import Historian
from historian.taginfo import TagInfo


def tag_info(h: Historian) -> dict[str, TagInfo]:
    """Tag → :class:`TagInfo` from the tags table."""
    return {
        str(row["name"]): TagInfo.from_mapping(str(row["name"]), row)
        for row in h.tags().to_dict("records")
    }


def open_data(
    url: str,
    tags: Sequence[str] | None,
    start: pd.Timestamp | None,
    end: pd.Timestamp | None,
    period: str,
) -> tuple[pd.DataFrame, dict[str, TagInfo]]:
    """Aligned frame of ``tags`` (all tags if None) on a ``period`` grid, plus tag metadata."""
    with Historian.open(url) as h:
        info = tag_info(h)
        names = list(tags) if tags else sorted(info)
        unknown = [t for t in names if t not in info]
        if unknown:
            raise KeyError(
                f"tag(s) {', '.join(unknown)} not in the historian {url} "
                f"(it has: {', '.join(sorted(info)) or 'no tags'}); diag import a file first"
            )
        if not names:
            raise ValueError(f"the historian {url} holds no tags: diag import a file first")
        a, b = h.time_range(names)
        if a is None:
            raise ValueError(f"no samples of {', '.join(names)} in {url}")
        start = start or a
        end = end or (b + pd.Timedelta(period))
        frame = h.window(names, start, end, period)
    return frame, info


def tag_sampling(
    url: str, tags: Sequence[str], start: pd.Timestamp | None = None, end=None
) -> dict[str, Sampling]:
    """How each tag is sampled over [start, end) (all its data when open): the median and
    95th-percentile spacing of its stored samples."""
    with Historian.open(url) as h:
        known = set(h.tags()["name"])
        unknown = [t for t in tags if t not in known]
        if unknown:
            raise KeyError(
                f"tag(s) {', '.join(unknown)} not in the historian {url} "
                f"(it has: {', '.join(sorted(known)) or 'no tags'}); diag import a file first"
            )
        return h.sampling(tags, start, end)


@dataclass
class WindowReader:
    """A picklable ``read(a, b)`` over the historian (Dask workers open their own connection).
    ``historian``: an open historian of ``url`` to read through (its owner closes it; a
    pickled reader opens its own)."""

    url: str
    tags: tuple[str, ...]
    period: str
    historian: Historian | None = field(default=None, repr=False, compare=False)

    def __post_init__(self) -> None:
        self._h: Historian | None = self.historian

    def __call__(self, a: pd.Timestamp, b: pd.Timestamp) -> pd.DataFrame:
        if self._h is None:  # one connection per process, opened on first use
            self._h = Historian.open(self.url)
        return self._h.window(list(self.tags), a, b, self.period, summary=False)

    def close(self) -> None:
        if self._h is not None and self._h is not self.historian:
            self._h.close()
        self._h = self.historian

    def __getstate__(self) -> dict:  # a Dask worker opens its own connection
        return {"url": self.url, "tags": self.tags, "period": self.period}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state, historian=None, _h=None)


def experiments(url: str, model: str) -> pd.DataFrame:
    """The experiment log of a model, one row per version, metrics as columns."""
    with Historian.open(url) as h:
        df = h.experiments(model)
    if df is None or len(df) == 0:
        return pd.DataFrame(columns=["version", "created_at", "inputs", "rmse_pct"])
    df = df.copy()
    if "metrics" in df.columns:
        m = pd.DataFrame([_as_dict(v) for v in df["metrics"]], index=df.index)
        for c in m.columns:
            if c not in df.columns:
                df[c] = m[c]
    if "inputs" in df.columns:
        df["inputs"] = [_as_list(v) for v in df["inputs"]]
    return df


def _as_dict(v) -> dict:
    if isinstance(v, dict):
        return v
    if isinstance(v, str):
        try:
            return json.loads(v)
        except ValueError:
            return {}
    return {}


def _as_list(v) -> list:
    if isinstance(v, list | tuple):
        return list(v)
    if isinstance(v, str):
        try:
            out = json.loads(v)
            return out if isinstance(out, list) else [v]
        except ValueError:
            return [v]
    return []
