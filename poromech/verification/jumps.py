"""Error measures on the fracture network against exact jumps (for benchmarks and tests).

Errors are integrated with Gauss–Legendre points on every owned fracture face; the finite
element jump is evaluated in the ``+`` and ``-`` cells of each face, the exact one by a function
of the points. All functions are collective and return rank-reduced numbers.
"""

from __future__ import annotations

from collections.abc import Callable

import dolfinx_solver  # noqa: F401

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI

from poromech.mesh.fractured import FracturedMesh

__all__ = ["FaceQuadrature", "face_quadrature", "jump_errors", "jump_values"]


class FaceQuadrature:
    """Gauss points on the owned fracture faces.

    Attributes:
        points: ``(N, 2)`` coordinates.
        weights: ``(N,)`` weights (m).
        plus, minus: ``(N,)`` cells of the ``+`` and ``-`` sides.
        normal: ``(N, 2)`` ``n⁺`` at each point.
        face: ``(N,)`` position of the point's face in ``fm.fractures``.
    """

    def __init__(self, fm: FracturedMesh, npoints: int = 6):
        faces = fm.fractures
        xg = fm.msh.geometry.x[:, :2]
        import dolfinx

        ends = xg[dolfinx.mesh.entities_to_geometry(fm.msh, 1, faces.facets)]
        g, w = np.polynomial.legendre.leggauss(npoints)
        s = 0.5 * (g + 1)
        a, b = ends[:, 0], ends[:, 1]
        self.points = (a[:, None, :] + s[None, :, None] * (b - a)[:, None, :]).reshape(-1, 2)
        self.weights = (0.5 * w[None, :] * faces.measure[:, None]).ravel()
        self.plus = np.repeat(faces.plus[:, 0], npoints)
        self.minus = np.repeat(faces.minus[:, 0], npoints)
        self.normal = np.repeat(faces.normal, npoints, axis=0)
        self.face = np.repeat(np.arange(len(faces.facets)), npoints)


def face_quadrature(fm: FracturedMesh, npoints: int = 6) -> FaceQuadrature:
    """Gauss points of the owned fracture faces."""
    return FaceQuadrature(fm, npoints)


def jump_values(u: fem.Function, q: FaceQuadrature) -> npt.NDArray[np.float64]:
    """``[[u]] = u⁺ - u⁻`` at the quadrature points, ``(N, 2)``."""
    pts = np.column_stack([q.points, np.zeros(len(q.points))])
    if len(pts) == 0:
        return np.empty((0, 2))
    return u.eval(pts, q.plus.astype(np.int32)) - u.eval(pts, q.minus.astype(np.int32))


def jump_errors(
    u: fem.Function,
    fm: FracturedMesh,
    exact: Callable[[npt.NDArray[np.float64], npt.NDArray[np.float64]], npt.NDArray[np.float64]],
    npoints: int = 6,
) -> dict[str, float]:
    """Relative L² and max errors of the jump, normal and tangential components (collective).

    Args:
        u: Displacement.
        fm: Fractured mesh.
        exact: ``exact(points, normals) -> (N, 2)`` exact jump vectors.
        npoints: Gauss points per face.

    Returns:
        ``l2``, ``max`` (relative, vector jump), ``l2_n``, ``l2_t`` (relative to the vector
        norm of the exact jump) and ``norm`` (the L² norm of the exact jump, m·m^½).
    """
    comm = fm.comm
    q = face_quadrature(fm, npoints)
    uh = jump_values(u, q)
    ue = exact(q.points, q.normal) if len(q.points) else np.empty((0, 2))
    e = uh - ue
    t = np.column_stack([q.normal[:, 1], -q.normal[:, 0]])
    en = np.einsum("ij,ij->i", e, q.normal)
    et = np.einsum("ij,ij->i", e, t)

    def integral(v):
        return comm.allreduce(float(np.sum(q.weights * v)), op=MPI.SUM)

    def maximum(v):
        return comm.allreduce(float(np.max(v)) if len(v) else 0.0, op=MPI.MAX)

    norm2 = integral(np.sum(ue**2, axis=1))
    scale = np.sqrt(norm2) if norm2 > 0 else 1.0  # absolute errors when the exact jump is 0
    emax = maximum(np.linalg.norm(e, axis=1))
    umax = maximum(np.linalg.norm(ue, axis=1))
    return {
        "l2": float(np.sqrt(integral(np.sum(e**2, axis=1))) / scale),
        "l2_n": float(np.sqrt(integral(en**2)) / scale),
        "l2_t": float(np.sqrt(integral(et**2)) / scale),
        "max": float(emax / umax) if umax > 0 else float(emax),
        "norm": float(np.sqrt(norm2)),
    }


def sneddon_jump(a: float, p: float, E: float, nu: float):
    """Exact jump of Sneddon's crack along the x axis: ``[[u]] = -w(x) n⁺``."""
    from poromech.analytic import sneddon_opening

    def exact(points, normals):
        return -sneddon_opening(points[:, 0], a, p, E, nu)[:, None] * normals

    return exact


def inclined_crack_jump(b: float, psi: float, sigma: float, F: float, E: float, nu: float):
    """Exact jump of the inclined frictional crack, from the slip field on both faces.

    The ``+`` face is the one ``n⁺`` points out of.
    """
    from poromech.analytic import inclined_crack_slip_field

    def exact(points, normals):
        eps = 1e-9 * b
        up = inclined_crack_slip_field(*(points - eps * normals).T, b, psi, sigma, F, E, nu)
        um = inclined_crack_slip_field(*(points + eps * normals).T, b, psi, sigma, F, E, nu)
        return np.column_stack(up) - np.column_stack(um)

    return exact


def exact_jump(scene) -> Callable:
    """The exact jump of a shipped verification scene (``sneddon*`` or ``inclined_crack*``)."""
    prm = scene.parameters
    if scene.name.startswith("sneddon"):
        return sneddon_jump(prm["a"], prm["p"], prm["E"], prm["nu"])
    if scene.name.startswith("inclined_crack"):
        return inclined_crack_jump(prm["b"], prm["psi"], prm["sigma"], prm["F"], prm["E"],
                                   prm["nu"])
    raise ValueError(f"no exact solution is known for scene '{scene.name}'")
