"""The bytes of ``DataFrame.to_csv(float_format="%.6g")`` written by one compiled pass a block
(issue 34, round six: ``diag diagnose --csv`` spent ~46 µs a row of ~150 columns in Python's
``%`` formatting and the :mod:`csv` writer, 45 of a 77 CPU s run at 1,000,000 rows).

Floats are formatted as C's and Python's ``%.6g`` do (:func:`_g6_digits`: the six significant
digits of the value's exact binary, rounded to nearest, ties to even), in numba. The scaled
value ``|x| · 10^(5−e)`` is one correctly rounded product or quotient by an exact power of ten
(``|5−e| ≤ 22``), so its error is below 1.2e-10; a value whose rounding that could change (a
fraction within 1e-9 of one half), an infinity, or a magnitude outside 1e-17 … 1e22, is
formatted by Python's ``%`` instead (:func:`hard_floats`), the rest by the kernel. Every other
column (times, integers, text) is a table of its distinct texts, each escaped as
:func:`csv.writer` escapes it, and per row the code of its text.
"""

from __future__ import annotations

import csv
import io
import os
import re

import numba as nb
import numpy as np

#: exact powers of ten as doubles (10^0 … 10^22 are exact)
_P10 = np.array([10.0**k for k in range(23)])
#: a scaled value's fraction this close to one half is rounded by Python, not here
_TIE = 1e-9
#: the one float format the kernel writes
G6 = "%.6g"
_g6 = G6.__mod__


@nb.njit(cache=True, nogil=True, inline="always")
def _g6_digits(a, p10):  # pragma: no cover - numba
    """(D, X, ok) of a finite ``a > 0``: ``%.6g`` of it shows the digits of D (100000 ≤ D
    < 1000000) times 10^(X−5); ``ok`` False where this is not certain (see the module)."""
    e = int(np.floor(np.log10(a)))
    for _ in range(3):
        k = 5 - e
        if k > 22 or k < -22:
            return 0, 0, False
        y = a * p10[k] if k >= 0 else a / p10[-k]
        if y < 100000.0:
            e -= 1
        elif y >= 1000000.0:
            e += 1
        else:
            d = int(np.floor(y))
            f = y - d
            if abs(f - 0.5) < 1e-9:  # _TIE
                return 0, 0, False
            if f > 0.5:
                d += 1
            if d == 1000000:
                return 100000, e + 1, True
            return d, e, True
    return 0, 0, False


@nb.njit(cache=True, nogil=True)
def _hard_kernel(x, p10, out):  # pragma: no cover - numba
    """``out[i]`` True where :func:`_g6_digits` is not certain of ``x[i]`` (NaN: not)."""
    for i in range(x.size):
        v = x.flat[i]
        if v != v or v == 0.0:
            out[i] = False
        elif abs(v) == np.inf:
            out[i] = True
        else:
            out[i] = not _g6_digits(abs(v), p10)[2]


#: the two digits of 0 … 99 as bytes, side by side
_D2 = np.array([ord(c) for i in range(100) for c in f"{i:02d}"], np.uint8)


@nb.njit(cache=True, nogil=True, inline="always")
def _six(d, out, at):  # pragma: no cover - numba
    """The six digits of ``d`` (100000 … 999999) at ``out[at:at + 6]``, two by two."""
    u = np.uint32(d)  # unsigned: a signed // and % are Python's, rounded down
    a = u // np.uint32(10000)
    r = u - a * np.uint32(10000)
    b = r // np.uint32(100)
    c = r - b * np.uint32(100)
    out[at] = _D2[2 * a]
    out[at + 1] = _D2[2 * a + 1]
    out[at + 2] = _D2[2 * b]
    out[at + 3] = _D2[2 * b + 1]
    out[at + 4] = _D2[2 * c]
    out[at + 5] = _D2[2 * c + 1]


