"""Closed-form plane-strain solutions for verification (NumPy, vectorized).

Cracks are straight, centred at the origin, in an infinite plane. The displacement fields are
exact everywhere (Westergaard stress functions), so a finite box with these values imposed on its
boundary reproduces the infinite-plane solution and the error is pure discretization error.

* Sneddon (1946): a crack of half-length ``a`` along the x axis, opened by a uniform internal
  pressure ``p``: opening ``w(x) = 4 (1 - ν²) p / E · sqrt(a² - x²)``.
* Inclined crack under uniaxial remote compression ``σ`` along the y axis, at angle ``ψ`` to it,
  with Coulomb friction ``F = tan φ`` (Phan et al. 2003; Franceschini et al. 2020): the crack is
  closed with normal traction ``t_N = -σ sin²ψ`` and, when ``cos ψ - F sin ψ > 0``, slips by
  ``g_T(ξ) = 4 (1 - ν²)/E · σ sin ψ (cos ψ - F sin ψ) · sqrt(b² - (b - ξ)²)``, ``ξ ∈ [0, 2b]``.

Two 3D solutions for a penny-shaped crack of radius ``a`` in an infinite solid (jumps only):

* Sneddon (1946): opened by a uniform pressure ``p``, ``w(r) = 8 (1 - ν²) p / (π E) √(a² - r²)``.
* Segedin (1968): loaded by a uniform remote shear ``τ`` on its plane (and closed by a normal
  compression, which does not interact with the shear: the crack is flat and the solid
  isotropic), slips parallel to ``τ`` by ``16 (1 - ν²) τ / (π (2 - ν) E) √(a² - r²)``, with no
  opening. A uniform friction traction ``b`` (Tresca ``s``, or Coulomb ``F σ`` under the
  uniform compression ``σ``) acts against the slip: the slip is that of ``τ - b`` (0 when
  ``τ <= b``, the crack sticks).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = [
    "penny_opening",
    "penny_shear_slip",
    "inclined_crack_displacement",
    "inclined_crack_frame",
    "inclined_crack_slip",
    "inclined_crack_slip_field",
    "sneddon_displacement",
    "sneddon_opening",
    "terzaghi_parameters",
    "terzaghi_pressure",
    "terzaghi_settlement",
]


def _sqrt_cut(z: npt.NDArray[np.complex128], a: float) -> npt.NDArray[np.complex128]:
    """``sqrt(z² - a²)`` with its branch cut on ``[-a, a]`` and ``~ z`` at infinity."""
    return np.sqrt(z - a) * np.sqrt(z + a)


def _z(x, y) -> npt.NDArray[np.complex128]:
    """Complex coordinate; points on the crack line are taken on the upper face."""
    y = np.asarray(y, dtype=np.float64)
    y = np.where(y == 0.0, 0.0, y)  # -0.0 → +0.0: the upper face
    return np.asarray(x, dtype=np.float64) + 1j * y


def _elastic(E: float, nu: float) -> tuple[float, float]:
    """Shear modulus μ and plane-strain Kolosov constant κ = 3 - 4ν."""
    return E / (2 * (1 + nu)), 3 - 4 * nu


def _westergaard(x, y, a: float, load: float, E: float, nu: float):
    """Westergaard stress function of a crack ``|x| < a`` loaded by ``q`` on its faces.

    Returns ``μ, κ``, ``Z = q (z / sqrt(z² - a²) - 1)``, its primitive
    ``Ẑ = q (sqrt(z² - a²) - z)``, and ``y``.
    """
    mu, kappa = _elastic(E, nu)
    z = _z(x, y)
    s = _sqrt_cut(z, a)
    with np.errstate(all="ignore"):
        Z = np.where(s == 0, 0.0, load * (z / s - 1.0))
    return mu, kappa, Z, load * (s - z), np.asarray(y, dtype=np.float64)


def sneddon_opening(x, a: float, p: float, E: float, nu: float):
    """Opening ``w = -[[u]]_n`` (m) of Sneddon's pressurized crack at abscissa ``x``."""
    x = np.asarray(x, dtype=np.float64)
    return 4 * (1 - nu**2) * p / E * np.sqrt(np.clip(a**2 - x**2, 0.0, None))


