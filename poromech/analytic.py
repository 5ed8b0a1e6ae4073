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

Two consolidation problems of poroelasticity (Biot), with the Biot coefficient ``b``, the Biot
modulus ``M`` and the mobility ``k/η``:

* Terzaghi: a laterally confined column under a constant load on its drained top.
* Mandel (1953): a slab ``|x| < a`` squeezed between rigid, frictionless, impervious plates by
  a constant force, drained on its sides ``x = ±a``, in plane strain. The pressure first rises
  above its undrained value at the centre (the Mandel–Cryer effect), then decays (Cheng and
  Detournay 1988; Abousleiman, Cheng, Cui, Detournay and Roegiers 1996, the isotropic case;
  Wang 2000).
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
    "mandel_displacement_x",
    "mandel_displacement_z",
    "mandel_parameters",
    "mandel_pressure",
    "mandel_roots",
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


def mandel_parameters(E: float, nu: float, biot: float, biot_modulus: float, mobility: float,
                      half_width: float, force: float) -> dict[str, float]:
    """Constants of Mandel's problem (Cheng and Detournay 1988; Abousleiman et al. 1996).

    The slab ``|x| < a`` carries the compressive force ``2F`` per unit length (``force`` is
    ``F``, N/m: the mean vertical stress is ``-F/a``). From the drained bulk modulus
    ``K = λ + 2μ/3``: the undrained one ``K_u = K + b² M``, Skempton's coefficient
    ``B = b M / K_u``, the undrained Poisson ratio ``ν_u = (3 K_u - 2μ) / (2 (3 K_u + μ))``,
    the consolidation coefficient ``c = 2 (k/η) B² μ (1 - ν) (1 + ν_u)² / (9 (1 - ν_u)
    (ν_u - ν))`` and the undrained pressure ``p₀ = F B (1 + ν_u) / (3a)``.

    Returns:
        ``{"mu", "nu_u", "B", "c", "p0", "a", "F", "nu"}`` (Pa, -, -, m²/s, Pa, m, N/m, -).
    """
    mu = E / (2 * (1 + nu))
    K = E / (3 * (1 - 2 * nu))
    Ku = K + biot**2 * biot_modulus
    B = biot * biot_modulus / Ku
    nu_u = (3 * Ku - 2 * mu) / (2 * (3 * Ku + mu))
    c = 2 * mobility * B**2 * mu * (1 - nu) * (1 + nu_u) ** 2 / (9 * (1 - nu_u) * (nu_u - nu))
    p0 = force * B * (1 + nu_u) / (3 * half_width)
    return {"mu": mu, "nu_u": nu_u, "B": B, "c": c, "p0": p0, "a": half_width, "F": force,
            "nu": nu}


def mandel_roots(nu: float, nu_u: float, terms: int = 200) -> npt.NDArray[np.float64]:
    """The first ``terms`` positive roots of ``tan α = (1 - ν)/(ν_u - ν) α``.

    The n-th root lies in ``((n-1)π, (n-1)π + π/2)``, where ``sin α - C α cos α`` changes sign
    once; found there by bisection to round-off.
    """
    C = (1 - nu) / (nu_u - nu)
    lo = np.arange(terms) * np.pi + 1e-12
    hi = np.arange(terms) * np.pi + np.pi / 2
    f_lo = np.sin(lo) - C * lo * np.cos(lo)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        f_mid = np.sin(mid) - C * mid * np.cos(mid)
        below = np.sign(f_mid) == np.sign(f_lo)
        lo, f_lo = np.where(below, mid, lo), np.where(below, f_mid, f_lo)
        hi = np.where(below, hi, mid)
    return 0.5 * (lo + hi)


def _mandel_modes(t: float, c: dict[str, float], terms: int, steps: int | None):
    """Roots ``α_n``, their decays and ``1/(α_n - sin α_n cos α_n)``."""
    alpha = mandel_roots(c["nu"], c["nu_u"], terms)
    rate = alpha**2 * c["c"] / c["a"] ** 2
    decay = np.exp(-rate * t) if steps is None else (1.0 + rate * t / steps) ** (-steps)
    return alpha, decay, 1.0 / (alpha - np.sin(alpha) * np.cos(alpha))


def mandel_pressure(x, t: float, c: dict[str, float], terms: int = 200,
                    steps: int | None = None):
    """Pore pressure (Pa) of Mandel's problem at abscissa ``x`` and time ``t`` (s).

    ``p = 2 p₀ Σ_n sin α_n / (α_n - sin α_n cos α_n) (cos(α_n x/a) - cos α_n)
    exp(-α_n² c t / a²)`` (Abousleiman et al. 1996, isotropic case), ``c`` from
    :func:`mandel_parameters`; ``p₀`` uniform at ``t <= 0`` (the undrained response). With
    ``steps``, each mode decays as after that many implicit Euler steps (see
    :func:`terzaghi_pressure`).
    """
    x = np.asarray(x, dtype=np.float64)
    if t <= 0:
        return np.full_like(x, c["p0"])
    alpha, decay, w = _mandel_modes(t, c, terms, steps)
    modes = np.cos(np.multiply.outer(x, alpha) / c["a"]) - np.cos(alpha)
    return 2 * c["p0"] * (modes * (np.sin(alpha) * w * decay)).sum(axis=-1)


def mandel_displacement_x(x, t: float, c: dict[str, float], terms: int = 200,
                          steps: int | None = None):
    """Horizontal displacement (m) of Mandel's problem at abscissa ``x`` and time ``t`` (s).

    ``u_x = [F ν/(2μa) - F ν_u/(μa) Σ_n sin α_n cos α_n/(α_n - sin α_n cos α_n) e_n] x
    + F/μ Σ_n cos α_n/(α_n - sin α_n cos α_n) sin(α_n x/a) e_n``, ``e_n = exp(-α_n² c t/a²)``;
    at ``t <= 0`` the undrained ``F ν_u x / (2μa)``.
    """
    x = np.asarray(x, dtype=np.float64)
    F, mu, a = c["F"], c["mu"], c["a"]
    if t <= 0:
        return F * c["nu_u"] * x / (2 * mu * a)
    alpha, decay, w = _mandel_modes(t, c, terms, steps)
    sc = (np.sin(alpha) * np.cos(alpha) * w * decay).sum()
    modes = np.sin(np.multiply.outer(x, alpha) / a) @ (np.cos(alpha) * w * decay)
    return (F * c["nu"] / (2 * mu * a) - F * c["nu_u"] / (mu * a) * sc) * x + F / mu * modes


def mandel_displacement_z(z, t: float, c: dict[str, float], terms: int = 200,
                          steps: int | None = None):
    """Vertical displacement (m) of Mandel's problem at height ``z`` above the mid-plane.

    ``u_z = [-F (1 - ν)/(2μa) + F (1 - ν_u)/(μa) Σ_n sin α_n cos α_n/(α_n - sin α_n cos α_n)
    exp(-α_n² c t/a²)] z``: the plates stay flat; at ``t <= 0`` the undrained
    ``-F (1 - ν_u) z / (2μa)``.
    """
    z = np.asarray(z, dtype=np.float64)
    F, mu, a = c["F"], c["mu"], c["a"]
    if t <= 0:
        return -F * (1 - c["nu_u"]) * z / (2 * mu * a)
    alpha, decay, w = _mandel_modes(t, c, terms, steps)
    sc = (np.sin(alpha) * np.cos(alpha) * w * decay).sum()
    return (-F * (1 - c["nu"]) / (2 * mu * a) + F * (1 - c["nu_u"]) / (mu * a) * sc) * z
