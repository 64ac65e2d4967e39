"""``diag diagnose``'s cache of its tests' models, keyed by each rule-base file's content.

Reading a unit's rule bases was most of its load (issue 34, "Speed": the bench's 45 files,
8,225 rules, each checked line by line: ~0.1 CPU s of a ~2 s run at 200,000 rows). A
Wang–Mendel model read once is kept as a NumPy ``.npz`` file — its exact state
(:meth:`~diag_plugin.fuzzy.wang_mendel.WangMendelRegressor.to_state`, integer and float
arrays), the conclusions as written in the file and the test's variables as JSON text —
and loaded with ``allow_pickle=False``: no Python object is ever unpickled from it. The
arrays' bytes are one member of it, ``blob``, each array's place, type and shape in the
JSON (:func:`pack`): ``np.load`` opened every array as a member of its own, with its own
header to parse (the bench's 45 entries, ~900 arrays: ~0.06 of the unit's ~0.12 CPU s load).

The key is the SHA-256 of the file's bytes and of the source of the code that turns a file
into a model (every module of the packages in :data:`CODE_PACKAGES` and the modules in
:data:`CODE`): an edited file, or changed code there, is a new key. Only a file
read without problems is kept (a broken one is read, and reported, every time); other
methods than Wang–Mendel's are read as before. An entry that cannot be read is ignored and
written again; one that cannot be written (a read-only home) is simply not kept.

Where: ``$DIAG_MODEL_CACHE`` (a folder), or ``off`` (also ``0``, ``no``, empty) for no cache;
by default ``$XDG_CACHE_HOME/diag-plugin/models`` (``~/.cache/diag-plugin/models``), made
readable by its owner alone. A folder that already exists is used only if it is owned by the
user running the command and no one else may write to it (a model planted there would be
trusted); otherwise the cache is not used and the command says why once (logging). Entries are
a few tens of kB; delete the folder at any time.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import stat
import tempfile
from pathlib import Path
from typing import Any

#: the entries' layout; a new value is a new key for every file
FORMAT = "diag-model-cache 2"
#: byte alignment of each array in an entry's blob (a cache line: the arrays are read in place)
ALIGN = 64
#: packages (relative to ``diag_plugin``) every module of which is part of the key: the rule-base
#: reader, the models' codecs and the fuzzy models themselves
CODE_PACKAGES = ("rulebase", "models", "fuzzy")
#: single modules whose source is part of the key (relative to the ``diag_plugin`` package)
CODE = (
    "regressors.py",
    "tomllines.py",
    "diagnose/unit.py",
    "diagnose/modelcache.py",
)
#: ``$DIAG_MODEL_CACHE`` values that turn the cache off
OFF = ("", "0", "off", "no", "false")

log = logging.getLogger(__name__)


def default_folder() -> Path | None:
    """The cache's folder, or None when ``$DIAG_MODEL_CACHE`` turns it off."""
    env = os.environ.get("DIAG_MODEL_CACHE")
    if env is not None:
        return None if env.strip().lower() in OFF else Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or "~/.cache"
    return Path(base).expanduser() / "diag-plugin" / "models"


