"""What every connector speaks: tag samples with a quality, an allow-list for writes, backoff.

Protocol libraries stay behind this interface (DESIGN.md: pymodbus and asyncua at the edge).
A connector reads tags as :class:`TagSample` (value, timestamp, quality) and writes only the
output tags its :class:`AllowList` names. Protocol errors come back as Bad-quality samples,
never as exceptions from deep inside a poll.
"""

from __future__ import annotations

import logging
import random
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from enum import IntEnum
from typing import Protocol

log = logging.getLogger(__name__)


class TagQuality(IntEnum):
    """OPC UA StatusCode severity, also used for Modbus (timeout/exception → BAD)."""

    GOOD = 0
    UNCERTAIN = 1
    BAD = 2


@dataclass(frozen=True)
class TagSample:
    """One reading of one tag: value (NaN when there is none), source time, quality."""

    tag: str
    value: float
    ts: datetime
    quality: TagQuality = TagQuality.GOOD
    reason: str = ""

    @property
    def good(self) -> bool:
        return self.quality == TagQuality.GOOD


def now() -> datetime:
    return datetime.now(UTC)


def name_tags(tags: list[str], most: int = 5) -> str:
    """``A, B, C, D, E and 2 more``: the first ``most`` tags of a message, then their count."""
    extra = len(tags) - most
    return ", ".join(tags[:most]) + (f" and {extra} more" if extra > 0 else "")


class TagReader(Protocol):
    """Reads a fixed set of tags; a failed read gives Bad samples, never raises."""

    async def read(self) -> list[TagSample]: ...

    async def close(self) -> None: ...


class TagWriter(Protocol):
    """Writes output tags; refuses (and logs) any tag not on its allow-list."""

    async def write(self, values: Mapping[str, float]) -> dict[str, str]: ...


class WriteRefused(Exception):
    """A write to a tag that is not on the configured allow-list."""


class AllowList:
    """Only configured output tags are ever written (DESIGN.md, plant conventions)."""

    def __init__(self, tags: Iterable[str]) -> None:
        self.tags = frozenset(tags)

    def check(self, tags: Iterable[str]) -> None:
        """Raise :class:`WriteRefused` naming every tag outside the list (and log it)."""
        bad = sorted(set(tags) - self.tags)
        if bad:
            log.warning("write refused, not on the output allow-list: %s", ", ".join(bad))
            raise WriteRefused(f"not on the output allow-list: {', '.join(bad)}")


class Backoff:
    """Exponential backoff with full jitter for reconnects: base · 2^n, capped, randomised."""

    def __init__(self, base: float = 0.5, cap: float = 30.0, seed: int | None = None) -> None:
        self.base, self.cap = base, cap
        self.attempt = 0
        self._rng = random.Random(seed)

    def next_delay(self) -> float:
        delay = min(self.cap, self.base * 2**self.attempt)
        self.attempt += 1
        return self._rng.uniform(0.5 * delay, delay)

    def reset(self) -> None:
        self.attempt = 0
