"""Patch tests (exact to round-off), blocking fractures, solver paths and value updates."""

import numpy as np
import pytest
from conftest import flow_properties, network_geometry
from mpi4py import MPI

from poromech.flow.balance import boundary_fluxes, compute_fluxes, mass_balance
from poromech.flow.boundary import FlowBoundary
from poromech.flow.hfv import isotropic_tensor, permeability_tensors
from poromech.flow.problem import DarcyProblem
from poromech.flow.shift import TraceShift
from poromech.verification.flow import rectangle, uniform_mesh

comm = MPI.COMM_WORLD
LAMBDA = np.array([[2.0, 0.5], [0.5, 1.0]])
GRAD = np.array([2.0, -3.0])


def properties(fm, perm=LAMBDA, **fracture):
    return flow_properties(fm, perm, **fracture)


def max_error(pb, exact, traces=True):
    """Largest error over the local dofs (traces optionally left out: they are side values)."""
    pts = pb.dofs.points
    err = np.abs(pb.p - exact(pts))
    if not traces:
        err = err[pb.dofs.kind != 2]
    return comm.allreduce(float(err.max(initial=0.0)), op=MPI.MAX)


def test_affine_patch_without_fractures():
    """Anisotropic full tensor, Dirichlet left/right, exact fluxes top/bottom."""
    fm = uniform_mesh(comm, rectangle(0, 0, 1, 1), 0.1)

    def exact(points, t=0.0):
        x, y = points[:, 0], points[:, 1]
        return 1.0 + GRAD[0] * x + GRAD[1] * y

    qy = float((LAMBDA @ GRAD)[1])  # -Λ∇p·n on the bottom (n = -e_y)
    bcs = [FlowBoundary("lr", (1, 3), "pressure", exact),
           FlowBoundary("bottom", (0,), "flux", lambda x, t: np.full(len(x), qy)),
           FlowBoundary("top", (2,), "flux", lambda x, t: np.full(len(x), -qy))]
    pb = DarcyProblem(fm, properties(fm), bcs, solver="direct")
    pb.solve()
    assert max_error(pb, exact) <= 1e-12 * 4
    fl = boundary_fluxes(pb, compute_fluxes(pb))
    qx = -(LAMBDA @ GRAD)[0]
    assert fl["right"]["total"] == pytest.approx(qx, rel=1e-12)
    assert fl["left"]["total"] == pytest.approx(-qx, rel=1e-12)
    pb.destroy()


def two_parallel_fractures():
    """Two parallel fractures crossing the unit square; affine pressure with jumps."""
    x0s = [np.array([0.0, 0.3]), np.array([0.0, 0.55])]
    d = np.array([1.0, 0.4])
    geo = rectangle(0, 0, 1, 1, [[x0, x0 + d] for x0 in x0s])
    tau = d / np.linalg.norm(d)
    n = np.array([-tau[1], tau[0]])
    q = -(LAMBDA @ GRAD) @ n  # outward flux of the + (lower) side through each fracture
    aperture, kn = np.array([1e-2, 3e-2]), np.array([1e-3, 5e-4])
    jump = 2 * q / (2 * kn / aperture)  # p+ - p- = 2 q / T_f
    C = np.array([jump[0] + jump[1], jump[1], 0.0])

    def exact(points, t=0.0):
        x, y = points[:, 0], points[:, 1]
        s = [(np.column_stack([x, y]) - x0) @ n for x0 in x0s]
        c = np.where(s[0] < 0, C[0], np.where(s[1] < 0, C[1], C[2]))
        c = np.where(np.abs(s[0]) < 1e-12, 0.5 * (C[0] + C[1]), c)  # on the fractures: p_f
        c = np.where(np.abs(s[1]) < 1e-12, 0.5 * (C[1] + C[2]), c)
        return c + GRAD[0] * x + GRAD[1] * y

    def traces(fm, midpoint):
        fid = fm.fractures.fracture
        return np.column_stack([C[fid], C[fid + 1]]) + (midpoint @ GRAD)[:, None]

    return geo, exact, aperture, kn, traces