@nb.njit(cache=True, nogil=True, inline="always")
def _put_g6(neg, d, x, out, pos):  # pragma: no cover - numba
    """``%.6g`` of a value that :func:`_g6_digits` gave ``(d, x)`` (its sign ``neg``) at
    ``pos``; returns the place after it. The six digits are written whole and the shown ones
    kept (trailing zeros dropped, no '#' flag): up to 13 bytes from ``pos`` are written."""
    if neg:
        out[pos] = 45  # -
        pos += 1
    nd = 6  # the digits shown
    u = np.uint32(d)
    while u % np.uint32(10) == 0:
        u //= np.uint32(10)
        nd -= 1
    if -4 <= x < 0:  # 0.000ddd
        z = -x - 1
        out[pos] = 48
        out[pos + 1] = 46  # .
        out[pos + 2] = 48
        out[pos + 3] = 48
        out[pos + 4] = 48
        _six(d, out, pos + 2 + z)
        return pos + 2 + z + nd
    if 0 <= x < 6:  # fixed notation, x + 1 digits before the point
        whole = x + 1
        _six(d, out, pos)
        if nd <= whole:  # an integer: the digits, then zeros
            for i in range(pos + nd, pos + whole):
                out[i] = 48
            return pos + whole
        for i in range(pos + nd, pos + whole, -1):  # the fraction one place on
            out[i] = out[i - 1]
        out[pos + whole] = 46
        return pos + nd + 1
    _six(d, out, pos + 1)  # d[.ddddd]e±XX
    out[pos] = out[pos + 1]
    if nd > 1:
        out[pos + 1] = 46
        pos += nd + 1
    else:
        pos += 1
    out[pos] = 101  # e
    out[pos + 1] = 45 if x < 0 else 43
    pos += 2
    ax = abs(x)
    if ax >= 100:
        out[pos] = 48 + ax // 100
        pos += 1
    out[pos] = 48 + (ax // 10) % 10
    out[pos + 1] = 48 + ax % 10
    return pos + 2


@nb.njit(cache=True, nogil=True)
def _rows_kernel(
    floats, codes, nrows, kind, col, text, text_at, eol, p10, out, r, c, pos, row_end
):  # pragma: no cover - numba
    """CSV rows into ``out`` from row ``r``, column ``c`` and byte ``pos`` on: column ``c`` is
    float column ``col[c]`` of ``floats`` (``kind[c]`` 0: NaN empty) or text column ``col[c]``
    of ``codes`` (1: the row's text ``text[text_at[k]:text_at[k + 1]]``); any layout of
    either (a piece's columns as they are, no copy into rows). Returns ``(pos, r, c)``: ``r``
    the row count when done, else the float the kernel is not certain of (:func:`_g6_digits`),
    its separator written, for the caller to write and resume at ``(r, c + 1)``. With
    ``row_end`` of a row per row, each row's end (where its line end starts) is noted there."""
    ncols = kind.size
    while r < nrows:
        while c < ncols:
            if c:
                out[pos] = 44  # ,
                pos += 1
            j = col[c]
            if kind[c] == 0:
                v = floats[r, j]
                if v == 0.0:
                    if np.signbit(v):
                        out[pos] = 45  # -
                        pos += 1
                    out[pos] = 48
                    pos += 1
                elif v == v:
                    if abs(v) == np.inf:
                        return pos, r, c
                    d, x, ok = _g6_digits(abs(v), p10)
                    if not ok:
                        return pos, r, c
                    pos = _put_g6(v < 0, d, x, out, pos)
            else:
                k = codes[r, j]
                for i in range(text_at[k], text_at[k + 1]):
                    out[pos] = text[i]
                    pos += 1
            c += 1
        if row_end.size:
            row_end[r] = pos
        for i in range(eol.size):
            out[pos] = eol[i]
            pos += 1
        r += 1
        c = 0
    return pos, r, c


def _fill(floats, codes, rows, kind, col, text, text_at, eol, out, row_end) -> int:
    """:func:`_rows_kernel` over ``rows`` rows, the floats it is not certain of written by
    Python's ``%`` where it stops; returns the bytes written."""
    r, c, pos = 0, 0, 0
    while True:
        pos, r, c = _rows_kernel(floats, codes, rows, kind, col, text, text_at, eol, _P10, out,
                                 r, c, pos, row_end)  # fmt: skip
        if r >= rows:
            return pos
        hard = _g6(floats[r, col[c]]).encode()  # at most 13 bytes: the room of any float
        out[pos : pos + len(hard)] = np.frombuffer(hard, np.uint8)
        pos += len(hard)
        c += 1


@nb.njit(cache=True, nogil=True)
def _utc_kernel(secs, out):  # pragma: no cover - numba
    """``YYYY-MM-DDTHH:MM:SS+0000`` of each second since 1970 (UTC, years 1000–9999) into the
    rows of ``out`` (24 bytes each): the days to a date by H. Hinnant's civil_from_days."""
    for i in range(secs.size):
        t = secs[i]
        days = t // 86400
        sod = t - days * 86400
        z = days + 719468
        era = (z if z >= 0 else z - 146096) // 146097
        doe = z - era * 146097
        yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
        doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
        mp = (5 * doy + 2) // 153
        day = doy - (153 * mp + 2) // 5 + 1
        month = mp + 3 if mp < 10 else mp - 9
        year = yoe + era * 400 + (1 if month <= 2 else 0)
        o = out[i]
        for k, v in ((0, year // 100), (2, year % 100), (5, month), (8, day), (11, sod // 3600),
                     (14, sod // 60 % 60), (17, sod % 60)):  # fmt: skip
            o[k] = 48 + v // 10
            o[k + 1] = 48 + v % 10
        for k, ch in ((4, 45), (7, 45), (10, 84), (13, 58), (16, 58), (19, 43), (20, 48),
                      (21, 48), (22, 48), (23, 48)):  # fmt: skip
            o[k] = ch


#: the seconds since 1970 of 1000-01-01 and 10000-01-01 (UTC): :func:`utc_texts`' range
_YEARS = (-30610224000, 253402300800)


def utc_texts(secs: np.ndarray) -> np.ndarray | None:
    """``%Y-%m-%dT%H:%M:%S+0000`` of each time (seconds since 1970, UTC) as 24-byte strings,
    the texts ``numpy.datetime_as_string`` and ``+0000`` gave at a fortieth of the cost (a
    piece of 41,666 rows: 33 ms); None outside the years 1000–9999."""
    secs = np.ascontiguousarray(secs, np.int64)
    if secs.size and (secs.min() < _YEARS[0] or secs.max() >= _YEARS[1]):
        return None
    out = np.empty((secs.size, 24), np.uint8)
    _utc_kernel(secs, out)
    return out.view("S24").reshape(-1)


def hard_floats(x: np.ndarray) -> np.ndarray:
    """Where the kernel leaves ``%.6g`` of ``x`` to Python (see the module): infinities,
    magnitudes outside 1e-17 … 1e22 and near-ties."""
    out = np.empty(x.shape, bool)
    _hard_kernel(np.ascontiguousarray(x, float), _P10, out.reshape(-1))
    return out


def format_g6(x: np.ndarray) -> list[str]:
    """``"%.6g" % v`` of each value (NaN: ``""``) through the kernel (hard ones by Python):
    what :func:`write_rows` writes of a float."""
    x = np.ascontiguousarray(x, float).reshape(-1, 1)
    out = np.empty(x.shape[0] * 14 + 1, np.uint8)
    codes = np.zeros((x.shape[0], 0), np.int64)
    n = _fill(x, codes, x.shape[0], np.zeros(1, np.int8), np.zeros(1, np.int64),
              np.zeros(0, np.uint8), np.zeros(1, np.int64), np.array([10], np.uint8), out,
              np.zeros(0, np.int64))  # fmt: skip
    return out[:n].tobytes().decode().split("\n")[:-1]


def _joined(texts: list[str]) -> tuple[np.ndarray, np.ndarray]:
    """Texts as one UTF-8 byte array and the offsets of each (len + 1 entries)."""
    raw = [t.encode() for t in texts]
    off = np.zeros(len(raw) + 1, np.int64)
    np.cumsum(np.fromiter(map(len, raw), np.int64, len(raw)), out=off[1:])
    return np.frombuffer(b"".join(raw), np.uint8).copy(), off


_SPECIAL = (",", '"', "\r", "\n")
_NEEDS = re.compile('[,"\r\n]')


def _writer_quotes(text: str) -> str:
    buf = io.StringIO()
    csv.writer(buf, lineterminator=os.linesep).writerow([text, ""])
    return buf.getvalue()[: -1 - len(os.linesep)]


#: whether :func:`csv.writer` quotes a field as ``"…"`` with its quotes doubled, as it did
#: for every text tried here; else each text is written by a writer
_MINIMAL = all(
    _writer_quotes(t) == '"' + t.replace('"', '""') + '"'
    for t in ("a,b", 'say "x"', "two\nlines", "cr\r", '",\r\n"', " a, ")
)


def escaped(text: str) -> str:
    """``text`` as :func:`csv.writer` (the default dialect, rows ended by ``os.linesep`` as
    ``to_csv`` ends them) writes a field of it among others: quoted where it holds a comma,
    a quote or a line break."""
    if not _NEEDS.search(text):
        return text
    if _MINIMAL:  # the writer's QUOTE_MINIMAL with doubled quotes, without a writer a text
        return '"' + text.replace('"', '""') + '"'
    return _writer_quotes(text)  # the row's "," and line end dropped


class TextTable:
    """The distinct texts of a frame's text columns, escaped and joined (:func:`_joined`),
    each column's values as codes into it."""

    def __init__(self) -> None:
        self._parts: list[list[str] | np.ndarray] = []  # texts, or fixed-width bytes
        self._count = 0

    def add(self, codes: np.ndarray, uniq: list[str], missing: bool) -> np.ndarray:
        """A column's global codes: ``codes`` index ``uniq`` (−1: missing, empty text)."""
        base = self._count
        texts = _escaped_all(uniq)
        codes = np.asarray(codes, np.int64) + base
        if missing:
            texts.append("")
            codes[codes < base] = base + len(texts) - 1
        self._parts.append(texts)
        self._count += len(texts)
        return codes

    def add_times(self, times: np.ndarray) -> np.ndarray:
        """The codes of a column of texts that need no quoting (the times, a numpy array of
        str): each its own code; kept as fixed-width bytes where they are all one width."""
        base = self._count
        if times.dtype.kind == "S" and times.size and times.itemsize:  # fixed width already
            self._parts.append(times)
            self._count += times.size
            return np.arange(base, base + times.size, dtype=np.int64)
        try:
            raw = times.astype(bytes)
        except UnicodeEncodeError:
            raw = None
        width = np.char.str_len(raw) if raw is not None else np.zeros(0, np.int64)
        if times.size and width.size and (width == width[0]).all() and width[0] > 0:
            self._parts.append(raw.astype(f"S{width[0]}"))
        else:
            self._parts.append(times.tolist())
        self._count += times.size
        return np.arange(base, base + times.size, dtype=np.int64)

    def arrays(self) -> tuple[np.ndarray, np.ndarray, int]:
        """(text bytes, offsets, the longest text's bytes)."""
        texts, offs, start = [], [np.zeros(1, np.int64)], 0
        for part in self._parts:
            if isinstance(part, np.ndarray):
                w = part.itemsize
                text, off = part.view(np.uint8).reshape(-1), np.arange(part.size + 1) * w
            else:
                text, off = _joined(part)
            texts.append(text)
            offs.append(off[1:] + start)
            start += len(text)
        off = np.concatenate(offs)
        text = np.concatenate(texts) if texts else np.zeros(0, np.uint8)
        return text, off, int(np.diff(off).max(initial=0))


def _escaped_all(texts: list[str]) -> list[str]:
    """:func:`escaped` of each text; looked at one by one only where their join holds a
    character that may need quoting."""
    joined = "".join(texts)
    if not any(ch in joined for ch in _SPECIAL):
        return list(texts)
    return [escaped(t) for t in texts]


def write_rows(fh, floats: np.ndarray, codes: np.ndarray, order, table, eol: str,
               step: int = 16_384, row_end: np.ndarray | None = None,
               spare: list | None = None) -> None:  # fmt: skip
    """Write the CSV rows of ``floats`` (rows × float columns) and ``codes`` (rows × text
    columns, codes into ``table``, a :class:`TextTable`) to the binary file ``fh`` in blocks
    of ``step`` rows: ``order`` lists per column ``(0, i)`` (float column ``i``) or ``(1, i)``
    (text column ``i``). The arrays are read in their own layout (a frame's columns, no copy
    into rows). With ``row_end`` (a row per row), each row's end is noted there: the offset
    from the first row's start where its line end starts. ``spare``, a list, keeps the bytes'
    buffer for the next call (a new one is a page fault per 4 kB of it)."""
    rows = codes.shape[0]
    kind = np.array([k for k, _ in order], np.int8)
    col = np.array([i for _, i in order], np.int64)
    text, text_at, longest = table.arrays()
    end = np.frombuffer(eol.encode(), np.uint8)
    size = min(rows, step) * (14 * floats.shape[1] + (longest + 1) * codes.shape[1] + end.size)
    if spare and spare[0].size >= size + 1:
        out = spare[0]
    else:
        out = np.empty(size + 1, np.uint8)
        if spare is not None:
            spare[:] = [out]
    none = np.zeros(0, np.int64)
    done = 0
    for a in range(0, rows, step):
        b = min(rows, a + step)
        ends = none if row_end is None else row_end[a:b]
        n = _fill(floats[a:b], codes[a:b], b - a, kind, col, text, text_at, end, out, ends)
        if row_end is not None:
            ends += done
        fh.write(out[:n].data)
        done += n
