"""Seawater properties as the Haidou paper and Sea-Bird SeaSoft compute them (EOS-80 family).

Implements §3.2.2 of Ma et al. (2023) *TERCOM Challenger Deep* (``papers/tercom-challenger-deep.md``):

* :func:`practical_salinity` — PSS-78 (UNESCO 1983, Tech. Pap. Mar. Sci. 44 "UNESCO 44", p. 6-9), the
  "formula to calculate the salinity" of Sea-Bird Electronics Inc. (2007) cited after [TERCOM Eq. 13];
* :func:`density_eos80` — [TERCOM Eq. 13], EOS-80 in situ density with the secant bulk modulus (UNESCO 44 p. 15-19,
  Millero & Poisson 1981); :func:`sigma_t`, :func:`sigma_theta`, :func:`potential_temperature`;
* :func:`gravity` — [TERCOM Eq. 14], after McDougall & Barker (2011) / ``gsw.grav`` (see the deviation note there);
* :func:`depth_fofonoff_millard` — [TERCOM Eqs. 8-10], Saunders & Fofonoff's fit, SeaSoft ``depSM``;
* :func:`sound_speed_chen_millero` — Chen & Millero (1977), UNESCO 44 p. 46-49, SeaSoft ``svCM``.

Conventions (as SeaSoft): temperatures passed in are ITS-90 (°C) and converted inside to IPTS-68 with
``T68 = 1.00024 * T90`` because the UNESCO 44 formulas are fitted on IPTS-68; pressure is sea pressure in
dbar (0 at the sea surface); conductivity in S/m. Every function is NumPy-vectorised and broadcasts its
arguments; NaN in → NaN out. The check values of UNESCO 44 and SeaSoft's own columns are tested in
``tests/unit/ctd/test_seawater.py``.
"""

from __future__ import annotations

import functools
import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import ArrayLike

#: Conductivity of standard seawater C(35, 15 °C(IPTS-68), 0) in S/m (UNESCO 44 p. 9: 42.914 mS/cm).
C3515_S_M = 4.2914
#: ITS-90 -> IPTS-68 scale factor used by SeaSoft and the UNESCO 44 formulas.
T68_PER_T90 = 1.00024
#: Degrees-to-radians divisor SeaSoft uses in depSM (57.29578, not 180/pi; the difference is < 1e-6 m).
_DEG_PER_RAD_SEASOFT = 57.29578


def _f(x: ArrayLike) -> np.ndarray:
    return np.asarray(x, dtype=np.float64)


#: Elements per block in :func:`_blockwise` (16 Ki x 8 B = 128 KiB per array: the temporaries stay in L2).
BLOCK_SIZE = 16_384
#: Threads evaluating blocks concurrently (NumPy releases the GIL inside its loops); 1 disables threading.
#: Override with the ``HADAL_SEAWATER_THREADS`` environment variable.
THREADS = max(1, int(os.environ.get("HADAL_SEAWATER_THREADS", min(4, os.cpu_count() or 1))))
_POOL: ThreadPoolExecutor | None = None


def _pool() -> ThreadPoolExecutor:
    global _POOL
    if _POOL is None:
        _POOL = ThreadPoolExecutor(max_workers=THREADS, thread_name_prefix="hadal-seawater")
    return _POOL


