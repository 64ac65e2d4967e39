"""What a tags CSV declares besides each tag's metadata: control loops (``loop``, ``role``,
``set_point``), hand valves, measured disturbances, discrete states, run conditions and pieces
of equipment (``role``, ``equipment``), and the same given as flags (``--loop PV=SP:OUT``,
``--running TAG=VALUE``). Each problem is a :class:`~historian.errors.UserError` naming
``file:line`` or the flag. What each declaration means to a unit:
``diag_plugin/unitbuild/loops.py``.

One reader and one set of checks for ``diag unit build --loops-from`` and ``diag import
--tags`` (:func:`declared_in_tags_csv`): a tags CSV imported is the file the unit's build
reads its loops from, so a mistake in it is said at the import, not a build later.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from .discrete import RUNNING_ROLE, STATE_ROLES
from .errors import UserError

#: role names of the tags CSV's ``role`` column, and the part of a loop each one is
ROLES = {"pv": "pv", "sensor": "pv", "sp": "sp", "out": "out", "actuator": "out"}
#: the role of a hand valve in the tags CSV (a row without a loop)
MANUAL = "manual"
#: the roles of a measured disturbance in the tags CSV (a row without a loop)
DISTURBANCE = ("disturbance", "driver", "exogenous")
#: the roles of a declared discrete state and of a run condition in the tags CSV (rows
#: without a loop; historian/discrete.py, which ``diag tags --tags`` reads them by too)
STATE, RUNNING = STATE_ROLES, RUNNING_ROLE


@dataclass(frozen=True)
class Loop:
    """A control loop: the measurement held (``pv``), its set-point, its output (or None)."""

    pv: str
    sp: str
    out: str | None = None
    #: where each tag was declared (tag, ``tags.csv:7`` or ``--loop 'PV=SP:OUT'``), for errors
    at: tuple[tuple[str, str], ...] = field(default=(), compare=False, repr=False)

    def where(self, tag: str) -> str:
        """Where ``tag`` of this loop was declared (``tags.csv:7``, ``--loop '…'``), or the
        loop itself when not known."""
        return dict(self.at).get(tag, f"loop {self}")

    def __str__(self) -> str:
        return f"{self.pv}={self.sp}" + (f":{self.out}" if self.out else "")

    @property
    def fixed(self) -> float | None:
        """The set-point's value when it is a number, not a tag (else None)."""
        return fixed_value(self.sp)


def fixed_value(text: str) -> float | None:
    """``text`` as a finite number (a fixed set-point), or None when it is a tag's name."""
    try:
        v = float(text)
    except ValueError:
        return None
    return v if math.isfinite(v) else None


def parse_loop(text: str) -> Loop:
    """``PV=SP:OUT`` (or ``PV=SP``) as a :class:`Loop`; a bad spec is a
    :class:`~historian.errors.UserError` that shows the form."""
    pv, eq, rest = text.partition("=")
    sp, colon, out = rest.partition(":")
    pv, sp, out = pv.strip(), sp.strip(), out.strip()
    if not eq or not pv or not sp or (colon and not out):
        raise UserError(
            f"--loop {text!r}: write PV=SP:OUT (or PV=SP; SP a set-point tag or a fixed "
            "number), e.g. FT101=FT101_SP:FV101 or TI9=120.4:TV9"
        )
    if fixed_value(pv) is not None or (out and fixed_value(out) is not None):
        raise UserError(
            f"--loop {text!r}: only the set-point may be a number; the measurement and the "
            "output are tags"
        )
    if sp.lower() in ("nan", "inf", "+inf", "-inf", "infinity"):
        raise UserError(f"--loop {text!r}: the set-point {sp!r} is not a finite number")
    if len({pv, sp, out or None} - {None}) < (3 if out else 2):
        raise UserError(f"--loop {text!r}: the measurement, set-point and output must differ")
    here = f"--loop {text!r}"
    return Loop(pv, sp, out or None, at=tuple((t, here) for t in (pv, sp, out) if t))


def _tags_csv(path: Path):
    """A tags CSV as text cells, its columns by lower-case name, and its name column (or
    None)."""
    from .importer import read_tags_frame

    try:
        frame, cols, name = read_tags_frame(path)
    except UserError:
        raise
    except (OSError, ValueError) as exc:
        raise UserError(_tags_csv_error(path, exc)) from None
    if frame.empty:
        raise UserError(f"{path}: no rows, only a header: it declares no loop nor any tag's role")
    return frame, cols, name


