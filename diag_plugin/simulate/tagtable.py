"""Tag lists written as text tables, a row a tag (the simulated plants' and rigs' tags).

``TAG | unit | lo | hi | description [| more columns]``: ``lo`` and ``hi`` (the nominal
range) are numbers, every other column is text, kept as written after trimming.
"""

from __future__ import annotations

from historian.taginfo import TagInfo


def tag_table(text: str) -> dict[str, tuple]:
    """``{tag: (unit, lo, hi, description, *more)}`` from the rows of ``text``."""
    out: dict[str, tuple] = {}
    for row in text.strip().splitlines():
        tag, unit, lo, hi, *rest = (c.strip() for c in row.split("|"))
        out[tag] = (unit, float(lo), float(hi), *rest)
    return out


def tag_infos(text: str) -> dict[str, TagInfo]:
    """:func:`tag_table` as ``{tag: TagInfo}`` (five columns: tag, unit, lo, hi, description)."""
    return {tag: TagInfo(tag, *row) for tag, row in tag_table(text).items()}