def _blockwise(kernel: Callable[..., np.ndarray]) -> Callable[..., np.ndarray]:
    """Evaluate an element-wise NumPy kernel block by block.

    The UNESCO polynomials are dozens of element-wise NumPy operations; on large arrays each one streams its
    operands through main memory. Evaluating blocks of :data:`BLOCK_SIZE` elements keeps the temporaries in
    the CPU cache, ~3x faster on a 1 M-scan dive (``bench/bench_seawater.py``), with identical results;
    large inputs are spread over :data:`THREADS` threads (NumPy releases the GIL in its loops).
    Arguments broadcast against each other as usual; 0-d arguments are passed through as scalars.
    """

    @functools.wraps(kernel)
    def wrapper(*args: ArrayLike) -> np.ndarray:
        arrs = [_f(a) for a in args]
        shape = np.broadcast_shapes(*(a.shape for a in arrs))
        n = int(np.prod(shape)) if shape else 1
        if not shape:  # all scalars: evaluate as 1-element arrays (the kernels work in place)
            flat = [a.reshape(1) for a in arrs]
        else:
            flat = [a if a.ndim == 0 else np.ascontiguousarray(np.broadcast_to(a, shape)).reshape(-1) for a in arrs]
        out = np.empty(n, dtype=np.float64)

        def block(i: int) -> None:
            out[i:i + BLOCK_SIZE] = kernel(*(a if a.ndim == 0 else a[i:i + BLOCK_SIZE] for a in flat))

        starts = range(0, n, BLOCK_SIZE)
        if THREADS > 1 and n >= 4 * BLOCK_SIZE:
            list(_pool().map(block, starts))
        else:
            for i in starts:
                block(i)
        return out.reshape(shape)

    return wrapper


def t68_from_t90(temperature_its90_degc: ArrayLike) -> np.ndarray:
    """IPTS-68 temperature (°C) from ITS-90 (°C): ``T68 = 1.00024 T90`` (SeaSoft convention)."""
    return _f(temperature_its90_degc) * T68_PER_T90


def t90_from_t68(temperature_ipts68_degc: ArrayLike) -> np.ndarray:
    """ITS-90 temperature (°C) from IPTS-68 (°C): ``T90 = T68 / 1.00024``."""
    return _f(temperature_ipts68_degc) / T68_PER_T90


# --------------------------------------------------------------------------------------------- PSS-78
# UNESCO 44 p. 6-9 (Lewis & Perkin 1981): S = sum a_i Rt^(i/2) + dS(t) sum b_i Rt^(i/2)
_A = (0.0080, -0.1692, 25.3851, 14.0941, -7.0261, 2.7081)
_B = (0.0005, -0.0056, -0.0066, -0.0375, 0.0636, -0.0144)
_K = 0.0162
_C = (0.6766097, 2.00564e-2, 1.104259e-4, -6.9698e-7, 1.0031e-9)  # rt(t)
_D = (3.426e-2, 4.464e-4, 4.215e-1, -3.107e-3)  # Rp denominator
_E = (2.070e-5, -6.370e-10, 3.989e-15)  # Rp numerator


