"""The residual low-pass filter's design in numpy: a digital Butterworth low-pass as
second-order sections, the sections' steady state after a unit step, and their poles.

Seed 000 (Laukonen et al., Sec. IV) filters every residual with "a fourth-order Butterworth
low-pass filter with a cutoff frequency of π/100"; :class:`~diag_plugin.diagnose.residuals.
LowPass` runs it. These are the steps of ``scipy.signal.butter(N, Wn, output="sos")``,
``sosfilt_zi`` and ``sos2zpk`` (scipy 1.17, ``scipy/signal/_filter_design.py`` and
``_signaltools.py``) for that one case, the same numpy operations in the same order, so the
coefficients are the same bits (tests/test_butterworth.py compares them with scipy's over
orders 1–12 and hundreds of cut-offs): importing ``scipy.signal`` took ~0.8 CPU s of every
``diag diagnose`` (it imports ``scipy.stats`` and more), for a design of a few microseconds
(issue 34).

1. Analog prototype (``buttap``): no zeros, poles ``−exp(jπm / 2N)``, ``m = −N+1, −N+3, …,
   N−1``, gain 1, on the unit circle of the s-plane.
2. Pre-warped cut-off ``ω = 2·fs·tan(π·Wn / fs)`` with ``fs = 2`` (``Wn`` in units of the
   Nyquist frequency), the prototype scaled to it (``lp2lp_zpk``: poles × ω, gain × ω^N).
3. Bilinear transform (``bilinear_zpk``): ``z = (2fs + s) / (2fs − s)``, the N zeros at
   infinity to ``z = −1``, the gain × ``Re(Π(2fs − zeros) / Π(2fs − poles))``.
4. Second-order sections (``zpk2sos``, pairing "nearest"): the pole nearest the unit circle
   first, with its conjugate (or the nearest real pole) and the zeros nearest it, into the
   last section; the gain into the first.
"""

from __future__ import annotations

import numpy as np

__all__ = ["butter_sos", "sos_poles", "sosfilt_zi"]


def butter_sos(order: int, wn: float) -> np.ndarray:
    """``scipy.signal.butter(order, wn, output="sos")``: the digital Butterworth low-pass of
    ``order`` with cut-off ``wn`` (0 < wn < 1, 1 = the Nyquist frequency, π rad/sample) as
    ``(sections, 6)`` rows ``b0 b1 b2 a0 a1 a2`` (the module doc's steps 1–4)."""
    n = int(order)
    if n < 1 or n != order:
        raise ValueError(f"filter order must be a positive integer, got {order!r}")
    w = np.asarray(wn, dtype=np.float64)
    if not 0 < w < 1:
        raise ValueError("Digital filter critical frequencies must be 0 < Wn < 1")
    # 1. the analog prototype (buttap)
    z = np.asarray([], dtype=np.float64)
    m = np.arange(-n + 1, n, 2, dtype=np.float64)
    p = -np.exp(1j * np.pi * m / (2 * n))
    k = 1.0
    # 2. pre-warped, scaled to the cut-off (iirfilter, lp2lp_zpk)
    fs = 2.0
    wo = float(2 * fs * np.tan(np.pi * w / fs))
    degree = p.shape[0] - z.shape[0]
    z, p, k = wo * z, wo * p, k * wo**degree
    # 3. the bilinear transform (bilinear_zpk)
    fs2 = 2.0 * fs
    z_z = np.concatenate(((fs2 + z) / (fs2 - z), -np.ones(degree)))
    p_z = (fs2 + p) / (fs2 - p)
    k_z = k * np.real(np.prod(fs2 - z) / np.prod(fs2 - p))
    # 4. second-order sections
    return _zpk2sos(z_z, p_z, k_z)


def _zpk2sos(z: np.ndarray, p: np.ndarray, k: float) -> np.ndarray:
    """``scipy.signal.zpk2sos(z, p, k)`` of a digital filter, pairing "nearest", with at
    least as many poles as zeros (``butter_sos``'s step 4)."""
    p = np.concatenate((p, np.zeros(max(len(z) - len(p), 0))))
    z = np.concatenate((z, np.zeros(max(len(p) - len(z), 0))))
    n_sections = (max(len(p), len(z)) + 1) // 2
    if len(p) % 2 == 1:
        p = np.concatenate((p, [0.0]))
        z = np.concatenate((z, [0.0]))
    z = np.concatenate(_cplxreal(z))
    p = np.concatenate(_cplxreal(p))
    k = np.asarray(k).real

    def idx_worst(p):
        return np.argmin(np.abs(1 - np.abs(p)))

    sos = np.zeros((n_sections, 6))
    for si in range(n_sections - 1, -1, -1):
        p1_idx = idx_worst(p)
        p1 = p[p1_idx]
        p = np.delete(p, p1_idx)
        if np.isreal(p1) and np.isreal(p).sum() == 0:
            z1_idx = _nearest(z, p1, "real")
            z1 = z[z1_idx]
            z = np.delete(z, z1_idx)
            sos[si] = _section([z1, 0], [p1, 0])
        elif (
            len(p) + 1 == len(z)
            and not np.isreal(p1)
            and np.isreal(p).sum() == 1
            and np.isreal(z).sum() == 1
        ):
            z1_idx = _nearest(z, p1, "complex")
            z1 = z[z1_idx]
            z = np.delete(z, z1_idx)
            sos[si] = _section([z1, z1.conj()], [p1, p1.conj()])
        else:
            if np.isreal(p1):
                prealidx = np.flatnonzero(np.isreal(p))
                p2_idx = prealidx[idx_worst(p[prealidx])]
                p2 = p[p2_idx]
                p = np.delete(p, p2_idx)
            else:
                p2 = p1.conj()
            if len(z) > 0:
                z1_idx = _nearest(z, p1, "any")
                z1 = z[z1_idx]
                z = np.delete(z, z1_idx)
                if not np.isreal(z1):
                    sos[si] = _section([z1, z1.conj()], [p1, p2])
                elif len(z) > 0:
                    z2_idx = _nearest(z, p1, "real")
                    z2 = z[z2_idx]
                    z = np.delete(z, z2_idx)
                    sos[si] = _section([z1, z2], [p1, p2])
                else:
                    sos[si] = _section([z1], [p1, p2])
            else:
                sos[si] = _section([], [p1, p2])
    sos[0][:3] *= k
    return sos


