"""The digital Butterworth low-pass of :class:`~diag_plugin.diagnose.residuals.LowPass` in
numpy alone: ``scipy.signal.butter(order, wn, output="sos")``, ``scipy.signal.sosfilt_zi``
and the slowest pole of ``scipy.signal.sos2zpk``, the same operations in the same order, so
the same bits.

Why not scipy.signal itself: importing it imports ``scipy.stats`` (its peak finding) and
parses the docstrings of its array-API wrappers, 0.8–0.9 CPU s of every ``diag diagnose``
process (issue 34: 200,000 rows replayed in about 7 CPU s end to end, of which 1.5 s were
imports). What is ported is scipy 1.17's path for a digital low-pass with the default
``pairing="nearest"``: ``buttap`` → pre-warping → ``lp2lp_zpk`` → ``bilinear_zpk`` →
``zpk2sos`` (scipy, BSD-3-Clause; Copyright (c) 2001-2002 Enthought, Inc., 2003-2024 SciPy
Developers), and ``sosfilt_zi`` (``lfilter_zi`` per section: the companion matrix and
``np.linalg.solve``). ``tests/test_lowpass_port.py`` compares the three with scipy's bit for
bit over orders 1–10 and cut-offs across (0, 1).
"""

from __future__ import annotations

import numpy as np

__all__ = ["butter_sos", "slowest_pole", "sosfilt_zi"]


def butter_sos(order: int, wn: float) -> np.ndarray:
    """``scipy.signal.butter(order, wn, output="sos")``: second-order sections (sections ×
    6: ``b0 b1 b2 a0 a1 a2``) of the digital Butterworth low-pass of ``order`` with cut-off
    ``wn`` (1.0 = Nyquist)."""
    if abs(int(order)) != order:
        raise ValueError("Filter order must be a nonnegative integer")
    wn_ = np.asarray(wn, dtype=np.float64)
    if not 0 < wn_ < 1:
        raise ValueError("Digital filter critical frequencies must be 0 < Wn < 1")
    # buttap: the analog prototype
    z = np.asarray([], dtype=np.float64)
    m = np.arange(-order + 1, order, 2, dtype=np.float64)
    p = -np.exp(1j * np.pi * m / (2 * order))
    k = 1.0
    # pre-warping (fs = 2) and lp2lp_zpk
    fs = 2.0
    wo = float(2 * fs * np.tan(np.pi * wn_ / fs))
    degree = p.shape[0] - z.shape[0]
    z, p, k = wo * z, wo * p, k * wo**degree
    # bilinear_zpk
    fs2 = 2.0 * fs
    z_z = np.concatenate(((fs2 + z) / (fs2 - z), -np.ones(degree)))
    p_z = (fs2 + p) / (fs2 - p)
    k_z = k * np.real(np.prod(fs2 - z) / np.prod(fs2 - p))
    return _zpk2sos(z_z, p_z, k_z)


def slowest_pole(sos: np.ndarray) -> float:
    """``np.abs(scipy.signal.sos2zpk(sos)[1]).max()``: the largest magnitude of the poles
    of the sections (each section's denominator, leading zeros trimmed and normalised, by
    ``np.roots``); 0.0 for sections without poles."""
    out = 0.0
    for a in np.asarray(sos, dtype=np.float64)[:, 3:]:
        nz = np.flatnonzero(a)
        if not len(nz):
            raise ValueError("Denominator must have at least on nonzero element.")
        a = a[nz[0] :]
        p = np.roots(a / a[0])
        if len(p):
            out = max(out, float(np.abs(p).max()))
    return out


def sosfilt_zi(sos: np.ndarray) -> np.ndarray:
    """``scipy.signal.sosfilt_zi(sos)``: each section's state (sections × 2) after a unit
    step held forever, the sections' gains carried from one to the next."""
    sos = np.asarray(sos)
    if sos.ndim != 2 or sos.shape[1] != 6:
        raise ValueError("sos must be shape (n_sections, 6)")
    if np.issubdtype(sos.dtype, np.integer) or sos.dtype == np.bool_:
        sos = sos.astype(np.float64)
    zi = np.empty((sos.shape[0], 2), dtype=sos.dtype)
    scale = 1.0
    for section in range(sos.shape[0]):
        b = sos[section, :3]
        a = sos[section, 3:]
        zi[section, ...] = scale * _lfilter_zi(b, a)
        scale *= np.sum(b) / np.sum(a)
    return zi