def pss78_ratios(conductivity_ratio: ArrayLike, temperature_ipts68_degc: ArrayLike, pressure_dbar: ArrayLike
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PSS-78 intermediate ratios ``(Rp, rt, Rt)`` of UNESCO 44 p. 6-9 (t in °C IPTS-68, p in dbar):
    ``rt(t)`` (C(35,t,0)/C(35,15,0)), ``Rp(R,t,p)`` (pressure correction) and ``Rt = R / (Rp rt)``."""
    r, t, p = np.broadcast_arrays(_f(conductivity_ratio), _f(temperature_ipts68_degc), _f(pressure_dbar))
    rt = _horner(t, *_C[::-1])
    den = _horner(t, _D[1], _D[0], 1.0)
    den += r * (_D[2] + _D[3] * t)
    rp = _horner(p, _E[2], _E[1], _E[0], 0.0)
    rp /= den
    rp += 1.0
    return rp, rt, r / (rp * rt)


def salinity_from_ratio(conductivity_ratio: ArrayLike, temperature_ipts68_degc: ArrayLike,
                        pressure_dbar: ArrayLike) -> np.ndarray:
    """PSS-78 practical salinity (dimensionless) from the conductivity ratio ``R = C/C(35,15,0)``.

    UNESCO 44 p. 6-9 (``SAL78``): ``Rt = R / (Rp rt)`` (:func:`pss78_ratios`), then
    ``S = Σ a_i Rt^(i/2) + (t-15)/(1+k(t-15)) Σ b_i Rt^(i/2)``; ``t`` in °C **IPTS-68**, ``p`` in dbar. As
    SeaSoft, no low-salinity (Hill et al. 1986) extension: ``Rt`` is clamped to >= 1e-6 and ``R <= 0``
    gives S = 0. Valid range of PSS-78: 2 <= S <= 42, -2 <= t <= 35 °C, p <= 10 000 dbar.
    """
    return _salinity_kernel(conductivity_ratio, temperature_ipts68_degc, pressure_dbar)


@_blockwise
def _salinity_kernel(r: np.ndarray, t: np.ndarray, p: np.ndarray) -> np.ndarray:
    x = pss78_ratios(r, t, p)[2]
    np.maximum(x, 1e-6, out=x)  # SeaSoft: Rt <= 0 -> 1e-6 (NaN stays NaN)
    np.sqrt(x, out=x)
    sb = _horner(x, *_B[::-1])
    dt = t - 15.0
    sb *= dt
    dt *= _K
    dt += 1.0
    sb /= dt
    s = _horner(x, *_A[::-1])
    s += sb
    with np.errstate(invalid="ignore"):
        np.copyto(s, 0.0, where=r <= 0.0)
    return s


def practical_salinity(conductivity_s_m: ArrayLike, temperature_its90_degc: ArrayLike,
                       pressure_dbar: ArrayLike) -> np.ndarray:
    """Practical salinity SP (PSS-78, dimensionless "psu") from conductivity, temperature and pressure.

    Sea-Bird Electronics Inc. (2007) / UNESCO 44 p. 6-9, as SeaSoft ``sal00`` computes it:
    ``R = C / 4.2914 S/m``, temperature converted to IPTS-68 (``T68 = 1.00024 T90``), then
    :func:`salinity_from_ratio`. Non-positive conductivity (sensor in air) gives 0 like SeaSoft.

    Parameters: ``conductivity_s_m`` (S/m), ``temperature_its90_degc`` (°C ITS-90), ``pressure_dbar``
    (sea pressure, dbar). Returns an array of SP, NaN where any input is NaN.
    """
    return _practical_salinity_kernel(conductivity_s_m, temperature_its90_degc, pressure_dbar)


@_blockwise
def _practical_salinity_kernel(c: np.ndarray, t90: np.ndarray, p: np.ndarray) -> np.ndarray:
    return _salinity_kernel.__wrapped__(c / C3515_S_M, t90 * T68_PER_T90, p)


def conductivity_ratio(salinity: ArrayLike, temperature_ipts68_degc: ArrayLike, pressure_dbar: ArrayLike,
                       *, iterations: int = 30) -> np.ndarray:
    """Inverse of PSS-78: conductivity ratio R from SP, t (°C IPTS-68) and p (dbar) (UNESCO 44 ``CNDR``).

    Solved by vectorised Newton iteration on ``R`` (numerical derivative of :func:`salinity_from_ratio`),
    started from ``R ≈ rt(t) S/35``; converges to 1e-13 in a few iterations over the oceanographic range.
    """
    s, t, p = np.broadcast_arrays(_f(salinity), _f(temperature_ipts68_degc), _f(pressure_dbar))
    r = _horner(t, *_C[::-1]) * np.maximum(s, 0.0) / 35.0 + 1e-3
    for _ in range(iterations):
        r_new = r - (salinity_from_ratio(r, t, p) - s) / _dsdr(r, t, p)
        if np.all(np.abs(r_new - r)[np.isfinite(r_new)] < 1e-13):
            r = r_new
            break
        r = np.maximum(r_new, 1e-8)
    return r


def _dsdr(r: np.ndarray, t: np.ndarray, p: np.ndarray, h: float = 1e-7) -> np.ndarray:
    return (salinity_from_ratio(r + h, t, p) - salinity_from_ratio(r - h, t, p)) / (2 * h)


def conductivity_from_salinity(salinity: ArrayLike, temperature_its90_degc: ArrayLike,
                               pressure_dbar: ArrayLike) -> np.ndarray:
    """Conductivity (S/m) whose PSS-78 salinity is ``salinity`` at (T90 °C, p dbar): inverse of
    :func:`practical_salinity` (UNESCO 44 ``CNDR`` times C(35,15,0) = 4.2914 S/m)."""
    return conductivity_ratio(salinity, t68_from_t90(temperature_its90_degc), pressure_dbar) * C3515_S_M


# --------------------------------------------------------------------------------------------- EOS-80
# [TERCOM Eq. 13] coefficients (UNESCO 44 p. 17-18, Millero & Poisson 1981; Sea-Bird 2007 application note 69)
_A0, _A1, _A2, _A3, _A4, _A5 = 999.842594, 6.793952e-2, -9.095290e-3, 1.001685e-4, -1.120083e-6, 6.536332e-9
_B0, _B1, _B2, _B3, _B4 = 8.24493e-1, -4.0899e-3, 7.6438e-5, -8.2467e-7, 5.3875e-9
_C0, _C1, _C2 = -5.72466e-3, 1.0227e-4, -1.6546e-6
_D0 = 4.8314e-4
_E0, _E1, _E2, _E3, _E4 = 19652.21, 148.4206, -2.327105, 1.360477e-2, -5.155288e-5
_FQ0, _FQ1, _FQ2, _FQ3 = 54.6746, -0.603459, 1.09987e-2, -6.1670e-5
_G0, _G1, _G2 = 7.944e-2, 1.6483e-2, -5.3009e-4
_H0, _H1, _H2, _H3 = 3.239908, 1.43713e-3, 1.16092e-4, -5.77905e-7
_I0, _I1, _I2 = 2.2838e-3, -1.0981e-5, -1.6078e-6
_J0 = 1.91075e-4
_K0, _K1, _K2 = 8.50935e-5, -6.12293e-6, 5.2787e-8
_M0, _M1, _M2 = -9.9348e-7, 2.0816e-8, 9.1697e-10


def _horner(x: np.ndarray, *coeffs: float) -> np.ndarray:
    """Σ c_i x^(n-i) by Horner's rule, highest power first, in place on one new array (no temporaries)."""
    out = np.multiply(x, coeffs[0])
    out += coeffs[1]
    for c in coeffs[2:]:
        out *= x
        out += c
    return out


def _rho0_and_k(s: np.ndarray, t: np.ndarray, p_bar: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
    """(one-atmosphere density ρ(S,t,0) = A+B+C+D, secant bulk modulus K(S,t,p) = E+...+M) of [TERCOM Eq. 13];
    t in °C IPTS-68, p in **bar**. Factored as ``A + S (B' + √S C' + D0 S)`` etc. (fewer operations)."""
    s = np.maximum(s, 1e-6)  # SeaSoft guard against s**1.5 of s <= 0 (NaN stays NaN)
    sq = np.sqrt(s)
    inner = _horner(t, _C2, _C1, _C0)  # C/s^1.5
    inner *= sq
    inner += _horner(t, _B4, _B3, _B2, _B1, _B0)
    inner += _D0 * s
    inner *= s
    rho0 = _horner(t, _A5, _A4, _A3, _A2, _A1, _A0)
    rho0 += inner
    inner = _horner(t, _G2, _G1, _G0)
    inner *= sq
    inner += _horner(t, _FQ3, _FQ2, _FQ1, _FQ0)
    inner *= s
    k = _horner(t, _E4, _E3, _E2, _E1, _E0)
    k += inner
    if np.ndim(p_bar) == 0 and float(p_bar) == 0.0:
        return rho0, k
    a = _horner(t, _I2, _I1, _I0)
    a += _J0 * sq
    a *= s
    a += _horner(t, _H3, _H2, _H1, _H0)
    b = _horner(t, _M2, _M1, _M0)
    b *= s
    b += _horner(t, _K2, _K1, _K0)
    b *= p_bar
    b += a
    b *= p_bar
    k += b
    return rho0, k


def density_eos80_t68(salinity: ArrayLike, temperature_ipts68_degc: ArrayLike, pressure_dbar: ArrayLike) -> np.ndarray:
    """EOS-80 in situ density (kg m⁻³), [TERCOM Eq. 13], with temperature on IPTS-68 (the UNESCO 44 ``DENS`` inputs)."""
    return _density_kernel(salinity, temperature_ipts68_degc, pressure_dbar)


@_blockwise
def _density_kernel(s: np.ndarray, t: np.ndarray, p: np.ndarray) -> np.ndarray:
    p_bar = p * 0.1
    rho0, k = _rho0_and_k(s, t, p_bar)
    np.divide(p_bar, k, out=k)  # p/K
    np.subtract(1.0, k, out=k)
    rho0 /= k
    return rho0


def density_eos80(salinity: ArrayLike, temperature_its90_degc: ArrayLike, pressure_dbar: ArrayLike) -> np.ndarray:
    """EOS-80 in situ density ρ (kg m⁻³) — [TERCOM Eq. 13] of the paper (Sea-Bird Electronics Inc. 2007).

    ``ρ = ρ(S,t,0) / (1 - p/K(S,t,p))`` with ``ρ(S,t,0) = A+B+C+D`` (one-atmosphere EOS, Millero & Poisson
    1981) and ``K = E+F+G+H+I+J+K+M`` the secant bulk modulus (UNESCO 44 p. 15-19). ``p`` in [TERCOM Eq. 13] is in
    bar: ``pressure_dbar / 10``. ``salinity`` is practical salinity, temperature ITS-90 °C (converted to
    IPTS-68 inside, as SeaSoft), ``pressure_dbar`` sea pressure. Non-positive salinity is treated as 1e-6
    (SeaSoft). Check values: UNESCO 44 p. 19 (e.g. ρ(35, 25 °C₆₈, 10 000 dbar) = 1062.53817).
    """
    return _density90_kernel(salinity, temperature_its90_degc, pressure_dbar)


@_blockwise
def _density90_kernel(s: np.ndarray, t90: np.ndarray, p: np.ndarray) -> np.ndarray:
    return _density_kernel.__wrapped__(s, t90 * T68_PER_T90, p)


def specific_volume_anomaly(salinity: ArrayLike, temperature_its90_degc: ArrayLike,
                            pressure_dbar: ArrayLike) -> np.ndarray:
    """EOS-80 specific volume anomaly δ = v(S,t,p) - v(35,0,p) (m³ kg⁻¹), UNESCO 44 ``SVAN``."""
    p = _f(pressure_dbar)
    return 1.0 / density_eos80(salinity, temperature_its90_degc, p) - 1.0 / density_eos80_t68(35.0, 0.0, p)


def sigma_t(salinity: ArrayLike, temperature_its90_degc: ArrayLike) -> np.ndarray:
    """σt = ρ(S, t, 0) - 1000 (kg m⁻³), SeaSoft ``sigma-t00`` (EOS-80 at zero sea pressure, in situ t).
    Evaluated block-wise (:func:`_blockwise`): memory ~ the output (``bench/bench_depth_memory.py``)."""
    return _sigma_t_kernel(salinity, temperature_its90_degc)


@_blockwise
def _sigma_t_kernel(s: np.ndarray, t90: np.ndarray) -> np.ndarray:
    s, t = np.broadcast_arrays(s, t90 * T68_PER_T90)
    out = _rho0_and_k(s, t, 0.0)[0]
    out -= 1000.0
    return out


# ------------------------------------------------------------------------------- potential temperature
def adiabatic_lapse_rate(salinity: ArrayLike, temperature_ipts68_degc: ArrayLike, pressure_dbar: ArrayLike) -> np.ndarray:
    """Adiabatic temperature gradient Γ (°C dbar⁻¹), Bryden (1973), UNESCO 44 ``ATG``; t in °C IPTS-68."""
    s, t, p = _f(salinity), _f(temperature_ipts68_degc), _f(pressure_dbar)
    ds = s - 35.0
    return ((((-2.1687e-16 * t + 1.8676e-14) * t - 4.6206e-13) * p
             + ((2.7759e-12 * t - 1.1351e-10) * ds + ((-5.4481e-14 * t + 8.733e-12) * t - 6.7795e-10) * t
                + 1.8741e-8)) * p
            + (-4.2393e-8 * t + 1.8932e-6) * ds + ((6.6228e-10 * t - 6.836e-8) * t + 8.5258e-6) * t + 3.5803e-5)


def potential_temperature_t68(salinity: ArrayLike, temperature_ipts68_degc: ArrayLike, pressure_dbar: ArrayLike,
                              reference_pressure_dbar: ArrayLike = 0.0) -> np.ndarray:
    """Potential temperature θ (°C IPTS-68), UNESCO 44 ``THETA``: one 4th-order Runge-Kutta step of
    :func:`adiabatic_lapse_rate` from ``pressure_dbar`` to ``reference_pressure_dbar`` (Fofonoff 1977).
    Check value θ(40, 40 °C, 10 000 dbar) = 36.89073 °C."""
    s, t0, p0, pr = np.broadcast_arrays(_f(salinity), _f(temperature_ipts68_degc), _f(pressure_dbar),
                                        _f(reference_pressure_dbar))
    h = pr - p0
    xk = h * adiabatic_lapse_rate(s, t0, p0)
    t = t0 + 0.5 * xk
    q = xk
    p = p0 + 0.5 * h
    xk = h * adiabatic_lapse_rate(s, t, p)
    t = t + 0.29289322 * (xk - q)
    q = 0.58578644 * xk + 0.121320344 * q
    xk = h * adiabatic_lapse_rate(s, t, p)
    t = t + 1.707106781 * (xk - q)
    q = 3.414213562 * xk - 4.121320344 * q
    p = p + 0.5 * h
    xk = h * adiabatic_lapse_rate(s, t, p)
    return t + (xk - 2.0 * q) / 6.0


def potential_temperature(salinity: ArrayLike, temperature_its90_degc: ArrayLike, pressure_dbar: ArrayLike,
                          reference_pressure_dbar: ArrayLike = 0.0) -> np.ndarray:
    """Potential temperature θ (°C ITS-90) referred to ``reference_pressure_dbar`` (UNESCO 44 ``THETA``,
    computed on IPTS-68 and converted back, like SeaSoft ``potemp090C``)."""
    return t90_from_t68(potential_temperature_t68(salinity, t68_from_t90(temperature_its90_degc), pressure_dbar,
                                                  reference_pressure_dbar))


def sigma_theta(salinity: ArrayLike, temperature_its90_degc: ArrayLike, pressure_dbar: ArrayLike) -> np.ndarray:
    """σθ = ρ(S, θ, 0) - 1000 (kg m⁻³), SeaSoft ``sigma-é00``: EOS-80 one-atmosphere density at the
    potential temperature referred to 0 dbar (UNESCO 44 ``THETA``, computed and used on IPTS-68)."""
    return _sigma_theta_kernel(salinity, temperature_its90_degc, pressure_dbar)


@_blockwise
def _sigma_theta_kernel(s: np.ndarray, t90: np.ndarray, p: np.ndarray) -> np.ndarray:
    # block-wise (cache-sized temporaries): the Runge-Kutta step of THETA makes ~40 temporaries per sample
    th68 = potential_temperature_t68(s, t90 * T68_PER_T90, p, 0.0)
    s, th68 = np.broadcast_arrays(s, th68)
    out = _rho0_and_k(s, th68, 0.0)[0]
    out -= 1000.0
    return out


# ---------------------------------------------------------------------------------------------- gravity
#: [TERCOM Eq. 14] constants (McDougall & Barker 2011, gsw_grav): g0, A3, B3, C3 (C3 in m⁻¹)
G0_M_S2, GRAV_A3, GRAV_B3, GRAV_C3_PER_M = 9.780327, 5.2792e-3, 2.32e-5, 2.26e-7


def gravity(latitude_deg: ArrayLike, depth_m: ArrayLike = 0.0) -> np.ndarray:
    """Gravitational acceleration g (m s⁻²) at latitude φ and depth H below the sea surface — [TERCOM Eq. 14].

    ``g = 9.780327 (1 + (5.2792e-3 + 2.32e-5 sin²φ) sin²φ) (1 + 2.26e-7 H)``, ``H`` in metres, positive down.

    Deviation from the paper: [TERCOM Eq. 14] as printed reads ``g0{1 + [A3 + (B3 - 5 sin²θ) sin²θ]}(1 - C3 H)``.
    The "``- 5``" is a transcription error (the cited source, McDougall & Barker 2011 / ``gsw.grav``, has
    ``(A3 + B3 sin²φ) sin²φ``; with ``-5 sin²φ`` g would drop by ~0.3 m s⁻² at 15° N), and the depth factor
    there is ``(1 - γ z)`` with ``z`` the *height* (negative below the sea surface), i.e. ``(1 + C3 H)`` for
    depth ``H``: gravity **increases** with depth in the ocean (moving towards the Earth's centre gains more
    than the attraction of the overlying water shell takes away). Using the printed sign would put a
    sample at 10 900 dbar ~13 m too deep after the hydrostatic integration.
    Verified against ``gsw.grav`` (``tests/unit/ctd/test_seawater.py``): ``gravity(lat, -gsw.z_from_p(p, lat))``
    equals ``gsw.grav(lat, p)`` to 1e-12, and the GSW check-cast values.
    """
    x = np.sin(np.deg2rad(_f(latitude_deg))) ** 2
    g0 = G0_M_S2 * (1.0 + (GRAV_A3 + GRAV_B3 * x) * x)
    return g0 * (1.0 + GRAV_C3_PER_M * _f(depth_m))


def gravity_unesco(latitude_deg: ArrayLike, pressure_dbar: ArrayLike = 0.0) -> np.ndarray:
    """Gravity (m s⁻²) of the Fofonoff-Millard depth formula, [TERCOM Eq. 10]:
    ``F = 9.780318 (1 + (5.2788e-3 + 2.36e-5 sin²φ) sin²φ) + 1.092e-6 p`` (``p`` in dbar) — a column-mean
    gravity (half the mean vertical gradient), not the local g; used only inside :func:`depth_fofonoff_millard`."""
    x = np.sin(_f(latitude_deg) / _DEG_PER_RAD_SEASOFT) ** 2  # on the latitudes' own shape, then broadcast
    return 9.780318 * (1.0 + (5.2788e-3 + 2.36e-5 * x) * x) + 1.092e-6 * _f(pressure_dbar)


def depth_fofonoff_millard(pressure_dbar: ArrayLike, latitude_deg: ArrayLike) -> np.ndarray:
    """Depth (m, positive down) of a standard ocean (S=35, T=0 °C) — [TERCOM Eqs. 8-10] without the ΔD/9.8 term.

    [TERCOM Eq. 9]: ``Z = (((A1 p + B1) p - C1) p + D1) p / F(φ, p)`` with A1=-1.82e-15, B1=2.279e-10, C1=2.2512e-5,
    D1=9.72659 and [TERCOM Eq. 10] ``F`` (:func:`gravity_unesco`); ``p`` in dbar. Note [TERCOM Eq. 9] as printed omits the
    final factor ``p`` of the Horner polynomial (UNESCO 44 p. 28 has it; without it H would not be a length).
    This is SeaSoft's ``depSM`` ("depth, salt water") and UNESCO 44 ``DEPTH``: check value 9712.653 m at
    10 000 dbar, 30° latitude. The geopotential anomaly term ΔD/9.8 of [TERCOM Eq. 8] is not included (as SeaSoft);
    the hydrostatic integral (:func:`hadal.depth.hydrostatic_depth`) replaces it.
    """
    return _depth_fm_kernel(pressure_dbar, latitude_deg)


@_blockwise
def _depth_fm_kernel(p: np.ndarray, lat: np.ndarray) -> np.ndarray:
    num = (((-1.82e-15 * p + 2.279e-10) * p - 2.2512e-5) * p + 9.72659) * p
    return num / gravity_unesco(lat, p)


# ----------------------------------------------------------------------------------------- sound speed
def sound_speed_chen_millero_t68(salinity: ArrayLike, temperature_ipts68_degc: ArrayLike,
                                 pressure_dbar: ArrayLike) -> np.ndarray:
    """Chen & Millero (1977) sound speed (m s⁻¹), UNESCO 44 ``SVEL`` inputs (t in °C IPTS-68, p in dbar)."""
    return _sound_speed_kernel(salinity, temperature_ipts68_degc, pressure_dbar)


@_blockwise
def _sound_speed_kernel(s: np.ndarray, t: np.ndarray, p0: np.ndarray) -> np.ndarray:
    p = p0 / 10.0  # bar
    sr = np.sqrt(np.abs(s))
    d = 1.727e-3 - 7.9836e-6 * p
    b = -1.922e-2 - 4.42e-5 * t + (7.3637e-5 + 1.7945e-7 * t) * p
    a3 = (-3.389e-13 * t + 6.649e-12) * t + 1.100e-10
    a2 = ((7.988e-12 * t - 1.6002e-10) * t + 9.1041e-9) * t - 3.9064e-7
    a1 = (((-2.0122e-10 * t + 1.0507e-8) * t - 6.4885e-8) * t - 1.2580e-5) * t + 9.4742e-5
    a0 = (((-3.21e-8 * t + 2.006e-6) * t + 7.164e-5) * t - 1.262e-2) * t + 1.389
    a = ((a3 * p + a2) * p + a1) * p + a0
    c3 = (-2.3643e-12 * t + 3.8504e-10) * t - 9.7729e-9
    c2 = (((1.0405e-12 * t - 2.5335e-10) * t + 2.5974e-8) * t - 1.7107e-6) * t + 3.1260e-5
    c1 = (((-6.1185e-10 * t + 1.3621e-7) * t - 8.1788e-6) * t + 6.8982e-4) * t + 0.153563
    c0 = ((((3.1464e-9 * t - 1.47800e-6) * t + 3.3420e-4) * t - 5.80852e-2) * t + 5.03711) * t + 1402.388
    c = ((c3 * p + c2) * p + c1) * p + c0
    return c + (a + b * sr + d * s) * s


def sound_speed_chen_millero(salinity: ArrayLike, temperature_its90_degc: ArrayLike,
                             pressure_dbar: ArrayLike) -> np.ndarray:
    """Sound speed in seawater (m s⁻¹), Chen & Millero (1977) as in UNESCO 44 p. 46-49 (SeaSoft ``svCM``).

    ``salinity`` practical, temperature ITS-90 °C (IPTS-68 inside), ``pressure_dbar`` sea pressure.
    Check value: svel(40, 40 °C₆₈, 10 000 dbar) = 1731.995 m s⁻¹. Used to correct altimeter ranges
    (:func:`hadal.depth.correct_altitude`).
    """
    return sound_speed_chen_millero_t68(salinity, t68_from_t90(temperature_its90_degc), pressure_dbar)