def _tags_csv_error(path: Path, exc: Exception) -> str:
    """A tags CSV that cannot be read, as ``file:line`` where the parser says which line
    (a row with more cells than the header: a decimal comma, ``1,5``, splits a number)."""
    import re

    m = re.search(r"Expected (\d+) fields in line (\d+), saw (\d+)", str(exc))
    if m is None:
        return f"{path}: cannot read the tags CSV: {exc}"
    want, line, saw = m.groups()
    return (
        f"{path}:{line}: {saw} cells where the header has {want} (a comma inside a value? a "
        "decimal comma splits a number: write 1.5, or quote the cell)"
    )


def loops_from_tags_csv(path: str | Path) -> list[Loop]:
    """The loops a tags CSV declares in its ``loop`` and ``role`` columns (see module doc);
    none when it has no ``loop`` column. Problems as ``file:line``."""
    path = Path(path)
    frame, cols, name = _tags_csv(path)
    if "loop" not in cols:
        return []
    if name is None or "role" not in cols:
        raise UserError(f"{path}:1: a 'loop' column needs 'name' and 'role' columns beside it")
    parts: dict[str, dict[str, tuple[str, int]]] = {}
    fixed_col = cols.get("set_point", cols.get("setpoint"))
    for i, row in enumerate(frame.to_dict("records")):
        line = i + 2
        loop = row[cols["loop"]].strip()
        fixed = row[fixed_col].strip() if fixed_col else ""
        if not loop:
            if fixed:
                raise UserError(
                    f"{path}:{line}: set_point {fixed!r} of {row[name].strip()} without a "
                    "loop (give the loop's name in the 'loop' column)"
                )
            continue
        tag, role = row[name].strip(), row[cols["role"]].strip().lower()
        if fixed:
            if ROLES.get(role) != "pv":
                raise UserError(
                    f"{path}:{line}: set_point {fixed!r} on {tag} (loop {loop}, role "
                    f"{role or 'none'}): a fixed set-point goes on the loop's pv row"
                )
            if fixed_value(fixed) is None:
                raise UserError(
                    f"{path}:{line}: set_point {fixed!r} of {tag} (loop {loop}) is not a number"
                )
            if "sp" in parts.get(loop, {}):
                raise UserError(
                    f"{path}:{line}: loop {loop} has a set-point tag ({parts[loop]['sp'][0]}) "
                    f"and a fixed set_point {fixed}: give one"
                )
            parts.setdefault(loop, {})["sp"] = (fixed, line)
        if role not in ROLES:
            raise UserError(
                f"{path}:{line}: role {role!r} of {tag} (loop {loop}) is not one of "
                f"{', '.join(ROLES)}"
            )
        got = parts.setdefault(loop, {})
        part = ROLES[role]
        if part == "sp" and part in got and fixed_value(got["sp"][0]) is not None:
            raise UserError(
                f"{path}:{line}: loop {loop} has a fixed set_point ({got['sp'][0]} on line "
                f"{got['sp'][1]}) and a set-point tag {tag}: give one"
            )
        if part in got:
            raise UserError(
                f"{path}:{line}: loop {loop} has two {part} tags ({got[part][0]} on line "
                f"{got[part][1]}, {tag})"
            )
        got[part] = (tag, line)
    out = []
    for loop, got in parts.items():
        missing = [p for p in ("pv", "sp") if p not in got]
        if missing:
            first = min(v[1] for v in got.values())
            raise UserError(f"{path}:{first}: loop {loop} has no {' and no '.join(missing)} tag")
        at = tuple((t, f"{path}:{line}") for t, line in got.values())
        out.append(Loop(got["pv"][0], got["sp"][0], got["out"][0] if "out" in got else None, at=at))
    return out


@dataclass(frozen=True)
class Manual:
    """A hand valve: its tag and where it was declared (``--manual`` or ``tags.csv:7``)."""

    tag: str
    where: str = "--manual"


def manual_from_tags_csv(path: str | Path) -> list[Manual]:
    """The hand valves a tags CSV declares: rows whose ``role`` is ``manual`` (see module
    doc); none without a ``role`` column. A hand valve in a loop is refused as ``file:line``."""
    return [Manual(tag, where) for tag, where in _loopless(Path(path), (MANUAL,), "a hand valve")]


@dataclass(frozen=True)
class Disturbance:
    """A measured disturbance: its tag and where it was declared (``--disturbance`` or
    ``tags.csv:7``)."""

    tag: str
    where: str = "--disturbance"


def disturbances_from_tags_csv(path: str | Path) -> list[Disturbance]:
    """The measured disturbances a tags CSV declares: rows whose ``role`` is ``disturbance``,
    ``driver`` or ``exogenous`` (see module doc); none without a ``role`` column."""
    rows = _loopless(Path(path), DISTURBANCE, "a measured disturbance")
    return [Disturbance(tag, where) for tag, where in rows]


