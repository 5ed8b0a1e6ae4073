"""Kinematics and tractions on the fracture network: pure UFL.

All quantities live on the interior fracture facets of the connected mesh, measured with a
``dS`` whose ``'+'`` side is the side that ``n⁺`` points out of (see ``poromech.mesh.fractured``).
Tangential quantities are given in the fracture's tangent frame ``(τ_1, …, τ_{d-1})``: in 2D one
tangent, ``τ = (n⁺_y, -n⁺_x)`` (the direction in which the fracture polyline is written), and
tangential quantities are scalars; in 3D two tangents of each planar fracture, and tangential
quantities are 2-vectors of their components in that frame.
Sign conventions follow the paper: ``[[u]] = u⁺ - u⁻``, ``[[u]]_n = [[u]]·n⁺ <= 0`` (negative when
open), contact traction ``T_n <= 0`` (compression), aperture ``d_f = d_0 - [[u]]_n``.
"""

from __future__ import annotations

from dataclasses import dataclass

import ufl

from poromech.forms.elasticity import sigma

__all__ = [
    "FractureKinematics",
    "ball_branch",
    "ball_projection",
    "contact_branch",
    "jump",
    "magnitude",
    "negative_part",
    "normal_jump",
    "positive_part",
    "slip",
    "tangent",
    "tangential",
    "tangential_product",
]


def tangent(n):
    """Unit tangent ``τ = (n_y, -n_x)`` of a 2D fracture with normal ``n``."""
    return ufl.as_vector((n[1], -n[0]))


def tangential(vector, frame):
    """Components of a vector along the tangents of ``frame`` (a scalar in 2D, a 2-vector in 3D)."""
    if len(frame) == 1:
        return ufl.dot(vector, frame[0])
    return ufl.as_vector([ufl.dot(vector, t) for t in frame])


def jump(w):
    """``[[w]] = w⁺ - w⁻``."""
    return w("+") - w("-")


def normal_jump(w, n):
    """``[[w]]_n = [[w]]·n⁺`` (m); negative when the fracture opens."""
    return ufl.dot(jump(w), n)


def slip(w, frame, w_ref=None):
    """Tangential jump ``[[w]]_τ`` (m), minus that of ``w_ref`` (a slip increment) if given.

    ``frame`` is the tangent frame (:attr:`FractureKinematics.frame`).
    """
    s = tangential(jump(w), frame)
    return s - tangential(jump(w_ref), frame) if w_ref is not None else s


def face_max(w):
    """``max(w⁺, w⁻)`` of a cellwise quantity on an interior facet."""
    return ufl.max_value(w("+"), w("-"))


def magnitude(x):
    """``|x|`` of a tangential quantity (a scalar in 2D, a vector in 3D)."""
    return abs(x) if x.ufl_shape == () else ufl.sqrt(ufl.inner(x, x))


def tangential_product(x, y):
    """``x·y`` of two tangential quantities (a product of scalars in 2D)."""
    return x * y if x.ufl_shape == () else ufl.inner(x, y)


def negative_part(x):
    """``[x]_R- = min(0, x)``.

    At ``x = 0`` the generalized derivative is that of the contact branch, so a Newton
    iteration started from rest begins with the fractures closed.
    """
    return ufl.conditional(ufl.le(x, 0.0), x, 0.0)


def contact_branch(x):
    """UFL condition ``x <= 0``: the contact branch of ``[x]_R-``, ties included.

    It is the branch whose derivative :func:`negative_part` uses.
    """
    return ufl.le(x, 0.0)


def positive_part(x):
    """``[x]_R+ = max(0, x)``."""
    return ufl.max_value(x, 0.0)


def ball_projection(x, radius):
    """``[x]_α``: projection of a tangential quantity on the ball of radius ``α >= 0``.

    In 2D (a scalar) the clip to ``[-α, α]``; in 3D (a vector) ``x`` inside the disc and
    ``α x/|x|`` outside. On the boundary ``|x| = α`` the generalized derivative is that of the
    stick branch.
    """
    if x.ufl_shape == ():
        return ufl.conditional(ufl.le(x, radius),
                               ufl.conditional(ufl.ge(x, -radius), x, -radius), radius)
    norm = magnitude(x)
    return ufl.conditional(ufl.le(norm, radius), x, radius * x / norm)


def ball_branch(x, radius):
    """Branch of ``[x]_α`` as a UFL number: 0 inside (stick), 1 above ``α``, 2 below ``-α``.

    In 3D: 0 inside, 1 outside (the direction is continuous, not a branch). The comparisons are
    those of :func:`ball_projection`, so the branch is the one whose derivative the Jacobian
    uses.
    """
    if x.ufl_shape != ():
        return ufl.conditional(ufl.le(magnitude(x), radius), 0.0, 1.0)
    return ufl.conditional(ufl.le(x, radius), ufl.conditional(ufl.ge(x, -radius), 0.0, 2.0), 1.0)


