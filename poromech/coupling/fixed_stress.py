"""Fixed-stress terms of the Darcy solve inside ``g``: they change ``g``, not its fixed point.

Matrix (Kim, Tchelepi & Juanes 2011): ``β_K (p - p_in)`` added to the storage of cell ``K``,
``β_K = factor · b² / K_dr`` with the drained bulk modulus ``K_dr = λ + 2μ/d`` (``λ + μ`` in
plane strain). Fractures: ``β_f (p_f - p_f,in)`` added to the volume balance of each fracture
face, ``β_f = factor · π (1 - ν²) a / E``, the mean opening per unit pressure of a pressurized
crack of half-length ``a`` (plane strain; in 3D that of a penny-shaped crack of the fracture's
radius): it gives the fracture pressure a response to the
volume change where the matrix cannot drain the fractures (an impervious matrix seals them).
``p_in`` is the input pressure of ``g``.

:class:`FixedStress` holds both for a run, and switches the fracture term on when a step fails
with a Darcy solve that is not to be trusted (``coupling.fracture_stabilization: null``).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

__all__ = ["FixedStress", "fracture_fixed_stress", "matrix_fixed_stress"]

Array = npt.NDArray[np.float64]


def matrix_fixed_stress(factor: float, biot: float, young: Array, poisson: Array,
                        dim: int) -> Array:
    """``β = factor · b² / K_dr`` (1/Pa), ``K_dr = λ + 2μ/d`` the drained bulk modulus."""
    lam = young * poisson / ((1 + poisson) * (1 - 2 * poisson))
    mu = young / (2 * (1 + poisson))
    return factor * biot**2 / (lam + 2 * mu / dim)


def fracture_fixed_stress(factor: float, half_length: Array, young: Array,
                          poisson: Array, dim: int = 2) -> Array:
    """``β_f = factor · π (1 - ν²) a / E`` (m/Pa), ``a`` the half-length of the fracture.

    In 3D ``a`` is the radius of the fracture (of the disc of the same area for a polygon) and
    ``β_f = factor · 16 (1 - ν²) a / (3 π E)``, the mean opening per unit pressure of a
    pressurized penny-shaped crack (Sneddon).
    """
    if dim == 3:
        return factor * 16.0 * (1 - poisson**2) * half_length / (3.0 * np.pi * young)
    return factor * np.pi * (1 - poisson**2) * half_length / young


class FixedStress:
    """The fixed-stress terms of a coupled run, per owned cell and fracture face.

    Args:
        matrix: ``β_K`` per owned cell (1/Pa); zeros without the term.
        fracture: ``β_f(factor)``: the fracture term for a factor (None: no fractures or no time
            steps).
        factor: The scene's ``coupling.fracture_stabilization`` (None: off until needed).

    Attributes:
        beta: ``β_K`` per owned cell (1/Pa).
        beta_f: ``β_f`` per owned fracture face (m/Pa), or None (off).
        switched_on_at: When the automatic switch turned the fracture term on, or None.
    """

    def __init__(self, matrix: Array, fracture, factor: float | None):
        self.beta = matrix
        self._fracture = fracture
        self.automatic = factor is None
        self.switched_on_at: float | None = None
        self.beta_f = self._fracture_term(factor or 0.0)

    def _fracture_term(self, factor: float) -> Array | None:
        return None if factor == 0 or self._fracture is None else self._fracture(factor)

    @property
    def active(self) -> bool:
        """Whether either term changes the Darcy solve."""
        return bool(np.any(self.beta > 0)) or self.beta_f is not None

    def can_switch_on(self) -> bool:
        """Automatic mode, not yet switched, and a fracture term exists."""
        return self.automatic and self.switched_on_at is None and self._fracture is not None

    def switch_on(self, t: float) -> None:
        """The fracture term at factor 1 from time ``t`` on."""
        self.beta_f = self._fracture_term(1.0)
        self.switched_on_at = t
