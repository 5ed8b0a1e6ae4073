"""Errors of coupled runs against the consolidation solutions, read from their output series.

Post-processing of an output directory (``flow``, ``displacement`` and ``fractures`` XDMF
series, :func:`poromech.io.xdmf.read_series`) in 2D and 3D: the cells are triangles or
tetrahedra, the fracture faces segments or triangles, and the vertical is the last coordinate
(``y`` in 2D, ``z`` in 3D). Serial NumPy on the files (which do not depend on the number of
ranks that wrote them).

* :func:`terzaghi_errors`: Terzaghi's column (``configs/terzaghi.yaml``,
  ``configs/terzaghi3d.yaml``);
* :func:`mandel_errors`: Mandel's slab (``configs/mandel3d.yaml``);
* :func:`fluid_volume`: the fluid stored in pores and apertures, for mass balance checks.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import numpy.typing as npt

from poromech.analytic import (
    mandel_displacement_x,
    mandel_parameters,
    mandel_pressure,
    terzaghi_parameters,
    terzaghi_pressure,
    terzaghi_settlement,
)
from poromech.io.xdmf import read_series
from poromech.scene.schema import Scene

__all__ = ["fluid_volume", "mandel_errors", "simplex_measures", "terzaghi_errors"]


def simplex_measures(points: npt.NDArray[np.float64],
                     cells: npt.NDArray[np.int64]) -> npt.NDArray[np.float64]:
    """Length, area or volume of each simplex ``cells`` (2, 3 or 4 vertices) of ``points``.

    Triangles of a 2D mesh by ``|e₁ × e₂|/2`` in the plane (the formula of the 2D tests, so
    that their numbers do not change), triangles in 3D by the norm of the cross product,
    tetrahedra by ``|det(e₁, e₂, e₃)|/6``.
    """
    x = points[cells]
    e = x[:, 1:] - x[:, :1]
    if cells.shape[1] == 2:
        return np.linalg.norm(e[:, 0], axis=1)
    if cells.shape[1] == 3:
        e1, e2 = e[:, 0], e[:, 1]
        if points.shape[1] == 2 or not np.any(x[..., 2:]):
            return 0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0])
        return 0.5 * np.linalg.norm(np.cross(e1, e2), axis=1)
    return np.abs(np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1], e[:, 2]))) / 6


def _vertical(cells: npt.NDArray[np.int64]) -> int:
    """Column of the vertical coordinate for a mesh of ``cells``: triangles y, tetrahedra z."""
    return cells.shape[1] - 2


def _relative_l2(measure, numerical, exact) -> float:
    return float(np.sqrt(np.sum(measure * (numerical - exact) ** 2)
                         / np.sum(measure * exact**2)))


def terzaghi_errors(scene: Scene, out: Path, steps: int | None = None):
    """Terzaghi's column: errors of the pressure and the settlement at the last output time.

    The relative L² error of ``p_m`` over the cells and the error of the settlement of the top
    relative to the total settlement, against the exact series or, with ``steps``, the exact
    solution of the problem after that many implicit Euler steps. The scene's ``parameters``
    hold ``L, sigma0, E, nu, b, M``, its ``flow`` the (isotropic, uniform) permeability and the
    viscosity; the drained top is at height ``L``.

    Returns:
        ``(pressure error, settlement error, p_m at the last time)``.
    """
    p = scene.parameters
    k = scene.flow.permeability[0].value()
    c = terzaghi_parameters(p["E"], p["nu"], p["b"], p["M"], k, scene.flow.viscosity,
                            p["sigma0"])
    flow = read_series(out, "flow")
    vertical = _vertical(flow.cells)
    x = flow.points[flow.cells].mean(axis=1)
    measure = simplex_measures(flow.points, flow.cells)
    t = flow.times[-1]
    ph = flow.fields(-1)["p_m"]
    pe = terzaghi_pressure(p["L"] - x[:, vertical], t, p["L"], c["p_u"], c["c_v"], steps=steps)
    err_p = _relative_l2(measure, ph, pe)
    u = read_series(out, "displacement")
    top = np.isclose(u.points[:, vertical], p["L"])
    settlement = u.fields(-1)["u"][top, vertical].mean()
    args = (p["L"], c["p_u"], c["c_v"], c["K_v"], p["b"], p["sigma0"])
    settled = terzaghi_settlement(t, *args) - terzaghi_settlement(1e-12, *args)
    err_u = abs(settlement - terzaghi_settlement(t, *args, steps=steps)) / abs(settled)
    return err_p, err_u, ph


def mandel_errors(scene: Scene, out: Path, index: int, centre: float = 0.1) -> dict:
    """Mandel's slab at output step ``index`` against the exact solution.

    The scene's ``parameters`` hold ``a, F, E, nu, b, M, k`` (half-width, force per unit length
    on the half-slab, moduli, Biot coefficient and modulus, mobility k/η); the slab is
    ``0 < x < a`` with its centre at ``x = 0``.

    Returns:
        ``time``; ``pressure``: relative L² error of ``p_m`` over the cells; ``centre`` and
        ``centre_exact``: the mean pressure of the cells within ``centre`` of ``x = 0``, computed
        and exact (cell centroids), in units of the undrained ``p₀``; ``ux``: relative error of
        the mean horizontal displacement of the drained side ``x = a``.
    """
    p = scene.parameters
    c = mandel_parameters(p["E"], p["nu"], p["b"], p["M"], p["k"], p["a"], p["F"])
    flow = read_series(out, "flow")
    t = flow.times[index]
    x = flow.points[flow.cells].mean(axis=1)[:, 0]
    measure = simplex_measures(flow.points, flow.cells)
    ph, pe = flow.fields(index)["p_m"], mandel_pressure(x, t, c)
    near = x < centre
    u = read_series(out, "displacement")
    side = np.isclose(u.points[:, 0], p["a"])
    ux, ux_exact = u.fields(index)["u"][side, 0].mean(), mandel_displacement_x(p["a"], t, c)
    return {
        "time": t,
        "pressure": _relative_l2(measure, ph, pe),
        "centre": float(measure[near] @ ph[near] / measure[near].sum() / c["p0"]),
        "centre_exact": float(measure[near] @ pe[near] / measure[near].sum() / c["p0"]),
        "ux": float(abs(ux - ux_exact) / abs(ux_exact)),
    }


def fluid_volume(out: Path, index: int) -> float:
    """Fluid stored at output step ``index``, ``Σ |K| φ_K + Σ |σ| d_σ``.

    In m³ (3D) or m² per unit depth (2D).
    """
    flow = read_series(out, "flow")
    frac = read_series(out, "fractures")
    stored = simplex_measures(flow.points, flow.cells) @ flow.fields(index)["porosity"]
    return stored + simplex_measures(frac.points, frac.cells) @ frac.fields(index)["aperture"]