@dataclass(frozen=True)
class FractureKinematics:
    """What the contact forms need to know about the fracture and the matrix next to it.

    Attributes:
        n: ``n⁺`` as a UFL expression on the fracture facets (``FacetNormal('+')``).
        young: Young's modulus (Pa), UFL coefficient or constant.
        poisson: Poisson's ratio, UFL coefficient or constant.
        side: ``"plus"`` evaluates the contact traction from the ``+`` side as in the paper,
            ``"mean"`` averages both sides.
        fracture_pressure: Fluid pressure ``p_f`` in the fractures (Pa), or None.
        matrix_pressure: Matrix pressure ``p_m`` (Pa) for the Biot term, or None.
        biot: Biot coefficient ``b`` (used with ``matrix_pressure``).
        slip_reference: Displacement whose tangential jump is subtracted in the friction law
            (the previous time step, for quasi-static friction), or None (static: total jump).
        tangents: The tangent frame of the fracture on its faces (3D: two orthonormal vectors
            per planar fracture); None in 2D, where it is ``τ = (n_y, -n_x)``.
        initial_stress: The in-situ (total) stress ``σ⁰`` (Pa), a tensor on the cells, or None:
            the traction is then ``(σ⁰ + σ(u) - b p_m I) n⁺ + p_f n⁺``.
        initial_traction_mean: The face means ``π⁰(σ⁰n⁺)`` (Pa, a vector in global
            coordinates, facewise constant) of :meth:`initial_traction`, or None (``σ⁰`` absent
            or constant on every face). The facewise formulations take the face means of the
            traction only, and load the fractures with ``σ⁰n⁺ - π⁰(σ⁰n⁺)`` pointwise (see
            :func:`poromech.forms.contact.displacement_residual`).
    """

    n: ufl.core.expr.Expr
    young: ufl.core.expr.Expr
    poisson: ufl.core.expr.Expr
    side: str = "plus"
    fracture_pressure: ufl.core.expr.Expr | None = None
    matrix_pressure: ufl.core.expr.Expr | None = None
    biot: ufl.core.expr.Expr | float = 1.0
    slip_reference: ufl.core.expr.Expr | None = None
    tangents: tuple[ufl.core.expr.Expr, ...] | None = None
    initial_stress: ufl.core.expr.Expr | None = None
    initial_traction_mean: ufl.core.expr.Expr | None = None

    @property
    def frame(self) -> tuple:
        """The tangents ``(τ_1, …, τ_{d-1})`` along which tangential quantities are taken."""
        return self.tangents if self.tangents is not None else (tangent(self.n),)

    def stress_variation(self, v):
        """``σ(v) n⁺`` on the chosen side (the linear part of the traction)."""
        stress = sigma(v, self.young, self.poisson)
        side = stress("+") if self.side == "plus" else 0.5 * (stress("+") + stress("-"))
        return ufl.dot(side, self.n)

    def _side(self, f):
        """``f`` on the side that defines the traction (``+``, or the mean of both)."""
        return f("+") if self.side == "plus" else 0.5 * (f("+") + f("-"))

    def initial_traction(self):
        """``σ⁰n⁺`` on the side that defines the traction (Pa), or None without ``σ⁰``."""
        if self.initial_stress is None:
            return None
        return ufl.dot(self._side(self.initial_stress), self.n)

    def traction(self, u):
        """Contact traction ``T(u) = (σ⁰ + σ(u) - b p_m I) n⁺ + p_f n⁺`` (Pa), eq. (1) and §3."""
        t = self.stress_variation(u)
        if self.initial_stress is not None:
            t = t + self.initial_traction()
        if self.matrix_pressure is not None:
            pm = self.matrix_pressure
            pm_side = pm("+") if self.side == "plus" else 0.5 * (pm("+") + pm("-"))
            t = t - self.biot * pm_side * self.n
        if self.fracture_pressure is not None:
            t = t + self.fracture_pressure * self.n
        return t

    def normal_traction(self, u):
        """``T_n(u) = T(u)·n⁺`` (Pa)."""
        return ufl.dot(self.traction(u), self.n)

    def tangential_traction(self, u):
        """``T_τ(u) = T(u)·τ`` (Pa), in the tangent frame."""
        return tangential(self.traction(u), self.frame)

    def normal_variation(self, v):
        """``T_n(v)`` for a test/trial direction ``v`` (no pressure terms)."""
        return ufl.dot(self.stress_variation(v), self.n)

    def tangential_variation(self, v):
        """``T_τ(v)`` for a test/trial direction ``v`` (no pressure terms)."""
        return tangential(self.stress_variation(v), self.frame)