@pytest.mark.parametrize("ratio", [0.0, np.inf])
def test_affine_patch_with_fracture_jumps(ratio, monkeypatch):
    """Piecewise affine pressure with jumps: exact for cells, faces, traces, p_f and nodes.

    Both variable choices at the fracture faces (traces, or δ = trace - p_f) are exact.
    """
    monkeypatch.setattr(TraceShift.__init__, "__defaults__", (ratio,))
    geo, exact, aperture, kn, traces = two_parallel_fractures()
    fm = uniform_mesh(comm, geo, 0.1)
    props = properties(fm, aperture=aperture, kn=kn, cond=np.array([0.3, 2.0]))
    pb = DarcyProblem(fm, props, [FlowBoundary("all", (0, 1, 2, 3), "pressure", exact)],
                      solver="direct")
    pb.solve()
    if comm.size == 1:
        assert pb.shift.num_shifted == (0 if ratio == np.inf else fm.num_fracture_faces)
    assert max_error(pb, exact, traces=False) <= 1e-12 * 200  # pressures up to 200
    tr = pb.trace_pressure
    assert np.abs(tr - traces(fm, pb.faces.midpoint)).max(initial=0) <= 1e-12 * 200
    assert np.abs(tr[:, 0] - tr[:, 1]).min(initial=np.inf) > 1.0  # the jumps are there
    pb.destroy()


def test_blocking_fracture_exact_1d():
    """A nearly impervious fracture across the flow: series resistance, exact to round-off.

    The blocked flux is 5e-8 of the flux scale K Δp / L = 1. LU resolves it to the round-off
    of pressures near 1 (1e-16 / 5e-8 ≈ 1e-7 relative); CG + GAMG bounds its error by about
    rtol times the flux scale (1e-12), not by the blocked flux itself.
    """
    fm = uniform_mesh(comm, rectangle(0, 0, 1, 0.5, [[[0.5, 0.0], [0.5, 0.5]]]), 0.08)
    d, kn = 1e-3, 1e-10
    T_f = 2 * kn / d
    q = 1.0 / (1.0 + 2.0 / T_f)  # K = 1, L = 1: p drops 1 over resistances 1 and 2/T_f
    bcs = [FlowBoundary("left", (3,), "pressure", lambda x, t: np.ones(len(x))),
           FlowBoundary("right", (1,), "pressure", lambda x, t: np.zeros(len(x)))]

    def exact(points, t=0.0):
        x = points[:, 0]
        p = np.where(x < 0.5, 1 - q * x, q * (1 - x))
        return np.where(np.isclose(x, 0.5, rtol=0, atol=1e-12), 0.5, p)

    for solver, tol in (("direct", 1e-13), ("iterative", 1e-11)):
        pb = DarcyProblem(fm, properties(fm, perm=np.eye(2), aperture=d, kn=kn), bcs,
                          solver=solver)
        rec = pb.solve()
        fl = boundary_fluxes(pb, compute_fluxes(pb))
        assert fl["right"]["total"] == pytest.approx(0.5 * q, abs=tol)
        assert fl["left"]["total"] == pytest.approx(-0.5 * q, abs=tol)
        assert max_error(pb, exact, traces=False) <= 1e-10
        assert np.abs(pb.trace_pressure - [q * 0.5, 1 - q * 0.5]).max(initial=0) <= 1e-10
        assert rec.iterations < 100
        pb.destroy()


def network(size=0.1):
    raw = network_geometry()
    x0, y0, x1, y1 = raw["domain"]["rectangle"]
    return rectangle(x0, y0, x1, y1, [f["points"] for f in raw["fractures"]])


@pytest.mark.parametrize("kn", [1e-12, 1e2])
def test_network_blocking_and_conductive(kn):
    """Tips, corner, T, X and a boundary end: iterative = direct, mass conserved."""
    fm = uniform_mesh(comm, network(), 0.08)
    p_left = FlowBoundary("left", (3,), "pressure", lambda x, t: np.ones(len(x)))
    p_right = FlowBoundary("right", (1,), "pressure", lambda x, t: np.zeros(len(x)))
    sols = {}
    for solver in ("direct", "iterative"):
        pb = DarcyProblem(fm, properties(fm, perm=np.eye(2), aperture=1e-3, kn=kn, kt=1e-2),
                          [p_left, p_right], solver=solver, options={"ksp_rtol": 1e-12})
        rec = pb.solve()
        bal = mass_balance(pb, compute_fluxes(pb))
        assert bal["relative_residual"] < 1e-9 and bal["max_local_residual"] < 1e-9
        sols[solver] = pb.p.copy()
        if solver == "iterative":
            assert rec.iterations < 60
        jump = np.abs(np.diff(pb.trace_pressure, axis=1)).max(initial=0)
        blocking = kn < 1
        assert (comm.allreduce(jump, op=MPI.MAX) > 1e-2) == blocking
        pb.destroy()
    assert np.abs(sols["direct"] - sols["iterative"]).max() < 1e-8


