"""Password hashes for plant.toml users: scrypt (stdlib), never the password itself.

``diag run --hash-password`` prints one; the OPC UA server checks a login against it in
constant time (:func:`check_password`: an unknown user costs one scrypt too). The text form
is ``scrypt$n$r$p$<salt base64>$<hash base64>``.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import os

#: scrypt cost (n, r, p): ~50 ms and 16 MB per check, once per login
_SCRYPT = (2**14, 8, 1)


def hash_password(password: str, salt: bytes | None = None) -> str:
    """``scrypt$n$r$p$salt$hash`` (base64) of ``password``, for ``password_hash`` in plant.toml."""
    n, r, p = _SCRYPT
    salt = salt if salt is not None else os.urandom(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, dklen=32)
    b64 = base64.b64encode
    return f"scrypt${n}${r}${p}${b64(salt).decode()}${b64(digest).decode()}"


def hash_problem(stored: str) -> str | None:
    """Why ``stored`` is not a hash :func:`verify_password` can check (None when it is)."""
    parts = stored.split("$")
    if len(parts) != 6 or parts[0] != "scrypt":
        return "expected scrypt$n$r$p$salt$hash (make one with `diag run --hash-password`)"
    try:
        n, r, p = (int(x) for x in parts[1:4])
        base64.b64decode(parts[4], validate=True)
        base64.b64decode(parts[5], validate=True)
    except ValueError:
        return "malformed scrypt hash (numbers n, r, p, then base64 salt and hash)"
    if n < 2 or n & (n - 1) or r < 1 or p < 1:
        return "scrypt n must be a power of 2 and r, p positive"
    if 128 * r * n > 32 * 2**20:
        return "scrypt n·r too large (over 32 MB per check)"
    return None


def verify_password(stored: str, password: str) -> bool:
    """``password`` matches the scrypt hash ``stored`` (compared in constant time)."""
    if hash_problem(stored) is not None:
        return False
    _, n, r, p, salt, digest = stored.split("$")
    want = base64.b64decode(digest)
    got = hashlib.scrypt(
        password.encode(),
        salt=base64.b64decode(salt),
        n=int(n),
        r=int(r),
        p=int(p),
        dklen=len(want),
    )
    return hmac.compare_digest(got, want)


_DUMMY: dict[tuple[int, int, int], str] = {}


def dummy_hash(like: str | None = None) -> str:
    """A hash of a random password with the cost (n, r, p) of ``like`` (default: ours), made
    once per cost: what an unknown user's password is checked against, so that refusing an
    unknown user costs one scrypt, as refusing a wrong password does (no user enumeration by
    timing)."""
    cost = _SCRYPT
    if like is not None and hash_problem(like) is None:
        n, r, p = (int(x) for x in like.split("$")[1:4])
        cost = (n, r, p)
    if cost not in _DUMMY:
        n, r, p = cost
        salt = os.urandom(16)
        digest = hashlib.scrypt(os.urandom(16), salt=salt, n=n, r=r, p=p, dklen=32)
        b64 = base64.b64encode
        _DUMMY[cost] = f"scrypt${n}${r}${p}${b64(salt).decode()}${b64(digest).decode()}"
    return _DUMMY[cost]


def check_password(stored: str | None, password: str | None, like: str | None = None) -> bool:
    """``password`` matches ``stored``, in the same time whether or not there is a user:
    with no ``stored`` hash (unknown user, or a certificate-only one) or no password the
    check runs against :func:`dummy_hash` (cost of ``like``) and returns False. Exactly one
    scrypt either way, compared with :func:`hmac.compare_digest`."""
    real = stored is not None and password is not None and hash_problem(stored) is None
    ok = verify_password(stored if real else dummy_hash(like or stored), password or "")
    return ok and real
