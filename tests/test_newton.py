"""The semi-smooth Newton solver: Jacobian consistency, line search, factorization reuse."""

import numpy as np
import pytest
from conftest import ROOT
from mpi4py import MPI

from poromech.config import load_scene
from poromech.errors import SolverError
from poromech.run import MechanicsSimulation, build_mesh
from poromech.timing import Timer

comm = MPI.COMM_WORLD


def simulation(name: str, *overrides: str):
    scene = load_scene(ROOT / "configs" / f"{name}.yaml", list(overrides))
    return MechanicsSimulation(scene, build_mesh(scene, comm), Timer())


@pytest.mark.parametrize("formulation", ["nitsche", "mean_nitsche", "stabilized_mixed", "mixed"])
def test_jacobian_matches_finite_differences(formulation):
    """J·d equals the central difference of the residual, block by block, at a slipping state
    (perturbations scaled entry by entry so that no contact state switches)."""
    sim = simulation("inclined_crack_slip", "degree=1", f"contact.formulation={formulation}")
    sim.run()
    s = sim.solver
    x = s.x.copy()
    offsets = s._blocks[0]
    s.snes.computeJacobian(x, s.A, s.A)
    rng = np.random.default_rng(3)
    fp, fm = s.b.duplicate(), s.b.duplicate()
    h = 1e-7
    for k in range(len(offsets) - 1):
        d = x.duplicate()
        d.set(0.0)
        arr = d.getArray()
        seg = slice(offsets[k], offsets[k + 1])
        xs = np.abs(x.getArray()[seg])
        arr[seg] = rng.standard_normal(len(xs)) * (xs + 1e-12 * xs.max())
        d.setArray(arr)
        xp, xm = x.copy(), x.copy()
        xp.axpy(h, d)
        xm.axpy(-h, d)
        s._cache_valid = False
        s.snes.computeFunction(xp, fp)
        s._cache_valid = False
        s.snes.computeFunction(xm, fm)
        fd = (fp - fm).getArray() / (2 * h)
        jd = s.A.createVecLeft()
        s.A.mult(d, jd)
        assert np.linalg.norm(fd - jd.getArray()) <= 1e-5 * np.linalg.norm(fd)
    sim.close()


def test_contact_line_search_converges_where_full_steps_cycle():
    """On the six-fracture scene, plain Newton (PETSc 'basic') ping-pongs between active sets;
    poromech's line search converges in a few iterations."""
    sim = simulation("six_fractures_mechanics", "time.steps=1", "solver.line_search=basic",
                     "solver.petsc.snes_max_it=40")
    with pytest.raises(SolverError):
        sim.run()
    sim.close()
    sim = simulation("six_fractures_mechanics", "time.steps=1")
    records = sim.run()
    assert records[0]["converged"] and records[0]["iterations"] <= 12
    sim.close()


def test_factorization_reused_across_steps_of_a_linear_problem():
    """An open pressurized crack is linear: one factorization serves every time step."""
    sim = simulation("sneddon", "fracture_pressure=1e7*t", "time={final: 1.0, steps: 4}")
    records = sim.run()
    assert [r["factorizations"] for r in records] == [1, 0, 0, 0]
    assert all(r["iterations"] == 1 for r in records)
    sim.close()


def test_reuse_can_be_switched_off():
    sim = simulation("sneddon", "fracture_pressure=1e7*t", "time={final: 1.0, steps: 3}",
                     "solver.reuse_jacobian=false")
    assert [r["factorizations"] for r in sim.run()] == [1, 1, 1]
    sim.close()


def test_stale_factorization_preconditions_small_active_set_changes():
    """After few contact-state switches, GMRES with the previous factorization gives the Newton
    direction; the converged solution is the one found with a refactorization per iteration."""
    values, records = {}, {}
    for stale in ("true", "false"):
        sim = simulation("six_fractures_mechanics", "time.steps=1",
                         f"solver.stale_factorization={stale}")
        records[stale] = sim.run()[0]
        values[stale] = sim.model.face_fields()[:, :4]
        sim.close()
    on, off = records["true"], records["false"]
    assert on["converged"] and off["converged"]
    assert on["stale_solves"] >= 1 and off["stale_solves"] == 0
    assert on["factorizations"] + on["stale_solves"] == on["iterations"]
    assert on["factorizations"] < off["factorizations"] == off["iterations"]
    scale = np.abs(values["false"]).max(axis=0)
    assert np.all(np.abs(values["true"] - values["false"]).max(axis=0) <= 1e-6 * scale)