def penny_opening(r, a: float, p: float, E: float, nu: float):
    """Opening ``w = -[[u]]_n`` (m) of Sneddon's penny crack of radius ``a`` at radius ``r``.

    ``w = 8 (1 - ν²) p / (π E) √(a² - r²)`` in an infinite solid under internal pressure ``p``
    (Sneddon 1946).
    """
    r = np.asarray(r, dtype=np.float64)
    return 8 * (1 - nu**2) * p / (np.pi * E) * np.sqrt(np.clip(a**2 - r**2, 0.0, None))


def penny_shear_slip(r, a: float, tau: float, E: float, nu: float):
    """Slip (m) at radius ``r`` of a penny crack of radius ``a`` under remote shear ``tau`` (Pa).

    ``16 (1 - ν²) τ / (π (2 - ν) E) √(a² - r²)`` (Segedin 1968; Kassir and Sih 1975, eq. for the
    shear-loaded penny crack), parallel to the shear traction on the crack plane; ``tau`` (Pa)
    is the shear that the slip releases (the remote shear minus a uniform friction traction).
    """
    r = np.asarray(r, dtype=np.float64)
    return (16 * (1 - nu**2) * tau / (np.pi * (2 - nu) * E)
            * np.sqrt(np.clip(a**2 - r**2, 0.0, None)))


def sneddon_displacement(x, y, a: float, p: float, E: float, nu: float):
    """Displacement ``(u_x, u_y)`` (m) around Sneddon's crack (mode I Westergaard field).

    ``Z = p (z / sqrt(z² - a²) - 1)``, ``Ẑ = p (sqrt(z² - a²) - z)``,
    ``2μ u_x = (κ-1)/2 Re Ẑ - y Im Z``, ``2μ u_y = (κ+1)/2 Im Ẑ - y Re Z``.
    """
    mu, kappa, Z, Zh, yy = _westergaard(x, y, a, p, E, nu)
    ux = ((kappa - 1) / 2 * Zh.real - yy * Z.imag) / (2 * mu)
    uy = ((kappa + 1) / 2 * Zh.imag - yy * Z.real) / (2 * mu)
    return ux, uy


def _mode2(x, y, a: float, tau: float, E: float, nu: float):
    """Mode II field of a crack on the x axis loaded by a uniform shear ``tau`` on its faces."""
    mu, kappa, Z, Zh, yy = _westergaard(x, y, a, tau, E, nu)
    ux = ((kappa + 1) / 2 * Zh.imag + yy * Z.real) / (2 * mu)
    uy = (-(kappa - 1) / 2 * Zh.real - yy * Z.imag) / (2 * mu)
    return ux, uy


def inclined_crack_frame(psi: float) -> tuple[npt.NDArray, npt.NDArray]:
    """Unit tangent ``t`` and normal ``n = (-t_y, t_x)`` of the inclined crack.

    ``ψ`` (rad) is the angle between the crack and the compression (y) axis; the crack runs
    from ``-b t`` to ``b t``.
    """
    t = np.array([np.sin(psi), np.cos(psi)])
    return t, np.array([-t[1], t[0]])


def _effective_shear(psi: float, sigma: float, friction: float) -> float:
    """Shear released by slip, ``σ sin ψ (cos ψ - F sin ψ)``, or 0 when the crack sticks."""
    return max(sigma * np.sin(psi) * (np.cos(psi) - friction * np.sin(psi)), 0.0)


def inclined_crack_slip(xi, b: float, psi: float, sigma: float, friction: float, E: float,
                        nu: float):
    """Slip magnitude ``g_T(ξ)`` (m) at distance ``ξ`` from the crack's first end."""
    xi = np.asarray(xi, dtype=np.float64)
    tau = _effective_shear(psi, sigma, friction)
    return 4 * (1 - nu**2) / E * tau * np.sqrt(np.clip(b**2 - (b - xi) ** 2, 0.0, None))