class ModelCache:
    """The models of rule-base files kept in ``folder`` (see the module's text)."""

    def __init__(self, folder: str | Path) -> None:
        self.folder = Path(folder)
        self._code: bytes | None = None
        self._safe: bool | None = None

    @classmethod
    def default(cls) -> ModelCache | None:
        folder = default_folder()
        return None if folder is None else cls(folder)

    def usable(self) -> bool:
        """Whether the folder may be trusted: absent (it is made owner-only), or a folder owned
        by this user that no one else may write to. Checked once; the reason is logged."""
        if self._safe is None:
            self._safe = True
            try:
                st = os.stat(self.folder)
            except FileNotFoundError:
                return True
            except OSError as e:
                why = f"cannot be read ({e.strerror})"
                self._safe = False
            else:
                mine = not hasattr(os, "getuid") or st.st_uid == os.getuid()
                if not stat.S_ISDIR(st.st_mode):
                    why = "is not a folder"
                    self._safe = False
                elif not mine:
                    why = f"is owned by user id {st.st_uid}, not this user"
                    self._safe = False
                elif st.st_mode & (stat.S_IWGRP | stat.S_IWOTH):
                    why = f"may be written by others (mode {stat.S_IMODE(st.st_mode):o})"
                    self._safe = False
            if not self._safe:
                log.warning(
                    "model cache %s not used: it %s; rule bases are read from their files "
                    "(chmod go-w the folder, or set DIAG_MODEL_CACHE)",
                    self.folder,
                    why,
                )
        return self._safe

    @staticmethod
    def code_files() -> list[str]:
        """The sources in the key (relative to ``diag_plugin``), in a fixed order."""
        root = Path(__file__).resolve().parents[1]
        rels = [
            p.relative_to(root).as_posix()
            for pkg in CODE_PACKAGES
            for p in (root / pkg).glob("*.py")
        ]
        return sorted(rels) + list(CODE)

    def _code_digest(self) -> bytes:
        if self._code is None:
            root = Path(__file__).resolve().parents[1]
            h = hashlib.sha256(FORMAT.encode())
            for rel in self.code_files():
                h.update(rel.encode() + b"\0")
                try:
                    h.update((root / rel).read_bytes())
                except OSError:
                    h.update(b"-")
            self._code = h.digest()
        return self._code

    def key(self, data: bytes) -> str:
        """The entry's name for a file of these bytes."""
        return hashlib.sha256(self._code_digest() + data).hexdigest()

    def get(self, data: bytes) -> dict[str, Any] | None:
        """What :meth:`put` kept for a file of these bytes, or None."""
        import numpy as np

        if not self.usable():
            return None
        path = self.folder / f"{self.key(data)}.npz"
        try:
            with np.load(path, allow_pickle=False) as z:
                meta = json.loads(z["meta"].tobytes().decode("utf-8"))
                if meta.get("format") != FORMAT:
                    return None
                arrays = unpack(z["blob"], meta.pop("layout"))
        except (OSError, ValueError, KeyError, TypeError, UnicodeDecodeError, EOFError):
            return None
        return {"meta": meta, "arrays": arrays}

    def put(self, data: bytes, meta: dict[str, Any], arrays: dict[str, Any]) -> None:
        """Keep ``meta`` (JSON) and ``arrays`` for a file of these bytes; errors are ignored."""
        import numpy as np

        if not self.usable():
            return
        try:
            blob, layout = pack(arrays)
            text = json.dumps({**meta, "format": FORMAT, "layout": layout}, allow_nan=True)
            self.folder.mkdir(parents=True, exist_ok=True, mode=0o700)
            replace_with(self.folder / f"{self.key(data)}.npz", lambda f: np.savez(
                f, meta=np.frombuffer(text.encode("utf-8"), np.uint8), blob=blob))  # fmt: skip
        except (OSError, ValueError):  # a full disk, a read-only home: not kept, not fatal
            pass


def replace_with(path: Path, write: Any) -> None:
    """``write(f)`` into a temporary binary file beside ``path``, then moved over it (a reader
    sees the old file or the whole new one); the temporary file is removed on any error."""
    fd, tmp = tempfile.mkstemp(dir=path.parent, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            write(f)
        os.replace(tmp, path)
    except BaseException:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        raise


def pack(arrays: dict[str, Any]) -> tuple[Any, list]:
    """``arrays`` as one byte array and its layout: per array its name, type (``dtype.str``),
    shape, memory order (Fortran where the array is so and not C, as ``np.save`` keeps it)
    and offset, each at a multiple of :data:`ALIGN`. Numbers and booleans only (a
    ``ValueError`` otherwise: nothing that would need a pickle)."""
    import numpy as np

    layout, at = [], 0
    parts = []
    for name, a in arrays.items():
        a = np.asanyarray(a)
        order = "F" if a.flags.f_contiguous and not a.flags.c_contiguous else "C"
        a = np.asarray(a, order=order)
        if a.dtype.kind not in "biuf" or a.dtype.fields is not None:
            raise ValueError(f"array {name!r} of {a.dtype}: not kept")
        at = -(-at // ALIGN) * ALIGN
        layout.append([name, a.dtype.str, list(a.shape), order, at])
        parts.append((at, a.reshape(-1, order=order)))
        at += a.nbytes
    blob = np.zeros(at, np.uint8)
    for start, flat in parts:
        blob[start : start + flat.nbytes] = flat.view(np.uint8)
    return blob, layout


def unpack(blob: Any, layout: list) -> dict[str, Any]:
    """The arrays :func:`pack` packed, each a copy of its bytes (its own, writable);
    a ``ValueError`` where the layout does not fit the blob."""
    import numpy as np

    out = {}
    for name, dtype, shape, order, at in layout:
        dt = np.dtype(dtype)
        if dt.kind not in "biuf" or order not in ("C", "F"):
            raise ValueError(f"array {name!r} of {dt}, order {order!r}")
        n = math.prod(shape) * dt.itemsize
        if at < 0 or at + n > blob.size:
            raise ValueError(f"array {name!r} outside the entry")
        out[name] = blob[at : at + n].view(dt).reshape(shape, order=order).copy(order="K")
    return out