def _lfilter_zi(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """scipy.signal's ``lfilter_zi`` of one section (1-D ``b`` and ``a``)."""
    while a.shape[0] > 1 and a[0] == 0.0:
        a = a[1:]
    if a.size < 1:
        raise ValueError("There must be at least one nonzero `a` coefficient.")
    if a[0] != 1.0:
        b = b / a[0]
        a = a / a[0]
    n = max(a.shape[0], b.shape[0])
    if a.shape[0] < n:
        a = np.concatenate((a, np.zeros(n - a.shape[0], dtype=a.dtype)))
    elif b.shape[0] < n:
        b = np.concatenate((b, np.zeros(n - b.shape[0], dtype=b.dtype)))
    dt = np.result_type(a, b)
    # scipy.linalg.companion(a)
    first_row = -a[1:] / (1.0 * a[0:1])
    companion = np.zeros((n - 1, n - 1), dtype=first_row.dtype)
    companion[0, :] = first_row
    companion[np.arange(1, n - 1), np.arange(0, n - 2)] = 1
    i_minus_a = np.asarray(np.eye(n - 1) - companion.T, dtype=dt)
    return np.linalg.solve(i_minus_a, b[1:] - a[1:] * b[0])


def _zpk2sos(z: np.ndarray, p: np.ndarray, k) -> np.ndarray:
    """``scipy.signal.zpk2sos(z, p, k)`` of a digital filter, ``pairing="nearest"``."""
    z, p = np.asarray(z), np.asarray(p)
    k = np.asarray(k)
    if len(z) == len(p) == 0:
        return np.asarray([[k, 0.0, 0.0, 1.0, 0.0, 0.0]])
    p = np.concatenate((p, np.zeros(max(len(z) - len(p), 0))))
    z = np.concatenate((z, np.zeros(max(len(p) - len(z), 0))))
    n_sections = (max(len(p), len(z)) + 1) // 2
    if len(p) % 2 == 1:
        p = np.concatenate((p, [0.0]))
        z = np.concatenate((z, [0.0]))
    z = np.concatenate(_cplxreal(z))
    p = np.concatenate(_cplxreal(p))
    if not np.isreal(k):
        raise ValueError("k must be real")
    k = k.real

    def idx_worst(p):
        return np.argmin(np.abs(1 - np.abs(p)))

    sos = np.zeros((n_sections, 6))
    for si in range(n_sections - 1, -1, -1):
        p1_idx = idx_worst(p)
        p1 = p[p1_idx]
        p = np.delete(p, p1_idx)
        if np.isreal(p1) and np.isreal(p).sum() == 0:
            z1_idx = _nearest_idx(z, p1, "real")
            z1 = z[z1_idx]
            z = np.delete(z, z1_idx)
            sos[si] = _single_zpksos([z1, 0], [p1, 0], 1)
        elif (
            len(p) + 1 == len(z)
            and not np.isreal(p1)
            and np.isreal(p).sum() == 1
            and np.isreal(z).sum() == 1
        ):
            z1_idx = _nearest_idx(z, p1, "complex")
            z1 = z[z1_idx]
            z = np.delete(z, z1_idx)
            sos[si] = _single_zpksos([z1, z1.conj()], [p1, p1.conj()], 1)
        else:
            if np.isreal(p1):
                prealidx = np.flatnonzero(np.isreal(p))
                p2_idx = prealidx[idx_worst(p[prealidx])]
                p2 = p[p2_idx]
                p = np.delete(p, p2_idx)
            else:
                p2 = p1.conj()
            if len(z) > 0:
                z1_idx = _nearest_idx(z, p1, "any")
                z1 = z[z1_idx]
                z = np.delete(z, z1_idx)
                if not np.isreal(z1):
                    sos[si] = _single_zpksos([z1, z1.conj()], [p1, p2], 1)
                elif len(z) > 0:
                    z2_idx = _nearest_idx(z, p1, "real")
                    z2 = z[z2_idx]
                    z = np.delete(z, z2_idx)
                    sos[si] = _single_zpksos([z1, z2], [p1, p2], 1)
                else:
                    sos[si] = _single_zpksos([z1], [p1, p2], 1)
            else:
                sos[si] = _single_zpksos([], [p1, p2], 1)
    sos[0][:3] *= k
    return sos


def _cplxreal(z, tol=None):
    """scipy.signal's ``_cplxreal``: the complex pairs (one of each, positive imaginary part)
    and the real values of ``z``, each sorted."""
    z = np.atleast_1d(z)
    if z.size == 0:
        return z, z
    if tol is None:
        tol = 100 * np.finfo((1.0 * z).dtype).eps
    z = z[np.lexsort((abs(z.imag), z.real))]
    real_indices = abs(z.imag) <= tol * abs(z)
    zr = z[real_indices].real
    if len(zr) == len(z):
        return np.array([]), zr
    z = z[~real_indices]
    zp = z[z.imag > 0]
    zn = z[z.imag < 0]
    if len(zp) != len(zn):
        raise ValueError("Array contains complex value with no matching conjugate.")
    same_real = np.diff(zp.real) <= tol * abs(zp[:-1])
    diffs = np.diff(np.concatenate(([0], same_real, [0])))
    run_starts = np.nonzero(diffs > 0)[0]
    run_stops = np.nonzero(diffs < 0)[0]
    for i in range(len(run_starts)):
        start = run_starts[i]
        stop = run_stops[i] + 1
        for chunk in (zp[start:stop], zn[start:stop]):
            chunk[...] = chunk[np.lexsort([abs(chunk.imag)])]
    if any(abs(zp - zn.conj()) > tol * abs(zn)):
        raise ValueError("Array contains complex value with no matching conjugate.")
    zc = (zp + zn.conj()) / 2
    return zc, zr


def _nearest_idx(fro, to, which: str):
    """scipy.signal's ``_nearest_real_complex_idx``."""
    order = np.argsort(np.abs(fro - to))
    if which == "any":
        return order[0]
    mask = np.isreal(fro[order])
    if which == "complex":
        mask = ~mask
    return order[np.nonzero(mask)[0][0]]


def _single_zpksos(z, p, k) -> np.ndarray:
    """One second-order section from up to two zeros and poles (scipy's ``zpk2tf``)."""
    sos = np.zeros(6)
    b, a = _zpk2tf(z, p, k)
    sos[3 - len(b) : 3] = b
    sos[6 - len(a) : 6] = a
    return sos


def _zpk2tf(z, p, k):
    """scipy.signal's ``zpk2tf`` of one section (1-D zeros)."""
    z, p = np.asarray(z), np.asarray(p)
    k = np.asarray(k, dtype=np.result_type(np.real(z), np.real(p), k))
    if np.issubdtype(k.dtype, np.integer):
        k = k.astype(np.float64)
    z = np.atleast_1d(z)
    b = np.multiply(k, _poly(z))
    a = np.atleast_1d(np.asarray(_poly(p)))
    return b, a


def _poly(seq_of_zeros):
    """scipy.signal's ``_polyutils.poly`` (the 1-D ``np.poly``) for numpy arrays."""
    seq_of_zeros = np.atleast_1d(np.asarray(seq_of_zeros))
    if seq_of_zeros.shape[0] == 0:
        return np.asarray(1.0, dtype=np.real(seq_of_zeros).dtype)
    a = np.ones((1,), dtype=seq_of_zeros.dtype)
    one = np.ones_like(seq_of_zeros[0])
    for zero in seq_of_zeros:
        a = np.convolve(a, np.stack((one, -zero)), mode="full")
    if np.issubdtype(a.dtype, np.complexfloating):
        roots = np.asarray(seq_of_zeros, dtype=np.complex128)
        if np.all(np.sort(np.imag(roots)) == np.sort(np.imag(np.conj(roots)))):
            a = np.asarray(np.real(a), copy=True)
    return a