def inclined_crack_slip_field(x, y, b: float, psi: float, sigma: float, friction: float,
                              E: float, nu: float):
    """The part of the displacement (m) due to slip, zero when the crack sticks.

    A mode II field in the crack frame, whose sign is that of the slip relaxing the remote
    shear.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    tau = _effective_shear(psi, sigma, friction)
    if tau == 0.0:
        return np.zeros_like(x), np.zeros_like(y)
    t, n = inclined_crack_frame(psi)
    xl, yl = x * t[0] + y * t[1], x * n[0] + y * n[1]  # crack-local coordinates
    remote_shear = -sigma * t[1] * n[1]  # t·σn of the remote field on the crack plane
    vx, vy = _mode2(xl, yl, b, np.sign(remote_shear) * tau, E, nu)
    return vx * t[0] + vy * n[0], vx * t[1] + vy * n[1]


def inclined_crack_displacement(x, y, b: float, psi: float, sigma: float, friction: float,
                                E: float, nu: float):
    """Displacement (m) around the inclined frictional crack under compression ``σ`` (Pa).

    Uniform plane-strain field of ``σ_yy = -σ`` plus the slip field.
    """
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    exx = (1 + nu) * nu * sigma / E
    eyy = -(1 + nu) * (1 - nu) * sigma / E
    vx, vy = inclined_crack_slip_field(x, y, b, psi, sigma, friction, E, nu)
    return exx * x + vx, eyy * y + vy


def terzaghi_parameters(E: float, nu: float, biot: float, biot_modulus: float,
                        permeability: float, viscosity: float, load: float) -> dict[str, float]:
    """Constants of Terzaghi's consolidation of a laterally confined column (plane strain).

    A column under a constant compressive load ``load`` (Pa) on its drained top, impervious
    elsewhere, with rollers on its sides: the constrained modulus is ``K_v = λ + 2μ``, the
    undrained pressure ``p_u = b M σ₀ / (K_v + b² M)`` and the consolidation coefficient
    ``c_v = (k/η) / (1/M + b²/K_v)`` (Wang 2000, §6.2; Verruijt 2013).

    Returns:
        ``{"K_v", "p_u", "c_v"}`` in Pa, Pa and m²/s.
    """
    lam = E * nu / ((1 + nu) * (1 - 2 * nu))
    mu = E / (2 * (1 + nu))
    kv = lam + 2 * mu
    inv_m = 0.0 if biot_modulus == np.inf else 1.0 / biot_modulus
    pu = biot * load / (kv * inv_m + biot**2)
    cv = permeability / viscosity / (inv_m + biot**2 / kv)
    return {"K_v": kv, "p_u": pu, "c_v": cv}


def _terzaghi_decay(m, t: float, height: float, c_v: float, steps: int | None):
    """Decay of the Fourier modes ``m``: exact, or after ``steps`` implicit Euler steps."""
    rate = m**2 * c_v / height**2
    if steps is None:
        return np.exp(-rate * t)
    return (1.0 + rate * t / steps) ** (-steps)


def terzaghi_pressure(z, t: float, height: float, p_u: float, c_v: float, terms: int = 400,
                      steps: int | None = None):
    """Excess pore pressure at depth ``z`` below the drained top at time ``t > 0`` (Pa).

    ``p = Σ_k 2 p_u / m_k sin(m_k z / L) exp(-m_k² c_v t / L²)``, ``m_k = (2k+1)π/2``. With
    ``steps``, each mode decays as after that many implicit Euler steps instead,
    ``(1 + m_k² c_v Δt / L²)^(-n)``: the solution of the time-discrete, space-exact problem,
    against which a space discretization error is measured free of time error.
    """
    z = np.asarray(z, dtype=np.float64)
    m = (2 * np.arange(terms) + 1) * np.pi / 2
    decay = _terzaghi_decay(m, t, height, c_v, steps)
    return (2 * p_u / m * decay * np.sin(np.multiply.outer(z, m) / height)).sum(axis=-1)


def terzaghi_settlement(t: float, height: float, p_u: float, c_v: float, K_v: float,
                        biot: float, load: float, terms: int = 400,
                        steps: int | None = None) -> float:
    """Vertical displacement of the top, ``u_y(L, t) = (b ∫p dz - σ₀ L) / K_v`` (m, < 0)."""
    m = (2 * np.arange(terms) + 1) * np.pi / 2
    mean = (2 * p_u / m**2 * _terzaghi_decay(m, t, height, c_v, steps)).sum()
    return (biot * mean * height - load * height) / K_v