def _cplxreal(z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``scipy.signal``'s ``_cplxreal``: the complex values of ``z`` with a positive imaginary
    part (each conjugate pair averaged) and the real ones, each sorted by real part."""
    z = np.atleast_1d(z)
    if z.size == 0:
        return z, z
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
    return (zp + zn.conj()) / 2, zr


def _nearest(fro: np.ndarray, to: complex, which: str) -> int:
    """Index of the value of ``fro`` nearest ``to`` (``which``: of any, of the real or of
    the complex ones; ``_nearest_real_complex_idx``)."""
    order = np.argsort(np.abs(fro - to))
    if which == "any":
        return order[0]
    mask = np.isreal(fro[order])
    if which == "complex":
        mask = ~mask
    return order[np.nonzero(mask)[0][0]]


def _section(z: list, p: list) -> np.ndarray:
    """One section ``b0 b1 b2 a0 a1 a2`` of zeros ``z`` and poles ``p``, gain 1
    (``_single_zpksos``, ``zpk2tf``)."""
    sos = np.zeros(6)
    z, p = np.asarray(z), np.asarray(p)
    k = np.atleast_1d(np.asarray(1, dtype=np.result_type(np.real(z), np.real(p), 1)))
    if k.dtype.kind in "iub":
        k = k.astype(np.float64)
    b = np.multiply(k, _poly(np.atleast_1d(z)))
    a = np.atleast_1d(np.asarray(_poly(p)))
    sos[3 - len(b) : 3] = b
    sos[6 - len(a) : 6] = a
    return sos


def _poly(roots: np.ndarray) -> np.ndarray:
    """The monic polynomial of ``roots`` (``scipy.signal._polyutils.poly``, numpy's
    ``poly`` in one dimension), real when the roots come in conjugate pairs."""
    roots = np.atleast_1d(np.asarray(roots))
    if roots.shape[0] == 0:
        return np.asarray(1.0, dtype=np.real(roots).dtype)
    a = np.ones((1,), dtype=roots.dtype)
    one = np.ones_like(roots[0])
    for zero in roots:
        a = np.convolve(a, np.stack((one, -zero)), mode="full")
    if a.dtype.kind == "c":
        r = np.asarray(roots, dtype=np.complex128)
        if np.all(np.sort(np.imag(r)) == np.sort(np.imag(np.conj(r)))):
            a = np.asarray(np.real(a), copy=True)
    return a


def sosfilt_zi(sos: np.ndarray) -> np.ndarray:
    """``scipy.signal.sosfilt_zi``: each section's state ``(sections, 2)`` after a unit step
    held forever (the filter's steady state, × a value to start at that value): per section
    the solution of ``(I − Aᵀ) zi = b[1:] − a[1:]·b[0]`` (``lfilter_zi``; ``A`` the companion
    matrix of ``a``), scaled by the DC gain of the sections before it."""
    sos = np.asarray(sos)
    if sos.ndim != 2 or sos.shape[1] != 6:
        raise ValueError("sos must be shape (n_sections, 6)")
    zi = np.empty((sos.shape[0], 2), dtype=sos.dtype)
    scale = 1.0
    for section in range(sos.shape[0]):
        b = sos[section, :3]
        a = sos[section, 3:]
        zi[section, ...] = scale * _lfilter_zi(b, a)
        scale *= np.sum(b) / np.sum(a)
    return zi


def _lfilter_zi(b: np.ndarray, a: np.ndarray) -> np.ndarray:
    """``scipy.signal.lfilter_zi`` of one section (``a[0]`` not zero)."""
    while a.shape[0] > 1 and a[0] == 0.0:
        a = a[1:]
    if a[0] != 1.0:
        b = b / a[0]
        a = a / a[0]
    n = max(a.shape[0], b.shape[0])
    if a.shape[0] < n:
        a = np.concatenate((a, np.zeros(n - a.shape[0], dtype=a.dtype)))
    elif b.shape[0] < n:
        b = np.concatenate((b, np.zeros(n - b.shape[0], dtype=b.dtype)))
    dt = np.result_type(a, b)
    companion = np.zeros((n - 1, n - 1), dtype=(-a[1:] / (1.0 * a[0:1])).dtype)
    companion[0, :] = -a[1:] / (1.0 * a[0:1])
    companion[np.arange(1, n - 1), np.arange(0, n - 2)] = 1
    i_minus_a = np.asarray(np.eye(n - 1) - companion.T, dtype=dt)
    return np.linalg.solve(i_minus_a, b[1:] - a[1:] * b[0])


def sos_poles(sos: np.ndarray) -> np.ndarray:
    """The poles of second-order sections (``scipy.signal.sos2zpk``'s, each section's
    denominator's roots; a first-order section's missing pole as 0)."""
    out = np.zeros(sos.shape[0] * 2, dtype=np.complex128)
    for s in range(sos.shape[0]):
        den = np.trim_zeros(np.asarray(sos[s, 3:]), "f")
        r = np.roots(den / den[0])
        out[2 * s : 2 * s + r.shape[0]] = r
    return out