def states_from_tags_csv(path: str | Path) -> list[str]:
    """The discrete states a tags CSV declares: rows whose ``role`` is ``state``, ``phase`` or
    ``step`` (a batch recipe's phase tag); none without a ``role`` column."""
    return [tag for tag, _ in _loopless(Path(path), STATE, "a discrete state")]


@dataclass(frozen=True)
class Running:
    """A run condition: the state tag, the value at which the unit runs (None: the higher of
    its two values) and where it was declared (``--running …`` or ``tags.csv:7``)."""

    tag: str
    value: float | None = None
    where: str = "--running"
    #: a piece of equipment's (:mod:`diag_plugin.diagnose.equipment`): its name and the tags
    #: that belong to it; () for the unit's own run condition
    name: str | None = None
    tags: tuple[str, ...] = ()
    #: where each of ``tags`` was declared (tag, ``tags.csv:7``), where not ``where``
    at: tuple[tuple[str, str], ...] = field(default=(), compare=False, repr=False)

    def where_of(self, tag: str) -> str:
        """Where ``tag`` (the run tag or one of ``tags``) was declared."""
        return dict(self.at).get(tag, self.where)


def parse_running(text: str) -> Running:
    """``--running TAG`` or ``--running TAG=VALUE`` as a :class:`Running`; a value that is no
    number is refused, naming the flag. ``--running [NAME:]TAG[=VALUE]:TAG1,TAG2,…``: a
    piece of equipment's run condition and the tags that belong to it (NAME default: TAG;
    :mod:`diag_plugin.diagnose.equipment`)."""
    where = f"--running {text}"
    if ":" in text:
        parts = [x.strip() for x in text.split(":")]
        if len(parts) > 3 or not parts[-1]:
            raise UserError(
                f"{where}: write [NAME:]TAG[=VALUE]:TAG1,TAG2,… for a piece of equipment"
            )
        tags = tuple(dict.fromkeys(t.strip() for t in parts[-1].split(",") if t.strip()))
        got = parse_running(parts[-2])
        name = parts[0] if len(parts) == 3 and parts[0] else got.tag
        if got.tag in tags:
            raise UserError(f"{where}: the run tag {got.tag} cannot be one of the equipment's tags")
        return Running(got.tag, got.value, where, name, tags)
    tag, eq, value = (x.strip() for x in text.partition("="))
    if not tag or (eq and not value):
        raise UserError(f"{where}: write TAG (runs at its higher value) or TAG=VALUE")
    if not eq:
        return Running(tag, None, where)
    v = fixed_value(value)
    if v is None:
        raise UserError(f"{where}: the value {value!r} the unit runs at is not a number")
    return Running(tag, v, where)


def running_from_tags_csv(path: str | Path) -> list[Running]:
    """The run conditions a tags CSV declares: rows whose ``role`` is ``running`` (see module
    doc); none without a ``role`` column."""
    path = Path(path)
    rows = _loopless(path, (RUNNING,), "a run condition")
    pieces = {r.where for r in equipment_from_tags_csv(path)}  # a piece's run tag: not the unit's
    return [Running(tag, None, where) for tag, where in rows if where not in pieces]


