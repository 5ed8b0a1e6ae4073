"""The four discretizations of Coulomb frictional contact on fractures: pure UFL.

Equation numbers refer to Beaude, Chouly, Laaziri, Masson (2023). Every formulation is written
with the same three *complementarity arguments* ``(P_n, P_τ, S)``, chosen so that at a solution
the contact traction is ``T_n = [P_n]_R-`` and ``T_τ = [P_τ]_S``; a point is in contact when
``P_n < 0`` and slips when ``|P_τ| > S``:

=================  ====================================  ===============================
formulation        ``P_n``                               ``P_τ``
=================  ====================================  ===============================
nitsche (8)        ``T_n(u) - β_n [[u]]_n``              ``T_τ(u) - β_τ [[u]]_τ``
mean_nitsche (7)   ``π⁰T_n(u) - β_n π⁰[[u]]_n``          ``π⁰T_τ(u) - β_τ π⁰[[u]]_τ``
stabilized (5/6)   as mean_nitsche                       as mean_nitsche
mixed (3/4)        ``-(λ_n + β_n π⁰[[u]]_n)``            ``-(λ_τ + β_τ π⁰[[u]]_τ)``
=================  ====================================  ===============================

with ``S = -F [P_n]_R-`` (Coulomb), ``S = s`` (Tresca), and no tangential terms at all when
frictionless. The face averages ``π⁰`` are extra facewise-constant unknowns ("averages") tied to
``u`` by linear equations, which keeps the Jacobian exact. Multipliers ``λ = -T`` live in the
same DG0 space on the fracture faces, in the ``(n⁺, τ_1, …, τ_{d-1})`` basis. Tangential
quantities (``P_τ``, ``λ_τ``, ``[[u]]_τ``) are scalars in 2D and 2-vectors in the fracture's
tangent frame in 3D, where ``[·]_S`` projects on the disc of radius ``S``.

Every fracture integral uses the quadrature of :func:`quadrature_degree` (``2k`` for
displacements of degree ``k``: ``k + 1`` Gauss points per face). For pointwise ``nitsche`` these
Gauss points *are* the contact points: the state (open/stick/slip) is decided at each of them,
so the residual, its Jacobian, the reported face means and the count of active-set changes must
all use the same points.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import ufl

from poromech.forms.fracture import (
    FractureKinematics,
    ball_branch,
    ball_projection,
    contact_branch,
    jump,
    magnitude,
    negative_part,
    normal_jump,
    slip,
    tangential_product,
)

__all__ = [
    "FORMULATIONS",
    "FRICTION_LAWS",
    "ContactParameters",
    "ContactState",
    "active_set_code",
    "average_names",
    "averages_residual",
    "complementarity_arguments",
    "consistent_face_values",
    "contact_measure",
    "displacement_residual",
    "multiplier_mass",
    "multiplier_residual",
    "multiplier_size",
    "pointwise",
    "quadrature_degree",
    "state_indicators",
]

FORMULATIONS = ("none", "mixed", "stabilized_mixed", "mean_nitsche", "nitsche")
FRICTION_LAWS = ("coulomb", "tresca", "frictionless")


@dataclass(frozen=True)
class ContactParameters:
    """Contact law and discretization parameters as UFL data.

    Attributes:
        formulation: One of :data:`FORMULATIONS`.
        friction: One of :data:`FRICTION_LAWS`.
        theta: Nitsche symmetry parameter θ (-1, 0 or 1).
        beta_n: ``β_n = β_n⁰ / h_σ`` (Pa/m); for ``mixed`` the ``β_n^sm`` of its
            complementarity functions, its only use there.
        beta_t: ``β_τ = β_τ⁰ / h_σ`` (Pa/m); for ``mixed`` ``β_τ^sm``.
        friction_coefficient: Coulomb coefficient ``F`` (Coulomb only).
        slip_bound: Tresca threshold ``s`` (Pa) (Tresca only).
        average_scale: Weight (Pa/m) of the linear equations defining face averages of jumps.
        quadrature_degree: Quadrature degree of every fracture integral (None: UFL's estimate);
            see :func:`quadrature_degree`.
        dim: Space dimension ``d`` (tangential quantities have ``d - 1`` components).
    """

    formulation: str
    friction: str
    theta: float
    beta_n: ufl.core.expr.Expr
    beta_t: ufl.core.expr.Expr
    friction_coefficient: ufl.core.expr.Expr | None = None
    slip_bound: ufl.core.expr.Expr | None = None
    average_scale: ufl.core.expr.Expr | float = 1.0
    quadrature_degree: int | None = None
    dim: int = 2

    @property
    def tangential(self) -> bool:
        """Whether tangential (friction) terms exist."""
        return self.friction != "frictionless"

    @property
    def active(self) -> bool:
        """Whether the contact conditions are imposed at all."""
        return self.formulation != "none"

    @property
    def piecewise_affine(self) -> bool:
        """Whether the residual is piecewise affine in the unknowns.

        Its Jacobian is then a function of the contact branches only (the active set), which
        lets Newton keep a Jacobian while the active set is unchanged. True in 2D, where the
        friction projection is a clip to ``[-S, S]``, and without friction; false for friction
        in 3D, where the projection on the disc of radius ``S`` depends on the slip direction.
        """
        return self.dim == 2 or not self.tangential or not self.active


def quadrature_degree(degree: int) -> int:
    """Quadrature degree of the fracture integrals for displacements of degree ``degree``.

    ``2k`` integrates the Nitsche terms ``[P_n]_R- [[v]]_n`` exactly on every face where the
    state does not change (``k + 1`` Gauss points) and the facewise formulations exactly.
    """
    return 2 * degree


def pointwise(p: ContactParameters) -> bool:
    """Whether the contact state varies inside a face (pointwise ``nitsche``)."""
    return p.formulation == "nitsche"


def contact_measure(p: ContactParameters, dG):
    """The fracture measure ``dG`` with the quadrature of ``p``."""
    return dG if p.quadrature_degree is None else dG(degree=p.quadrature_degree)


def multiplier_size(p: ContactParameters) -> int:
    """Number of multiplier components per fracture face (0 for Nitsche-type methods).

    ``λ_n``, and with friction the ``d - 1`` components of ``λ_τ``.
    """
    if p.formulation in ("mixed", "stabilized_mixed"):
        return p.dim if p.tangential else 1
    return 0


def _tangential_names(name: str, p: ContactParameters) -> tuple[str, ...]:
    """``name`` in 2D, ``name1, name2`` (its components in the tangent frame) in 3D."""
    return (name,) if p.dim == 2 else tuple(f"{name}{i + 1}" for i in range(p.dim - 1))


def average_names(p: ContactParameters) -> tuple[str, ...]:
    """Names of the face-average unknowns a formulation needs, in storage order."""
    jt, tt = _tangential_names("jump_t", p), _tangential_names("traction_t", p)
    if p.formulation == "mixed":
        return ("jump_n", *jt) if p.tangential else ("jump_n",)
    if p.formulation in ("stabilized_mixed", "mean_nitsche"):
        names = ("traction_n", "jump_n")
        return (*names, *tt, *jt) if p.tangential else names
    return ()


def _components(f, k: int) -> list:
    """Components of a DG0 field with ``k`` values (a scalar field when ``k == 1``)."""
    return [f] if k == 1 else [f[i] for i in range(k)]


def _named(f, names: tuple[str, ...]) -> dict:
    return dict(zip(names, _components(f, len(names)), strict=True))


def _tangential_part(values: list, p: ContactParameters):
    """The tangential quantity of its components: a scalar in 2D, a vector in 3D."""
    return values[0] if len(values) == 1 else ufl.as_vector(values)


def _average(a: dict, name: str, p: ContactParameters):
    """Face average ``name`` (``jump_t``, ``traction_t`` are tangential quantities)."""
    if name in a:
        return a[name]
    return _tangential_part([a[k] for k in _tangential_names(name, p)], p)


def _multiplier_t(lm: list, p: ContactParameters):
    """``λ_τ`` of the multiplier components ``[λ_n, λ_τ...]``."""
    return _tangential_part(lm[1:], p)


def slip_threshold(p: ContactParameters, pn):
    """``S = -F [P_n]_R-`` (Coulomb) or ``S = s`` (Tresca)."""
    if p.friction == "coulomb":
        return -p.friction_coefficient * negative_part(pn)
    return p.slip_bound


def complementarity_arguments(fk: FractureKinematics, p: ContactParameters, u, lam=None, avg=None):
    """``(P_n, P_τ, S)`` of the table above; ``P_τ`` and ``S`` are None when frictionless."""
    if p.formulation == "nitsche":
        pn = fk.normal_traction(u) - p.beta_n * normal_jump(u, fk.n)
        pt = fk.tangential_traction(u) - p.beta_t * slip(u, fk.frame, fk.slip_reference)
    elif p.formulation in ("mean_nitsche", "stabilized_mixed"):
        a = _named(avg, average_names(p))
        pn = a["traction_n"] - p.beta_n * a["jump_n"]
        pt = (_average(a, "traction_t", p) - p.beta_t * _average(a, "jump_t", p)
              if p.tangential else None)
    elif p.formulation == "mixed":
        a = _named(avg, average_names(p))
        lm = _components(lam, multiplier_size(p))
        pn = -(lm[0] + p.beta_n * a["jump_n"])
        pt = -(_multiplier_t(lm, p) + p.beta_t * _average(a, "jump_t", p)) \
            if p.tangential else None
    else:
        raise ValueError(f"formulation '{p.formulation}' imposes no contact conditions")
    if not p.tangential:
        return pn, None, None
    return pn, pt, slip_threshold(p, pn)


def displacement_residual(fk: FractureKinematics, p: ContactParameters, u, v, dG, lam=None,
                          avg=None):
    """Fracture terms of the displacement equation (the bulk terms are added by the caller).

    Includes the fluid pressure ``∫ p_f [[v]]_n`` of eq. (5) when ``fk.fracture_pressure`` is set.
    Returns None when there is nothing to integrate on the fractures.
    """
    jn_v = normal_jump(v, fk.n)
    jt_v = slip(v, fk.frame)
    terms = []
    if fk.fracture_pressure is not None:
        terms.append(fk.fracture_pressure * jn_v)
    if p.formulation in ("nitsche", "mean_nitsche"):
        pn, pt, s = complementarity_arguments(fk, p, u, lam, avg)
        if p.formulation == "nitsche":
            tn, tt = fk.normal_traction(u), fk.tangential_traction(u) if p.tangential else None
        else:
            a = _named(avg, average_names(p))
            tn = a["traction_n"]
            tt = _average(a, "traction_t", p) if p.tangential else None
        th = p.theta
        tn_v = fk.normal_variation(v)
        terms.append(-th / p.beta_n * tn * tn_v)
        terms.append(negative_part(pn) * (th * tn_v - p.beta_n * jn_v) / p.beta_n)  # (7)/(8)
        if p.tangential and p.dim == 2:
            tt_v = fk.tangential_variation(v)
            terms.append(-th / p.beta_t * tt * tt_v)
            terms.append(ball_projection(pt, s) * (th * tt_v - p.beta_t * jt_v) / p.beta_t)
        elif p.tangential:
            tt_v = fk.tangential_variation(v)
            terms.append(-th / p.beta_t * ufl.inner(tt, tt_v))
            terms.append(ufl.inner(ball_projection(pt, s), th * tt_v - p.beta_t * jt_v)
                         / p.beta_t)
    elif p.formulation in ("mixed", "stabilized_mixed"):
        lm = _components(lam, multiplier_size(p))
        terms.append(lm[0] * jn_v)  # ∫ λ·[[v]], eq. (3)/(5)
        if p.tangential:
            terms.append(tangential_product(_multiplier_t(lm, p), jt_v))
        if p.formulation == "stabilized_mixed" and p.theta != 0:
            a = _named(avg, average_names(p))
            terms.append(-p.theta / p.beta_n * (lm[0] + a["traction_n"]) * fk.normal_variation(v))
            if p.tangential and p.dim == 2:
                terms.append(
                    -p.theta / p.beta_t * (lm[1] + a["traction_t"]) * fk.tangential_variation(v)
                )
            elif p.tangential:
                terms.append(-p.theta / p.beta_t * ufl.inner(
                    _multiplier_t(lm, p) + _average(a, "traction_t", p),
                    fk.tangential_variation(v)))
    if fk.initial_traction_mean is not None and p.active and not pointwise(p):
        # The facewise formulations carry the face mean π⁰T of the traction; the in-situ part
        # σ⁰n⁺ varies along a face (σ⁰ linear in depth), and its remainder σ⁰n⁺ - π⁰(σ⁰n⁺) is
        # applied pointwise: the multiplier (or π⁰T) is then a facewise change from σ⁰n⁺, and
        # u = 0 with T = σ⁰n⁺ is the exact discrete solution of a body at rest. Without the
        # term, ∫ σ⁰:ε(v) (= ∫ σ⁰n⁺·[[v]] on the fractures) is balanced by ∫ π⁰(σ⁰n⁺)·[[v]] only.
        terms.append(-ufl.dot(fk.initial_traction() - fk.initial_traction_mean, jump(v)))
    if not terms:
        return None
    return sum(terms[1:], terms[0]) * contact_measure(p, dG)


def multiplier_residual(fk: FractureKinematics, p: ContactParameters, u, lam, mu, avg, dG):
    """Facewise complementarity equations ``λ + [P]`` = 0, eqs. (4) and (6), tested with ``μ``."""
    pn, pt, s = complementarity_arguments(fk, p, u, lam, avg)
    k = multiplier_size(p)
    lm, mm = _components(lam, k), _components(mu, k)
    form = (lm[0] + negative_part(pn)) * mm[0]
    if p.tangential:
        form += tangential_product(_multiplier_t(lm, p) + ball_projection(pt, s),
                                   _multiplier_t(mm, p))
    return form * contact_measure(p, dG)


def multiplier_mass(p: ContactParameters, lam, mu, dG):
    """``∫ λ·μ`` on the fracture faces: the multiplier rows of the condensation matrix."""
    return ufl.inner(lam, mu) * contact_measure(p, dG)


def _averaged(fk: FractureKinematics, p: ContactParameters, u) -> dict:
    """The pointwise quantities whose face means are the average unknowns, by name."""
    exact = {"jump_n": normal_jump(u, fk.n), "traction_n": fk.normal_traction(u)}
    for name, value in (("jump_t", slip(u, fk.frame, fk.slip_reference)),
                        ("traction_t", fk.tangential_traction(u))):
        parts = _tangential_names(name, p)
        exact.update({parts[0]: value} if p.dim == 2 else
                     {k: value[i] for i, k in enumerate(parts)})
    return exact


def consistent_face_values(fk: FractureKinematics, p: ContactParameters, u):
    """Pointwise values whose face means are the face unknowns consistent with ``u``.

    ``(multiplier, averages)``: lists of UFL expressions in storage order (None for a
    formulation without them). The multiplier balances the face mean of the traction,
    ``λ = -π⁰T(u)`` (eq. (3): ``∫ λ·[[v]]`` stands for ``-∫ T(u)·[[v]]``), and the averages
    are ``π⁰T(u)`` and ``π⁰[[u]]``. Under an in-situ stress the Newton then starts from the
    face unknowns of the state ``u`` instead of zero, which are far from it (the traction of
    a fracture at depth).
    """
    k = multiplier_size(p)
    multiplier = None
    if k:
        tn = fk.normal_traction(u)
        multiplier = [-tn]
        if p.tangential:
            tt = fk.tangential_traction(u)
            multiplier += [-tt] if p.dim == 2 else [-tt[i] for i in range(p.dim - 1)]
    names = average_names(p)
    averages = None
    if names:
        exact = _averaged(fk, p, u)
        averages = [exact[name] for name in names]
    return multiplier, averages


def averages_residual(fk: FractureKinematics, p: ContactParameters, u, avg, q, dG):
    """Linear equations defining the face averages ``π⁰T(u)`` and ``π⁰[[u]]``, tested with ``q``."""
    names = average_names(p)
    a, r = _named(avg, names), _named(q, names)
    exact = _averaged(fk, p, u)
    weight = {k: p.average_scale for k in names if k.startswith("jump_")}
    form = sum(weight.get(k, 1.0) * (a[k] - exact[k]) * r[k] for k in names)
    return form * contact_measure(p, dG)


class ContactState(NamedTuple):
    """Pointwise contact state and tractions (UFL expressions).

    Attributes:
        contact: 1 where the point is closed (``P_n < 0``), else 0.
        slip: 1 where a closed point slides (``|P_τ| > S``; always when frictionless), else 0.
            With Tresca friction an open point may slide as well.
        traction_n: Contact traction ``T_n = [P_n]_R-`` (Pa).
        traction_t: Tangential traction ``T_τ = [P_τ]_S`` (Pa), 0 when frictionless.
        bound: Friction bound ``S`` (Pa): ``-F [P_n]_R-`` (Coulomb), ``s`` (Tresca), 0 without
            friction.
    """

    contact: ufl.core.expr.Expr
    slip: ufl.core.expr.Expr
    traction_n: ufl.core.expr.Expr
    traction_t: ufl.core.expr.Expr
    bound: ufl.core.expr.Expr


def state_indicators(fk: FractureKinematics, p: ContactParameters, u, lam=None,
                     avg=None) -> ContactState:
    """Pointwise contact state, tractions (Pa) and friction bound (Pa), eqs. (4), (7), (8).

    A closed point without friction slides (its tangential traction, 0, is on the bound).
    """
    pn, pt, s = complementarity_arguments(fk, p, u, lam, avg)
    closed = ufl.lt(pn, 0.0)
    contact = ufl.conditional(closed, 1.0, 0.0)
    tn = negative_part(pn)
    if not p.tangential:
        return ContactState(contact, contact, tn, 0.0 * tn, 0.0 * tn)
    sliding = ufl.gt(magnitude(pt), s)
    if p.friction == "coulomb":
        sliding = ufl.And(closed, sliding)
    return ContactState(contact, ufl.conditional(sliding, 1.0, 0.0), tn,
                        ball_projection(pt, s), s)


def active_set_code(fk: FractureKinematics, p: ContactParameters, u, lam=None, avg=None):
    """Branches of the nonsmooth functions at a point, as a UFL number ``c_n + 2 c_τ``.

    ``c_n = 1`` on the contact branch of ``[P_n]_R-``, ``c_τ`` the branch of ``[P_τ]_S`` (0
    stick, 1 slip forwards, 2 backwards; see :func:`~poromech.forms.fracture.ball_branch`). The
    comparisons are those of the residual, so the Jacobian changes exactly where a code does.
    With Coulomb friction on the open branch ``S = 0``: both slip branches have the same
    (zero) derivative and share ``c_τ = 0``, but the tie ``P_τ = 0`` (a fracture at rest, the
    usual initial iterate) takes the stick derivative and gets its own ``c_τ = 3``.
    """
    pn, pt, s = complementarity_arguments(fk, p, u, lam, avg)
    cn = ufl.conditional(contact_branch(pn), 1.0, 0.0)
    if not p.tangential:
        return cn
    ct = ball_branch(pt, s)
    if p.friction == "coulomb":
        ct = cn * ct + (1.0 - cn) * ufl.conditional(ufl.eq(ct, 0.0), 3.0, 0.0)
    return cn + 2.0 * ct
