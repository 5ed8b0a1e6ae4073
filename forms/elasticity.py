"""Linear (poro)elasticity in the matrix: pure UFL, eq. (1) of Beaude et al. (2023).

Units: displacements in m, moduli and stresses in Pa, body forces in N/m³.
"""

from __future__ import annotations

import ufl

__all__ = ["biot_stress_form", "epsilon", "initial_stress_form", "lame_parameters", "sigma",
           "elastic_form"]


def lame_parameters(young, poisson):
    """Lamé parameters ``(μ, λ)`` (Pa) from Young's modulus (Pa) and Poisson's ratio."""
    mu = young / (2 * (1 + poisson))
    lmbda = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    return mu, lmbda


def epsilon(u):
    """Symmetric gradient ``ε(u) = (∇u + ∇uᵀ)/2``."""
    return ufl.sym(ufl.grad(u))


def sigma(u, young, poisson):
    """Cauchy stress ``σ(u) = E/(1+ν) (ε(u) + ν/(1-2ν) div(u) I)`` (Pa), eq. (1)."""
    mu, lmbda = lame_parameters(young, poisson)
    return 2 * mu * epsilon(u) + lmbda * ufl.tr(epsilon(u)) * ufl.Identity(len(u))


def elastic_form(u, v, young, poisson, dx):
    """Bulk stiffness ``∫_Ω σ(u):ε(v) dx``."""
    return ufl.inner(sigma(u, young, poisson), epsilon(v)) * dx


def initial_stress_form(sigma0, v, dx):
    """Initial (in-situ) stress term ``∫_Ω σ⁰:ε(v) dx`` of the total stress ``σ⁰ + σ(u)``."""
    return ufl.inner(sigma0, epsilon(v)) * dx


def biot_stress_form(p, v, biot, dx):
    """Biot pressure term ``-∫_Ω b p div(v) dx`` of the total stress ``σ - b p I``."""
    return -biot * p * ufl.div(v) * dx