def equipment_from_tags_csv(path: str | Path) -> list[Running]:
    """The pieces of equipment a tags CSV declares in its ``equipment`` column (see module
    doc): per piece its row of role ``running`` (the run tag, ``where`` its line) and its
    other rows' tags; none without the column. A piece with no run tag or two, none but its
    run tag, or a tag in two pieces is refused as ``file:line``."""
    path = Path(path)
    frame, cols, name = _tags_csv(path)
    if "equipment" not in cols:
        return []
    if name is None:
        raise UserError(f"{path}:1: an 'equipment' column needs a 'name' column beside it")
    role_col = cols.get("role")
    run: dict[str, tuple[str, int]] = {}
    tags: dict[str, dict[str, int]] = {}
    first: dict[str, int] = {}
    owner: dict[str, tuple[str, int]] = {}
    for i, row in enumerate(frame.to_dict("records")):
        line, piece = i + 2, row[cols["equipment"]].strip()
        if not piece:
            continue
        tag = row[name].strip()
        if not tag:
            raise UserError(f"{path}:{line}: equipment {piece} on a row without a tag name")
        first.setdefault(piece, line)
        if tag in owner and owner[tag][0] != piece:
            raise UserError(
                f"{path}:{line}: {tag} in equipment {piece} and in {owner[tag][0]} (line "
                f"{owner[tag][1]}): a tag belongs to one piece"
            )
        owner.setdefault(tag, (piece, line))
        role = row[role_col].strip().lower() if role_col else ""
        if role == RUNNING:
            if piece in run and run[piece][0] != tag:
                raise UserError(
                    f"{path}:{line}: equipment {piece} has two run tags ({run[piece][0]} on "
                    f"line {run[piece][1]}, {tag}): a piece runs on one"
                )
            run[piece] = (tag, line)
        else:
            tags.setdefault(piece, {}).setdefault(tag, line)
    out = []
    for piece, at in first.items():
        if piece not in run:
            raise UserError(
                f"{path}:{at}: equipment {piece} has no run tag (a row of role {RUNNING} with "
                f"equipment {piece})"
            )
        tag, line = run[piece]
        mine = tags.get(piece, {})
        mine.pop(tag, None)
        if not mine:
            raise UserError(
                f"{path}:{line}: equipment {piece} has no tag but its run tag {tag} (name the "
                f"piece in the equipment cell of its tags' rows)"
            )
        where = f"{path}:{line}"
        here = tuple((t, f"{path}:{n}") for t, n in mine.items())
        out.append(Running(tag, None, where, piece, tuple(mine), at=((tag, where), *here)))
    return out


def _loopless(path: Path, roles: Sequence[str], what: str) -> list[tuple[str, str]]:
    """(tag, ``file:line``) of the tags CSV's rows whose ``role`` is one of ``roles``; such a
    row in a loop, or a row without a loop whose role is no loop-less one, is refused as
    ``file:line``."""
    frame, cols, name = _tags_csv(path)
    if "role" not in cols:
        return []
    loopless = (MANUAL, *DISTURBANCE, RUNNING, *STATE)
    out = []
    for i, row in enumerate(frame.to_dict("records")):
        role = row[cols["role"]].strip().lower()
        where = f"{path}:{i + 2}"
        tag = row[name].strip() if name is not None else ""
        loop = row[cols["loop"]].strip() if "loop" in cols else ""
        if role and not loop and role not in loopless:
            raise UserError(
                f"{where}: role {role!r} of {tag or 'a row without a name'} without a loop: a "
                f"row without a loop is one of {', '.join(loopless)} (a loop's "
                f"{', '.join(ROLES)} needs its loop's name in the 'loop' column)"
            )
        if role not in roles:
            continue
        if not tag:
            raise UserError(f"{where}: role {role} without a tag name ('name' column)")
        if loop:
            raise UserError(
                f"{where}: {tag} is {what} (role {role}) and in loop {loop}: it is no loop's "
                "part (leave its loop cell empty)"
            )
        out.append((tag, where))
    return out


#: the columns of a tags CSV that declare something :func:`declared_in_tags_csv` checks
DECLARING = ("loop", "role", "equipment", "set_point", "setpoint")


@dataclass
class Declared:
    """What a tags CSV declares (:func:`declared_in_tags_csv`)."""

    loops: list[Loop] = field(default_factory=list)
    manual: list[Manual] = field(default_factory=list)
    disturbances: list[Disturbance] = field(default_factory=list)
    running: list[Running] = field(default_factory=list)
    equipment: list[Running] = field(default_factory=list)
    states: list[str] = field(default_factory=list)


def declared_in_tags_csv(path: str | Path) -> Declared:
    """Every declaration of the tags CSV at ``path``, each row's ``loop``/``role``/
    ``equipment``/``set_point`` checked (a problem: :class:`UserError` at ``file:line``); a
    hand valve first (one in a loop is said as such), the run conditions before the loops
    (a run tag in a loop too)."""
    path = Path(path)
    out = Declared()
    out.manual = manual_from_tags_csv(path)
    out.disturbances = disturbances_from_tags_csv(path)
    out.running = running_from_tags_csv(path)
    out.equipment = equipment_from_tags_csv(path)
    out.states = states_from_tags_csv(path)
    out.loops = loops_from_tags_csv(path)
    return out


def check_tags_csv_declarations(path: str | Path) -> None:
    """:func:`declared_in_tags_csv` for ``diag import --tags``: a tags CSV with a
    declaring column (:data:`DECLARING`) and a row is checked as ``diag unit build
    --loops-from`` checks it; one without (metadata only) is not read here."""
    from .importer import read_tags_frame

    frame, cols, _ = read_tags_frame(Path(path))
    if frame.empty or not any(c in cols for c in DECLARING):
        return
    declared_in_tags_csv(path)
