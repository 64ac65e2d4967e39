"""Valve and fluid physics of the DAMADICS actuator (water as the medium).

Every function here is plain arithmetic on floats or float arrays, compiled
with :func:`numba.njit`, so the same code serves vectorised use (tests, the
workbench: pass numpy float arrays or floats, not pandas objects) and the
simulator's compiled loop (``_kernel.py``).

Units: pressures in kPa *absolute*, temperatures in °C, flow in t/h, travel
``x`` as the relative valve opening 0…1 (0 closed, 1 fully open).

Sources (equations written from the publications, not from any code):

* Bartyś M., de las Heras S., "Actuator simulation of the DAMADICS benchmark
  actuator system", IFAC SAFEPROCESS 2003 — eq. 7 (flow through the valve),
  eq. 8 (choked flow), eq. 9 (vapour pressure law).
* Bartyś M., de las Heras S., "Benchmark simulation model in Simulink",
  DAMADICS workshop, Hull, January 2002 (slides "Vapor pressure law",
  "Choked flow", "Control valve simulation model").
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: compiled once, cached; callable from Python with floats or float arrays and from
#: the simulator's compiled loop
_jit = nb.njit(cache=True, nogil=True)

#: Vapour-pressure law log10(pv / kPa) = b - a / T(K) (Bartyś & de las Heras 2003, eq. 9),
#: a and b fitted to the steam tables of water at 100 °C (101.3 kPa) and 250 °C (3976 kPa).
VAPOUR_A_K = 2074.2
VAPOUR_B = 7.5642
#: critical pressure of water, kPa (for the critical pressure ratio rc)
WATER_PC_KPA = 22064.0


@_jit
def vapour_pressure_kpa(t_c):
    """Vapour pressure of water in kPa at ``t_c`` °C.

    Bartyś & de las Heras 2003, eq. 9 (Hull Jan 2002, "Vapor pressure law"):
    ``log pv = -a / T + b`` with T in kelvin; within 3 % of the steam tables
    between 60 °C and 300 °C.
    """
    return 10.0 ** (VAPOUR_B - VAPOUR_A_K / (t_c + 273.15))


@_jit
def water_density(t_c):
    """Density of liquid water in kg/m³ at ``t_c`` °C (engineering fit, ±1 % 0–300 °C).

    Needed by eq. 7 of Bartyś & de las Heras 2003 (ρ, the liquid specific gravity).
    """
    return 1000.0 - 0.0178 * np.abs(t_c - 4.0) ** 1.7


@_jit
def critical_pressure_ratio(pv_kpa):
    """Critical pressure ratio rc of water, ``0.96 - 0.28 sqrt(pv / pc)``.

    The rc of Bartyś & de las Heras 2003, eq. 8 (Hull Jan 2002, "Choked flow":
    rc, critical pressure ratio for water), in the usual ISA/IEC 60534 form.
    """
    return 0.96 - 0.28 * np.sqrt(np.maximum(pv_kpa, 0.0) / WATER_PC_KPA)


@_jit
def recovery_coefficient(x, km0, km1):
    """Valve pressure recovery coefficient Km(X) = km0 - km1·X.

    Hull Jan 2002, "Choked flow" (Km curve of a typical high-recovery valve) and
    Bartyś & de las Heras 2003, Fig. 12 (Km falls as the valve opens).
    """
    return km0 - km1 * x


@_jit
def kv_relative(x, rangeability):
    """Relative equal-percentage flow coefficient Kv(X)/Kvs for opening ``x``.

    Equal-percentage characteristic R^(X-1) (DABLib §5.1: "equal percentage
    control valve"; Bartyś & de las Heras 2003, "for benchmark purposes the equal
    percentage flow characteristics was fixed"), blended with ``-(1-X)/R`` so that
    the valve closes tight at X = 0 and gives exactly Kvs at X = 1. ``x`` above 1
    (f3, erosion) extrapolates the exponential.
    """
    xx = np.maximum(x, 0.0)
    return rangeability ** (xx - 1.0) - np.maximum(1.0 - xx, 0.0) / rangeability


@_jit
def allowed_pressure_drop_kpa(x, p1_kpa, t_c, km0, km1):
    """Largest effective pressure drop before the flow chokes, kPa.

    Bartyś & de las Heras 2003, eq. 8: ``Δp_all = Km (P1 - rc·pv)``; never below 0.
    """
    pv = vapour_pressure_kpa(t_c)
    rc = critical_pressure_ratio(pv)
    return np.maximum(recovery_coefficient(x, km0, km1) * (p1_kpa - rc * pv), 0.0)


@_jit
def liquid_flow_th(kv, dp_kpa, rho):
    """Mass flow in t/h of a liquid through a restriction of coefficient ``kv``.

    Bartyś & de las Heras 2003, eq. 7: ``F = Kv sqrt(Δp / ρ)`` in engineering
    units: Kv in m³/h at Δp = 1 bar with water of 1000 kg/m³, so
    ``Q[m³/h] = Kv sqrt(Δp[bar] · 1000 / ρ)`` and ``F[t/h] = Q ρ / 1000``.
    """
    q = kv * np.sqrt(np.maximum(dp_kpa, 0.0) * 10.0 / rho)
    return q * rho / 1000.0


@_jit
def valve_flow_th(x, p1_kpa, p2_kpa, t_c, kvs, rangeability, km0, km1):
    """Flow through the equal-percentage control valve, t/h, with choked flow.

    Bartyś & de las Heras 2003, eqs. 7–9: Bernoulli flow ``Kv(X) sqrt(Δp/ρ)`` with
    ``Δp = P1 - P2``; once Δp exceeds ``Δp_all = Km (P1 - rc pv(T))`` the flow is
    choked and no longer depends on P2 (Hull Jan 2002, "Choked flow").
    """
    dp_all = allowed_pressure_drop_kpa(x, p1_kpa, t_c, km0, km1)
    dp = np.minimum(np.maximum(p1_kpa - p2_kpa, 0.0), dp_all)
    return liquid_flow_th(kvs * kv_relative(x, rangeability), dp, water_density(t_c))
