"""The semi-smooth Newton solver: Jacobian consistency, line search, factorization reuse."""

import csv

import dolfinx.fem.petsc
import numpy as np
import pytest
from conftest import ROOT
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import SolverError
from poromech.run import Run, build_mesh, run_scene
from poromech.scene.loading import load_scene

comm = MPI.COMM_WORLD


def run_of(name: str, *overrides: str, prepare=None) -> Run:
    """An in-memory run of a shipped scene (use as a context manager, then ``execute``)."""
    return Run(load_scene(ROOT / "configs" / f"{name}.yaml", list(overrides)), prepare=prepare)


def records_of(name: str, *overrides: str, prepare=None) -> list[dict]:
    """The step records of an in-memory run of a shipped scene."""
    with run_of(name, *overrides, prepare=prepare) as run:
        return run.execute()["solves"]


def no_predictor(physics) -> None:
    physics.predictor.extrapolate = False


@pytest.mark.parametrize("formulation", ["nitsche", "mean_nitsche", "stabilized_mixed", "mixed"])
def test_jacobian_matches_finite_differences(formulation):
    """J·d equals the central difference of the residual, block by block, at a slipping state
    (perturbations scaled entry by entry so that no contact state switches)."""
    with run_of("inclined_crack_slip", "degree=1", f"contact.formulation={formulation}") as run:
        run.execute()
        check_jacobian(run.physics.solver)


def check_jacobian(s, h: float = 1e-7) -> None:
    """J·d against the central difference of step ``h`` (relative to each entry) per block."""
    x = s.x.copy()
    sizes = [f.function_space.dofmap.index_map.size_local * f.function_space.dofmap.index_map_bs
             for f in s.u]
    offsets = np.concatenate([[0], np.cumsum(sizes)])
    s.snes.computeJacobian(x, s.A, s.A)
    rng = np.random.default_rng(3)
    fp, fm = s.b.duplicate(), s.b.duplicate()
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
        s.snes.computeFunction(xp, fp)
        s.snes.computeFunction(xm, fm)
        fd = (fp - fm).getArray() / (2 * h)
        jd = s.A.createVecLeft()
        s.A.mult(d, jd)
        assert np.linalg.norm(fd - jd.getArray()) <= 1e-5 * np.linalg.norm(fd)


def test_contact_line_search_converges_where_full_steps_cycle():
    """On the six-fracture scene, plain Newton (PETSc 'basic') ping-pongs between active sets;
    poromech's line search converges in a few iterations."""
    with pytest.raises(SolverError):
        records_of("six_fractures_mechanics", "time.steps=1", "solver.line_search=basic",
                   "solver.petsc.snes_max_it=40")
    records = records_of("six_fractures_mechanics", "time.steps=1")
    assert records[0]["converged"] and records[0]["iterations"] <= 12


def test_factorization_reused_across_steps_of_a_linear_problem():
    """An open pressurized crack is linear: one factorization serves every time step."""
    # without the predictor, which would start every later step at the answer
    records = records_of("sneddon", "fracture_pressure=1e7*t", "time={final: 1.0, steps: 4}",
                         prepare=no_predictor)
    assert [r["factorizations"] for r in records] == [1, 0, 0, 0]
    assert all(r["iterations"] == 1 for r in records)


