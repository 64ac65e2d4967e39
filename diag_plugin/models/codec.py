"""What every model-file codec shares (``wm-avg``/``wm``, ``ts-fcm``, ``narmax2``, ``track``):
the method name, the walk over the ``[rules] list`` with its line numbers and comments, and
the ``list = [...]`` text with the comments kept.

A codec reads and writes one method's rules; the file around them (header, ``[[inputs]]``,
``[output]``, locks, checks) is :mod:`diag_plugin.rulebase.document`'s.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from typing import Any, NamedTuple, Protocol


class _Errors(Protocol):
    problems: list

    def error(self, line: int, message: str) -> None: ...

    def line_of(self, table: str, key: str) -> int: ...


class Entry(NamedTuple):
    """One item of the ``[rules] list`` that is a table: where it stands and what it says."""

    item: Mapping[str, Any]
    line: int
    comments: list[str]
    trailing: str
    where: str  # "rule 3", "term 2": how messages name it
    problems: int  # the file's problem count before this item (new ones: the item is bad)


class RuleCodec:
    """The base of the model-file codecs: ``method`` (one codec may serve several names),
    the predictor of a trained model (the model itself, unless a method applies locks)."""

    #: the method name a codec made without one serves (each codec class names its own;
    #: :meth:`~diag_plugin.models.registry.Method.load` passes the name the file gives)
    method = ""
    #: the estimator class the codec makes (its ``_params`` name what the method takes)
    estimator: type | None = None
    #: whether the method has an IEC 61131-7 FCL form (``diag rules export``)
    fcl = False

    def __init__(self, method: str | None = None) -> None:
        if method is not None:
            self.method = method

    def predictor(self, rb: Any, model: Any) -> Any:
        """The trained model as the file predicts with it (no locks in this method)."""
        return model

    @staticmethod
    def entries(
        rb: _Errors,
        items: list,
        positions: Sequence[tuple[int, list[str], str]],
        noun: str,
        keys: set[str],
        shape: str,
    ) -> Iterator[Entry]:
        """The tables of the ``[rules] list`` with their line, comments and name (``noun``
        and its 1-based place); an item that is not a table, or names a key not in ``keys``,
        goes to ``rb.error`` (``shape``: what an item looks like, for the message)."""
        for i, item in enumerate(items):
            line, comments, trail = (
                positions[i] if i < len(positions) else (rb.line_of("rules", "list"), [], "")
            )
            where = f"{noun} {i + 1}"
            if not isinstance(item, Mapping):
                rb.error(line, f"{where}: expected {{ {shape} }}")
                continue
            n0 = len(rb.problems)
            unknown = set(item) - keys
            if unknown:
                rb.error(line, f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
            yield Entry(item, line, comments, trail, where, n0)

    @staticmethod
    def format_list(rules: Iterable[Any], text: Callable[[Any], str]) -> str:
        """``list = [...]``: per rule its comments, ``text(rule)`` and its trailing comment."""
        lines = ["list = [\n"]
        for r in rules:
            lines += [f"    {c}\n" for c in r.comments]
            lines.append(f"    {text(r)}" + (f"  {r.trailing}" if r.trailing else "") + "\n")
        lines.append("]\n")
        return "".join(lines)