def test_values_only_update():
    """New apertures: same matrix pattern, same answer as a problem built from scratch."""
    geo, *_ = two_parallel_fractures()
    fm = uniform_mesh(comm, geo, 0.1)
    p_lr = FlowBoundary("lr", (1, 3), "pressure", lambda x, t: x[:, 0])
    pb = DarcyProblem(fm, properties(fm, perm=np.eye(2)), [p_lr])
    pb.solve()
    nz = pb.A.getInfo()["nz_allocated"]
    first = pb.p.copy()
    d_new = np.full(len(fm.fractures.facets), 5e-2)
    pb.set_aperture(d_new)
    pb.solve()
    assert pb.A.getInfo()["nz_allocated"] == nz
    fresh = DarcyProblem(fm, properties(fm, perm=np.eye(2), aperture=5e-2), [p_lr])
    fresh.solve()
    assert np.abs(pb.p - fresh.p).max() < 1e-8
    assert np.abs(pb.p - first).max() > 1e-3
    perm = permeability_tensors([np.full(len(pb.geom.volume), 3.0)])
    pb.set_permeability(perm)
    pb.solve()
    assert pb.A.getInfo()["nz_allocated"] == nz
    assert isotropic_tensor(np.ones(1)).shape == (1, 2, 2)
    for p in (pb, fresh):
        p.destroy()


@pytest.mark.parametrize("ends", ["inherit", "no_flow"])
def test_fracture_end_on_pressure_boundary(ends):
    """The 'edge' fracture reaches x = 2: its end node gets p = g (inherit) or no flow."""
    fm = uniform_mesh(comm, network(), 0.1)

    def g(points, t=0.0):
        return 1.0 + 0.5 * points[:, 1]

    bcs = [FlowBoundary("left", (3,), "pressure", lambda x, t: np.zeros(len(x))),
           FlowBoundary("right", (1,), "pressure", g, ends)]
    pb = DarcyProblem(fm, properties(fm, perm=np.eye(2), aperture=1e-2, kt=1.0), bcs,
                      solver="direct")
    pb.solve()
    ends_xy = pb.dofs.points[pb.dofs.node]
    at_boundary = np.isclose(ends_xy[..., 0], 2.0)
    p_end = pb.node_pressure[at_boundary]
    fl = boundary_fluxes(pb, compute_fluxes(pb))
    found = comm.allreduce(int(at_boundary.sum()))
    assert found >= 1
    if ends == "inherit":
        assert np.allclose(p_end, g(np.array([[2.0, 0.8]]))[0], rtol=0, atol=1e-12)
        assert abs(fl["right"]["fracture"]) > 1e-5 * abs(fl["right"]["matrix"]) > 0
    else:
        assert np.all(np.abs(p_end - g(np.array([[2.0, 0.8]]))[0]) > 1e-6)
        assert abs(fl["right"]["fracture"]) < 1e-12 * abs(fl["right"]["matrix"])
    pb.destroy()


def test_owned_cell_values_follow_flow_order():
    """A DG0 field read with owned_cell_values matches the flow cell order (centroids)."""
    from dolfinx import fem

    from poromech.mesh.entities import cell_geometry, owned_cell_values

    fm = uniform_mesh(comm, rectangle(0, 0, 1, 1), 0.2)
    f = fem.Function(fem.functionspace(fm.msh, ("DG", 0)))
    f.interpolate(lambda x: x[0] + 10 * x[1])
    g = cell_geometry(fm.msh)
    assert np.allclose(owned_cell_values(f), g.centroid[:, 0] + 10 * g.centroid[:, 1])
