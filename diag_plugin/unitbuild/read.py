"""The historian's window of a build read by shares of its tags on every core (issue 34,
speed).

:func:`~diag_plugin.unitbuild.build.build_from_historian` reads every raw sample of every tag
twice — the tags' sampling (:func:`historian.access.tag_sampling`, the grid period from the
data) and the window on the grid (:func:`historian.access.open_data`) — and each tag's read
and alignment is its own (:meth:`historian.store.Historian.window` aligns each tag straight
into its row of the frame). So the tags are cut into one contiguous share per worker, each
share read by a worker process through its own connection, and the shares joined in the
tags' order: the same sampling and the same frame as one read of every tag (the build's
parent spent ~3 CPU s of a 200-tag window in these two reads alone).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import pandas as pd

from historian.sampling import Sampling
from historian.taginfo import TagInfo

#: ``mapper(fn, items, args)``: ``[fn(item, *args) for item in items]`` in the tags' order
Mapper = Callable[[Callable[..., Any], Sequence[Any], tuple], list[Any]]


def shares(tags: Sequence[str], n: int) -> list[list[str]]:
    """``tags`` cut into at most ``n`` contiguous shares of nearly equal size, in order."""
    n = max(1, min(int(n), len(tags)))
    size, extra = divmod(len(tags), n)
    out, at = [], 0
    for i in range(n):
        k = size + (1 if i < extra else 0)
        out.append(list(tags[at : at + k]))
        at += k
    return out


def _sampling_share(tags: list[str], url: str, start, end) -> dict[str, Sampling]:
    from historian.access import tag_sampling

    return tag_sampling(url, tags, start, end)


def _window_share(
    tags: list[str], url: str, start, end, period: str
) -> tuple[pd.DataFrame, dict[str, TagInfo]]:
    from historian.access import open_data

    frame, info = open_data(url, tags, start, end, period)
    frame.attrs = {}  # the window's quality summary: the build has no use for it
    return frame, info


def read_sampling(
    url: str, tags: Sequence[str], start, end, n: int, mapper: Mapper
) -> dict[str, Sampling]:
    """:func:`historian.access.tag_sampling` of ``tags`` over ``[start, end)``, ``n``
    shares of the tags read by ``mapper``; in the tags' order."""
    out: dict[str, Sampling] = {}
    for got in mapper(_sampling_share, shares(tags, n), (url, start, end)):
        out.update(got)
    return out


def read_window(
    url: str, tags: Sequence[str], start, end, period: str, n: int, mapper: Mapper
) -> tuple[pd.DataFrame, dict[str, TagInfo]]:
    """:func:`historian.access.open_data` of ``tags`` on the ``period`` grid of ``[start,
    end)`` (its ``attrs`` left empty), ``n`` shares of the tags read by ``mapper`` and
    joined column by column in the tags' order."""
    parts = mapper(_window_share, shares(tags, n), (url, start, end, period))
    info = parts[0][1]  # every share's: the historian's whole tags table
    if len(parts) == 1:
        return parts[0][0], info
    # one block of tags × rows, as Historian.window lays out a single read
    block = np.concatenate([f.to_numpy(float).T for f, _ in parts])
    frame = pd.DataFrame(block.T, index=parts[0][0].index, columns=list(tags), copy=False)
    return frame, info
