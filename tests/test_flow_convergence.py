"""Verification: manufactured solution with pressure jumps (order 2) and transient order 1."""

import numpy as np
from mpi4py import MPI

from poromech.verification.flow import Diffusion1D, JumpSolution, observed_orders, uniform_mesh

comm = MPI.COMM_WORLD


def test_manufactured_jumps_second_order():
    """DESIGN §5 solution: L² errors of cells, traces, p_f and nodes decrease as h²."""
    sol = JumpSolution()
    geo = sol.geometry()
    h, errors, iterations = [], [], []
    for m in range(4):
        fm = uniform_mesh(comm, geo, 0.2, refinement=m)
        pb = sol.problem(fm, options={"ksp_rtol": 1e-12})
        rec = pb.solve()
        iterations.append(rec.iterations)
        errors.append(sol.errors(pb))
        h.append(0.2 / 2**m)
        pb.destroy()
    for key in ("cell", "trace", "fracture", "node"):
        e = np.array([err[key] for err in errors])
        orders = observed_orders(np.array(h), e)
        assert np.all(orders > 1.9), (key, e, orders)
    assert errors[-1]["cell"] < 6e-4
    assert max(iterations) < 40  # CG + GAMG: mesh-independent iteration counts


def test_transient_first_order_in_time():
    """Implicit Euler on a decaying sine mode with storage: error ∝ Δt."""
    sol = Diffusion1D()
    fm = uniform_mesh(comm, sol.geometry(), 0.02)
    steps = np.array([4, 8, 16, 32])
    errors = []
    for n in steps:
        pb = sol.problem(fm, solver="direct")
        errors.append(sol.run(pb, 0.1, int(n)))
        pb.destroy()
    orders = observed_orders(1.0 / steps, np.array(errors))
    assert np.all((orders > 0.9) & (orders < 1.1)), (errors, orders)
    assert errors[-1] < 0.02