@pytest.mark.parametrize("name", ["terzaghi", "terzaghi3d"])
def test_a_jacobian_without_contact_is_assembled_once(name):
    """A column without fractures and with constant moduli (the coupled Terzaghi scenes): the
    Jacobian is assembled at the first Newton iteration of the run only. Assembling it at every
    iteration, as before, gives the same displacement and pressures bitwise."""
    assemblies, fields = {}, {}
    for constant in (True, False):
        calls = []

        def prepare(physics, constant=constant, calls=calls):
            solver = physics.mech.solver
            assert solver.constant_jacobian
            solver.constant_jacobian = constant
            assembled = solver.linear.assembled

            def counted(states):
                calls.append(states)
                assembled(states)

            solver.linear.assembled = counted

        with run_of(name, "time.steps=3", prepare=prepare) as run:
            summary = run.execute()
            fields[constant] = [f.x.array.copy() for f in (run.physics.model.u,
                                                           run.physics.model.p_m)]
        assemblies[constant] = len(calls)
    assert assemblies[True] == 1
    assert assemblies[False] == summary["coupling"]["newton_iterations"] + 1  # + the initial one
    for a, b in zip(fields[True], fields[False], strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize(("name", "overrides"), [
    ("inclined_crack_slip", ["contact.formulation=nitsche"]),
    ("inclined_crack_slip", ["contact.formulation=mean_nitsche"]),
    ("inclined_crack_slip", ["contact.formulation=stabilized_mixed"]),
    ("inclined_crack_slip", ["contact.formulation=mixed", "degree=2"]),
    ("network3d", ["degree=1", "mesh.size=0.75", "mesh.fracture_size=0.25", "time.final=2",
                   "output.xdmf=false"]),
])
def test_jacobian_from_the_constant_bulk_equals_the_full_assembly(name, overrides):
    """The Jacobian as the kept bulk stiffness plus the contact terms is, entry by entry and
    bitwise, the Jacobian assembled from its full forms (2D, and 3D with Coulomb friction)."""
    scipy = pytest.importorskip("scipy.sparse")
    with run_of(name, *overrides) as run:
        run.execute()
        s = run.physics.solver
        s.states_determine_jacobian = False  # assemble even in the last active set
        s.snes.computeJacobian(s.x, s.A, s.A)  # (the first Jacobian of a run keeps the bulk)
        assert s._K is not None
        s.snes.computeJacobian(s.x, s.A, s.A)
        full = dolfinx.fem.petsc.assemble_matrix(s.J, s.bcs, diag=1.0)
        full.assemble()

        def csr(M):
            return scipy.csr_matrix(M.getValuesCSR()[::-1], shape=M.getSize())

        a, b = csr(s.A), csr(full)
        a.eliminate_zeros()
        b.eliminate_zeros()
        assert a.nnz == b.nnz > 0
        assert (a != b).nnz == 0
        full.destroy()


def test_reuse_can_be_switched_off():
    records = records_of("sneddon", "fracture_pressure=1e7*t", "time={final: 1.0, steps: 3}",
                         "solver.reuse_jacobian=false", prepare=no_predictor)
    assert [r["factorizations"] for r in records] == [1, 1, 1]
    # the matrix is assembled every time: PETSc keeps the factors of an unmodified matrix, so a
    # kept Jacobian would be counted as factorized without being factorized again
    assert [r["jacobian_reuses"] for r in records] == [0, 0, 0]


@pytest.mark.parametrize(("name", "overrides"), [
    ("sneddon", ["contact.formulation=nitsche", "contact.beta_n=1e12", "contact.beta_t=1e12"]),
    ("six_fractures_mechanics", ["time.steps=2", "contact.formulation=nitsche"]),
    ("six_fractures_mechanics", ["time.steps=2", "contact.formulation=mixed",
                                 "solver.condensation=false"]),
])
def test_jacobian_kept_for_an_unchanged_active_set_changes_no_iterate(name, overrides):
    """The Jacobian is a function of the contact branches only, so keeping it while no code
    changes gives the iterates of a fresh assembly. A fracture at rest is a tie of the open
    branch (``P_τ = 0`` takes the stick derivative): coded like an open face, it kept a wrong
    Jacobian and Newton crawled to its iteration limit on an open Sneddon crack."""
    runs = {}
    for keep in (True, False):
        def configure(physics, keep=keep):
            assert physics.solver.states_determine_jacobian  # 2D: piecewise affine
            physics.solver.states_determine_jacobian = keep
        runs[keep] = records_of(name, *overrides, prepare=configure)
    assert [r["iterations"] for r in runs[True]] == [r["iterations"] for r in runs[False]]
    roundoff = 1e-12 * runs[False][0]["residuals"][0]
    for kept, fresh in zip(runs[True], runs[False], strict=True):
        assert kept["converged"] and kept["iterations"] <= 12
        np.testing.assert_allclose(kept["residuals"], fresh["residuals"], rtol=1e-6, atol=roundoff)
    if name == "six_fractures_mechanics":
        assert sum(r["jacobian_reuses"] for r in runs[True]) >= 1


def stale_on_small_meshes(physics) -> None:
    """Stale GMRES on a mesh below the size where it pays (so that the tests see it)."""
    physics.solver.linear.stale_min_unknowns = 0


def face_values(model) -> np.ndarray:
    """Jumps and tractions of the owned faces, ``(faces, 4)``."""
    f = model.face_fields()
    return np.column_stack([f["jump_n"], f["jump_t"], f["traction_n"], f["traction_t"]])


def test_stale_factorization_preconditions_small_active_set_changes():
    """After few contact-state switches, GMRES with the previous factorization gives the Newton
    direction; the converged solution is the one found with a refactorization per iteration.
    The choice depends on the contact states only, so a second run takes the same decisions
    and repeats the first to round-off (the choice used to depend on measured times)."""
    values, records = {}, {}
    for key in ("true", "true again", "false"):
        with run_of("six_fractures_mechanics", "time.steps=1",
                    f"solver.stale_factorization={key.split()[0]}",
                    prepare=stale_on_small_meshes) as run:
            records[key] = run.execute()["solves"][0]
            values[key] = face_values(run.physics.model)
    on, off = records["true"], records["false"]
    for key in ("iterations", "factorizations", "stale_solves"):
        assert records["true again"][key] == on[key]
    np.testing.assert_allclose(records["true again"]["residuals"], on["residuals"], rtol=1e-9,
                               atol=1e-12 * on["residuals"][0])
    assert on["converged"] and off["converged"]
    assert on["stale_solves"] >= 1 and off["stale_solves"] == 0
    assert on["factorizations"] + on["stale_solves"] == on["iterations"]
    assert on["factorizations"] < off["factorizations"] == off["iterations"]
    scale = np.abs(values["false"]).max(axis=0)
    assert np.all(np.abs(values["true"] - values["false"]).max(axis=0) <= 1e-6 * scale)


def test_stale_budget_refactorizes_once_stale_solves_cost_a_factorization():
    """Stale GMRES iterations between two factorizations are bounded by ``stale_budget``: with
    a budget of 0 every Newton iteration factorizes; with 1 the first stale solve spends it, so
    the next changed Jacobian is factorized (fewer stale solves than with the default budget);
    the iterates do not change."""
    records = {}
    for budget in (0, 1, None):
        def configure(physics, budget=budget):
            stale_on_small_meshes(physics)
            if budget is not None:
                physics.solver.linear.stale_budget = budget
        records[budget] = records_of("six_fractures_mechanics", "time.steps=1",
                                     prepare=configure)[0]
    none, one, default = records[0], records[1], records[None]
    assert none["stale_solves"] == 0 and none["factorizations"] == none["iterations"]
    assert 1 <= one["stale_solves"] < default["stale_solves"]
    assert one["factorizations"] > default["factorizations"]
    for rec in records.values():
        assert rec["converged"] and rec["iterations"] == none["iterations"]
        assert rec["factorizations"] + rec["stale_solves"] == rec["iterations"]


def test_priced_stale_budget_is_the_factorization_in_iterations_and_backs_off(monkeypatch):
    """3D (``priced``): stale GMRES is tried whatever the contact states did, within a budget of
    iterations priced from MUMPS' counts of the factorization (deterministic: a run repeats its
    choices); a Jacobian far from the factorized one fails within the budget, and failures in a
    row make the tries rarer (4^k - 1 skipped). On the 3D fault scene's medium mesh (``mixed``
    P2, 119k unknowns, 2 ranks, 8 steps) 5 factorizations instead of 10, 104 s against 137 s,
    the same Newton iterations and fractures.csv to 4e-14 (docs/mechanics3d.md)."""
    import poromech.mechanics.linear as linear
    from poromech.mechanics.newton import NewtonRecord

    n = 20**3  # a 3D Laplacian: the fill of a 3D factorization
    A = PETSc.Mat().createAIJ([n, n], nnz=7, comm=PETSc.COMM_SELF)
    idx = np.arange(n).reshape(20, 20, 20)
    for axis in range(3):
        for a, b in ((np.take(idx, range(19), axis), np.take(idx, range(1, 20), axis)),):
            for i, j in zip(a.ravel(), b.ravel(), strict=True):
                A.setValue(i, j, -1.0, addv=True)
                A.setValue(j, i, -1.0, addv=True)
    for i in range(n):
        A.setValue(i, i, 6.5, addv=True)
    A.assemble()
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(A, A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    monkeypatch.setattr(linear, "SOLVE_SLOWDOWN", 0.5)  # a budget of tens of iterations here
    solver = linear.DirectSolver(ksp, A, "priced_", reuse=True, stale=True, priced=True)
    F, Y = A.createVecs()
    F.set(1.0)
    record = NewtonRecord()
    assert solver.solve(F, Y, record, None) and record.factorizations == 1
    factor = ksp.getPC().getFactorMatrix()
    work = 0.5 * (4.0 * factor.getMumpsInfog(29) + 2.0 * A.getInfo()["nz_used"])
    assert solver.stale_budget == int(factor.getMumpsRinfog(3) / work) >= 12
    # a nearby Jacobian: solved with the old factors, to the stale tolerance
    A.shift(1e-3)
    solver.assembled(None)
    assert solver.solve(F, Y, record, None)
    assert record.factorizations == 1 and record.stale_solves == 1
    R = F.duplicate()
    A.mult(Y, R)
    R.axpy(-1.0, F)
    assert R.norm() <= linear.STALE_RTOL * F.norm()
    # a distant one: the stale try fails within the rest of the budget, then factorizes
    tries, rng = [], np.random.default_rng(1)
    for _ in range(5):
        before = (record.factorizations, record.stale_solves, record.linear_iterations)
        scale = F.duplicate()
        scale.setArray(10.0 ** rng.uniform(-3.0, 3.0, n))  # rows scaled by 1e-3 .. 1e3
        A.diagonalScale(scale)
        solver.assembled(None)
        assert solver.solve(F, Y, record, None)
        tried = record.linear_iterations > before[2]
        assert record.factorizations == before[0] + 1 and record.stale_solves == before[1]
        assert record.linear_iterations - before[2] <= solver.stale_budget
        tries.append(tried)
    # tried and failed; the next 4^1 - 1 = 3 skipped; tried and failed again: 4^2 - 1 to skip
    assert tries == [True, False, False, False, True]
    assert solver._stale_misses == 2 and solver._stale_skip == 15
    solver.destroy()
    ksp.destroy()
    A.destroy()


# -- the model and its Newton on their own (unit tests of the solver) ---------------------------
def model_and_solver(name: str, *overrides: str, solver_class=None):
    from poromech.mechanics.model import MechanicsModel
    from poromech.mechanics.newton import SemiSmoothNewton

    scene = load_scene(ROOT / "configs" / f"{name}.yaml", list(overrides))
    fm = build_mesh(scene, comm)
    model = MechanicsModel(fm, scene)
    solver = (solver_class or SemiSmoothNewton)(model.F, model.J, model.unknowns, model.bcs,
                                                prefix="test_", states=model.active_set)
    return scene, fm, model, solver


# -- active-set changes (issue 7 §2) ------------------------------------------------------------
@pytest.mark.parametrize(("formulation", "points"), [("nitsche", 3), ("mixed", 1)])
def test_active_set_changes_count_what_switches(formulation, points):
    """Pointwise Nitsche has one state per Gauss point of the contact quadrature (3 per face for
    P2), the facewise formulations one per face. The residual is piecewise affine in the
    unknowns, so an iteration that takes the full step and changes no code lands on the root:
    a zero count is followed by convergence (the issue's ``46,2,0,0,0`` cannot happen)."""
    scene, fm, model, solver = model_and_solver(
        "six_fractures_mechanics", "time.final=100", "time.steps=1",
        f"contact.formulation={formulation}")
    assert comm.allreduce(len(model.active_set())) == points * fm.num_fracture_faces
    model.set_time(100.0)
    rec = solver.solve()
    assert rec.converged
    ref = rec.residuals[0]
    for k, (changes, alpha) in enumerate(zip(rec.active_set_changes, rec.steps, strict=False)):
        if changes == 0 and alpha == 1.0:
            assert rec.residuals[k + 1] <= 1e-9 * ref, (k, rec.active_set_changes)
    assert rec.active_set_changes[0] > 0
    solver.destroy()


def test_active_set_points_are_the_gauss_points():
    """Collocation of the code recovers the Gauss points of each face: here x itself."""
    import basix
    import ufl

    _, fm, model, solver = model_and_solver("inclined_crack_slip", "degree=2")
    x = ufl.SpatialCoordinate(fm.msh)
    got = model.collocate(x[0]("+"))
    pts, _ = basix.make_quadrature(basix.CellType.interval, model.params.quadrature_degree)
    sub = model.submesh
    n = sub.topology.index_map(1).size_local
    ends = sub.geometry.x[sub.geometry.dofmaps[0][:n]][:, :, 0]
    expected = ends[:, :1] + pts[:, 0][None, :] * (ends[:, 1:] - ends[:, :1])
    assert got.shape == expected.shape == (n, 3)
    assert np.allclose(np.sort(got, axis=1), np.sort(expected, axis=1), atol=1e-12)
    solver.destroy()


# -- NaN and infinite residuals (issue 7 §4) ----------------------------------------------------
@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_initial_residual_ends_the_solve(bad):
    """A NaN or infinite residual ends the solve with PETSc's DIVERGED_FUNCTION_NANORINF and a
    record, not with an exception."""
    _, _, model, solver = model_and_solver("inclined_crack_slip", "degree=1")
    model.set_time(0.0)
    model.u.x.array[7] = bad
    rec = solver.solve()
    assert not rec.converged
    assert rec.reason == "DIVERGED_FUNCTION_NANORINF"
    assert rec.iterations == 0
    solver.destroy()


def test_nan_residual_during_the_line_search_ends_the_solve():
    """Every trial residual NaN after two evaluations: the solve ends with the NaN reason."""
    _, _, model, solver = model_and_solver("inclined_crack_slip", "degree=1")
    b, (residual, _, _) = solver.snes.getFunction()

    def nan_after_two(snes, x, f):
        residual(snes, x, f)
        if solver.record.residual_evaluations > 2:  # assemblies so far in this solve
            f.set(np.nan)

    solver.snes.setFunction(nan_after_two, b)
    model.set_time(0.0)
    rec = solver.solve()
    assert not rec.converged
    assert rec.reason == "DIVERGED_FUNCTION_NANORINF"
    assert np.all(np.isfinite(rec.residuals))
    solver.destroy()


# -- Newton iterations against the mesh (issue 7 §6) -------------------------------------------
def test_predictor_starts_each_step_from_the_extrapolated_increment():
    """The last accepted increment, scaled by the step ratio, starts each step: on the
    six-fracture ramp (proportional loading) every step after the first takes at most one
    Newton iteration, where starting from the accepted state (zero slip increment: every
    sliding point sticks) took 4-7; the converged answer is the same."""
    faces, records = {}, {}
    for on in (True, False):
        with run_of("six_fractures_mechanics", prepare=None if on else no_predictor) as run:
            records[on] = run.execute()["solves"]
            faces[on] = face_values(run.physics.model)
    assert all(r["iterations"] <= 1 for r in records[True][1:])
    assert all(r["iterations"] >= 3 for r in records[False][1:])
    scale = np.abs(faces[True]).max(axis=0)
    assert np.all(np.abs(faces[False] - faces[True]).max(axis=0) <= 1e-6 * scale)


def test_predictor_uses_accepted_states_only():
    """Non-uniform steps scale the increment by the step ratio; unknowns that are not the last
    accepted ones (a restored checkpoint, a repeated solve of the same step) are kept."""
    with run_of("six_fractures_mechanics", "time={times: [100.0, 150.0]}") as run:
        run.execute()
        mech, fm = run.physics, run.mesh
        (t1, (u1, *_)), (t2, (u2, *_)) = mech.predictor.history
        assert (t1, t2) == (100.0, 150.0)
        mech.predictor.predict(250.0)
        assert np.allclose(mech.model.u.x.array, u2 + 2.0 * (u2 - u1))
        mech.model.u.x.array[:] = u2 + 1.0
        mech.predictor.predict(250.0)
        assert np.allclose(mech.model.u.x.array, u2 + 1.0) and mech.predictor.history == []

    def restored(physics):  # not the zero state of t = 0
        physics.model.u.x.array[:] = u2

    scene = load_scene(ROOT / "configs" / "six_fractures_mechanics.yaml", ["time={times: [300.0]}"])
    with Run(scene, mesh=fm, prepare=restored) as run:
        run.execute()
        mech = run.physics
        assert len(mech.predictor.history) == 1
        mech.predictor.predict(400.0)
        assert np.allclose(mech.model.u.x.array, mech.predictor.history[0][1][0])


@pytest.mark.parametrize(("target", "start"), [(5.0, "extrapolated"), (2.0, "last"),
                                             (np.nan, "last")])
def test_predictor_keeps_the_start_of_lower_merit(target, start):
    """With a merit (``solver.predictor: lower_residual``) the extrapolation is kept only where
    its merit is lower than the last unknowns'; a non-finite merit keeps the last ones."""
    import dolfinx

    from poromech.mechanics.predictor import StepPredictor

    msh = dolfinx.mesh.create_unit_interval(MPI.COMM_SELF, 4)
    u = dolfinx.fem.Function(dolfinx.fem.functionspace(msh, ("Lagrange", 1)))
    calls = []

    def merit() -> float:  # distance of the unknowns from ``target``
        calls.append(u.x.array.copy())
        return float(np.abs(u.x.array - target).max())

    predictor = StepPredictor([u], MPI.COMM_SELF, merit=merit)
    for t, value in ((1.0, 1.0), (2.0, 3.0)):  # accepted steps: u = 1, then u = 3
        predictor.predict(t)
        u.x.array[:] = value
        predictor.accept()
    predictor.predict(3.0)  # candidates: u = 3 (last) and u = 5 (extrapolated)
    assert predictor.start == start
    assert np.all(u.x.array == (5.0 if start == "extrapolated" else 3.0))
    # one merit at each candidate from the second step on (the zero start counts as t = 0)
    assert [c[0] for c in calls] == [1.0, 2.0, 3.0, 5.0]


def test_predictor_does_not_extrapolate_over_a_step_far_longer_than_the_last():
    """Listed times [1e-300, 1]: extrapolating the first step's change by 1e300 overflowed, and
    every cut of the second step failed on a residual that was not finite. A step more than
    ``MAX_RATIO`` times the last starts from the last unknowns, and the run converges."""
    from poromech.mechanics.predictor import MAX_RATIO

    with run_of("sneddon", "time={times: [1.0e-300, 1.0]}") as run:
        records = run.execute()["solves"]
        history = run.physics.predictor.history
    assert [r["converged"] for r in records] == [True, True]
    assert np.array_equal(history[0][1][0], history[1][1][0])  # a linear problem, one load
    with run_of("sneddon", f"time={{times: [1.0, {1.0 + 0.5 * MAX_RATIO}]}}") as run:
        run.execute()
        assert run.physics.predictor.start == "extrapolated"


@pytest.mark.slow
def test_newton_iterations_do_not_grow_with_the_mesh():
    """Pointwise P2 Nitsche on the six-fracture ramp: at most 12 Newton iterations per step from
    0.66k to 12k cells (before: 5, 7 and 13 in the first step, 4-7 in every later one)."""
    levels = [("mesh.size=0.095", "mesh.fracture_size=0.085"), ("mesh.refinement=0",),
              ("mesh.refinement=1",)]
    for level in levels:
        iterations = [r["iterations"] for r in records_of("six_fractures_mechanics", *level)]
        assert max(iterations) <= 12, (level, iterations)


def test_a_failure_message_quotes_the_ends_of_a_long_history():
    """A failed Newton quoted its whole residual history on one line (100-300 values, several
    kB); the message keeps the first and last few, and the step records keep them all."""
    from poromech.mechanics.newton import QUOTED_RESIDUALS, quoted_history

    k = QUOTED_RESIDUALS
    short = [1.0, 0.5, 0.25]
    assert quoted_history(short) == "1.000e+00, 5.000e-01, 2.500e-01"
    long = [float(i) for i in range(101)]
    text = quoted_history(long)
    assert text.startswith("0.000e+00, 1.000e+00") and text.endswith("1.000e+02")
    assert f"... ({101 - 2 * k} more) ..." in text and len(text.split(", ")) == 2 * k + 1


def test_a_residual_at_round_off_has_converged(tmp_path):
    """The relative tolerance is taken from the largest initial residual, which falls with the
    load increment: an inclined crack (a user's scene) loaded in 1,500 steps stalled at
    |F| = 1.7e-6 against a tolerance of 1.56e-6 (1.5e-13 of the forces in balance) and failed
    every cut. A residual at round-off of ``‖J x‖`` has converged; here a tolerance below
    round-off from the start (``snes_rtol`` 1e-16), which failed by the same stall
    (DIVERGED_LINE_SEARCH after 94 iterations), gives the default run's jumps."""
    from poromech.io.results import read_table  # noqa: PLC0415
    from poromech.mechanics.newton import ROUNDOFF_FLOOR  # noqa: PLC0415
    from poromech.run import run_scene  # noqa: PLC0415

    scene = load_scene(ROOT / "configs" / "inclined_crack_slip.yaml", ["output.xdmf=false"])
    tight = load_scene(ROOT / "configs" / "inclined_crack_slip.yaml",
                       ["output.xdmf=false", "solver.petsc={snes_rtol: 1e-16}"])
    ref = run_scene(scene, tmp_path / "default")
    summary = run_scene(tight, tmp_path / "tight")
    rec = summary["solves"][-1]
    assert rec["reason"] == "CONVERGED_FNORM_ABS" and rec["iterations"] < 10
    assert rec["residuals"][-1] < 1e-16 * rec["residuals"][0] * 1e4  # far below the default's
    assert ref["solves"][-1]["reason"] == "CONVERGED_FNORM_RELATIVE"
    a = read_table(tmp_path / "tight" / "fractures.csv")
    b = read_table(tmp_path / "default" / "fractures.csv")
    for key in ("jump_n", "jump_t"):
        assert np.allclose(a[key], b[key], rtol=0, atol=1e-8 * np.abs(b["jump_t"]).max())
    assert ROUNDOFF_FLOOR < 1e-10  # below the default relative tolerance


@pytest.mark.parametrize("formulation", ["mixed", "nitsche"])
def test_a_stiffness_contrast_converges_at_the_round_off_of_its_terms(tmp_path, formulation):
    """A layer of E = 1e4 Pa under one of 1e10 Pa, a horizontal interface and an inclined crack,
    compressed by a top traction: the stress is uniform and both fractures stick. The first
    full step reached the solution at the round-off of the stiff side's terms (2.4e-16
    ‖diag(J) x‖), above the relative tolerance; the line search then stalled and the step
    failed (exit 3) with every formulation. The stall there is now convergence."""
    from poromech.scene.loading import scene_from_dict

    c = 0.2828427
    raw = {
        "name": "contrast", "physics": "mechanics",
        "geometry": {"domain": {"rectangle": [-1, -1, 1, 1]},
                     "fractures": [{"name": "iface", "points": [[-1, 0], [1, 0]]},
                                   {"name": "incl", "points": [[-c, -c], [c, c]]}]},
        "mesh": {"size": 0.25, "fracture_size": 0.1}, "degree": 2,
        "material": {"young": "where(y > 0, 1e10, 1e4)", "poisson": 0.25},
        "contact": {"formulation": formulation, "friction": "coulomb",
                    "friction_coefficient": 0.6},
        "boundary_conditions": [{"boundary": "bottom", "displacement": [0, 0]},
                                {"boundary": "left", "displacement": [0, None]},
                                {"boundary": "right", "displacement": [0, None]},
                                {"boundary": "top", "traction": [0, -1000]}],
    }
    summary = run_scene(scene_from_dict(raw), tmp_path)
    assert summary["status"] == "converged", summary["solves"][-1]["reason"]
    rows = list(csv.DictReader(open(tmp_path / "fractures.csv")))
    want = {"iface": (-1000.0, 0.0), "incl": (-2000.0 / 3, 1000.0 / 3)}
    for r in rows:
        tn, tt = want[r["fracture"]]
        assert float(r["traction_n"]) == pytest.approx(tn, rel=1e-5)
        assert abs(float(r["traction_t"])) == pytest.approx(tt, rel=1e-5, abs=1e-5)
        assert abs(float(r["jump_n"])) < 1e-14 and abs(float(r["jump_t"])) < 1e-14
        assert r["state"] == "stick"
