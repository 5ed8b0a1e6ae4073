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

__all__ = ["FaceQuadrature", "exact_jump", "face_quadrature", "jump_errors", "jump_values",
           "friction_bound", "penny_jump", "penny_shear_jump", "remote_stress",
           "sneddon_jump"]


class FaceQuadrature:
    """Gauss points on the owned fracture faces (segments in 2D, triangles in 3D).

    Attributes:
        points: ``(N, d)`` coordinates.
        weights: ``(N,)`` weights (m in 2D, m² in 3D).
        plus, minus: ``(N,)`` cells of the ``+`` and ``-`` sides.
        normal: ``(N, d)`` ``n⁺`` at each point.
        face: ``(N,)`` position of the point's face in ``fm.fractures``.
    """

    def __init__(self, fm: FracturedMesh, npoints: int = 6):
        import basix
        import dolfinx

        faces = fm.fractures
        tdim = fm.msh.topology.dim
        xg = fm.msh.geometry.x[:, :tdim]
        fm.msh.topology.create_connectivity(tdim - 1, 0)
        corners = xg[dolfinx.mesh.entities_to_geometry(fm.msh, tdim - 1, faces.facets)]
        if tdim == 2:
            g, w = np.polynomial.legendre.leggauss(npoints)
            ref, w = (0.5 * (g + 1))[:, None], 0.5 * w
        else:  # Gauss-Jacobi points of degree 2 npoints - 1 on the reference triangle
            ref, w = basix.make_quadrature(basix.CellType.triangle, 2 * npoints - 1)
            w = 2.0 * w  # the reference triangle has area 1/2
        a = corners[:, 0]
        edges = corners[:, 1:] - a[:, None, :]  # (faces, d - 1, d)
        pts = a[:, None, :] + np.einsum("qk,fkd->fqd", ref, edges)
        self.points = pts.reshape(-1, tdim)
        npoints = len(w)
        self.weights = (w[None, :] * faces.measure[:, None]).ravel()
        self.plus = np.repeat(faces.plus[:, 0], npoints)
        self.minus = np.repeat(faces.minus[:, 0], npoints)
        self.normal = np.repeat(faces.normal, npoints, axis=0)
        self.face = np.repeat(np.arange(len(faces.facets)), npoints)


def face_quadrature(fm: FracturedMesh, npoints: int = 6) -> FaceQuadrature:
    """Gauss points of the owned fracture faces."""
    return FaceQuadrature(fm, npoints)


def jump_values(u: fem.Function, q: FaceQuadrature) -> npt.NDArray[np.float64]:
    """``[[u]] = u⁺ - u⁻`` at the quadrature points, ``(N, d)``."""
    d = q.points.shape[1]
    pts = np.column_stack([q.points, np.zeros((len(q.points), 3 - d))])
    if len(pts) == 0:
        return np.empty((0, d))
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
        exact: ``exact(points, normals) -> (N, d)`` exact jump vectors.
        npoints: Gauss points per face.

    Returns:
        ``l2``, ``max`` (relative, vector jump), ``l2_n``, ``l2_t`` (relative to the vector
        norm of the exact jump) and ``norm`` (the L² norm of the exact jump, m·m^½).
    """
    comm = fm.comm
    q = face_quadrature(fm, npoints)
    uh = jump_values(u, q)
    d = q.points.shape[1]
    ue = exact(q.points, q.normal) if len(q.points) else np.empty((0, d))
    e = uh - ue
    en = np.einsum("ij,ij->i", e, q.normal)
    et = np.linalg.norm(e - en[:, None] * q.normal, axis=1)  # tangential part, any d

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


def penny_jump(a: float, p: float, E: float, nu: float, center=(0.0, 0.0, 0.0)):
    """Exact jump of Sneddon's penny crack of radius ``a``: ``[[u]] = -w(r) n⁺``."""
    from poromech.analytic import penny_opening

    c = np.asarray(center, dtype=np.float64)

    def exact(points, normals):
        rel = points - c
        r = np.linalg.norm(rel - np.einsum("ij,ij->i", rel, normals)[:, None] * normals, axis=1)
        return -penny_opening(r, a, p, E, nu)[:, None] * normals

    return exact


def remote_stress(tau: float, phi: float, sigma: float) -> npt.NDArray[np.float64]:
    """Remote stress (Pa) of the sheared penny.

    Shear ``τ`` along ``(cos φ, sin φ, 0)`` on the plane ``z = 0`` and normal stress
    ``σ_zz = -σ`` (compression for ``σ > 0``).
    """
    s = np.zeros((3, 3))
    s[0, 2] = s[2, 0] = tau * np.cos(phi)
    s[1, 2] = s[2, 1] = tau * np.sin(phi)
    s[2, 2] = -sigma
    return s


def penny_shear_jump(a: float, tau: float, phi: float, sigma: float, E: float, nu: float,
                     bound: float = 0.0, center=(0.0, 0.0, 0.0)):
    """Exact jump of a penny crack in the plane ``z = 0`` under remote shear (Segedin 1968).

    The crack is closed (``σ > 0``) and slips against a uniform friction traction ``bound``
    (Pa; 0 frictionless, ``s`` Tresca, ``F σ`` Coulomb) along the remote shear traction
    ``t_τ = (σ⁰ n⁺)_τ`` on it: ``[[u]] = -g(r) t_τ/|t_τ|``, ``g`` of
    :func:`poromech.analytic.penny_shear_slip` with the shear ``τ - bound`` (the ``+`` side is
    the one ``n⁺`` points out of, which moves against ``t_τ``); 0 when ``τ <= bound``.
    """
    from poromech.analytic import penny_shear_slip

    c = np.asarray(center, dtype=np.float64)
    stress = remote_stress(tau, phi, sigma)

    def exact(points, normals):
        rel = points - c
        r = np.linalg.norm(rel - np.einsum("ij,ij->i", rel, normals)[:, None] * normals, axis=1)
        t = normals @ stress  # σ⁰ n⁺ (σ⁰ is symmetric)
        t -= np.einsum("ij,ij->i", t, normals)[:, None] * normals
        direction = t / np.linalg.norm(t, axis=1)[:, None]
        return -penny_shear_slip(r, a, max(tau - bound, 0.0), E, nu)[:, None] * direction

    return exact


def friction_bound(scene, sigma: float) -> float:
    """Uniform friction traction (Pa) of a crack under normal compression ``sigma`` (Pa)."""
    c = scene.contact
    if c.friction == "coulomb":
        return c.friction_coefficient * sigma
    if c.friction == "tresca":
        return c.slip_bound.value()
    return 0.0


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
    """The exact jump of a verification scene.

    ``sneddon*``, ``penny_shear*`` (the bound of its friction law), ``penny*``,
    ``inclined_crack*``.
    """
    prm = scene.parameters
    if scene.name.startswith("sneddon"):
        return sneddon_jump(prm["a"], prm["p"], prm["E"], prm["nu"])
    if scene.name.startswith("penny_shear"):
        return penny_shear_jump(prm["a"], prm["tau"], prm["phi"], prm["sigma"], prm["E"],
                                prm["nu"], friction_bound(scene, prm["sigma"]))
    if scene.name.startswith("penny"):
        return penny_jump(prm["a"], prm["p"], prm["E"], prm["nu"])
    if scene.name.startswith("inclined_crack"):
        return inclined_crack_jump(prm["b"], prm["psi"], prm["sigma"], prm["F"], prm["E"],
                                   prm["nu"])
    raise ValueError(f"no exact solution is known for scene '{scene.name}'")
