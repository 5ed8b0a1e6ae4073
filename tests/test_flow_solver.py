"""The flow module's linear solver: the lagged AMG preconditioner of the coupled Darcy solves."""

import dolfinx_solver  # noqa: F401

import numpy as np
import pytest
from mpi4py import MPI
from petsc4py import PETSc

from poromech.flow.solver import LAG_GROWTH, LAG_SLACK, LinearSolver

N = 16  # a 16³ grid: 4096 unknowns, a tenth of a second per solve


def laplacian(scale: np.ndarray) -> PETSc.Mat:
    """A 7-point finite-volume matrix with cell conductivities ``scale`` and a Dirichlet shell."""
    n = N**3
    idx = np.arange(n).reshape(N, N, N)
    A = PETSc.Mat().createAIJ((n, n), nnz=7, comm=MPI.COMM_SELF)
    for axis in range(3):
        a = np.take(idx, range(N - 1), axis=axis).ravel()
        b = np.take(idx, range(1, N), axis=axis).ravel()
        t = 2.0 / (1.0 / scale[a] + 1.0 / scale[b])
        for i, j, v in zip(a, b, t, strict=True):
            A.setValue(i, j, -v, addv=True)
            A.setValue(j, i, -v, addv=True)
            A.setValue(i, i, v, addv=True)
            A.setValue(j, j, v, addv=True)
    for i in range(n):
        A.setValue(i, i, 1e-2 * scale[i], addv=True)  # storage: SPD without boundary rows
    A.assemble()
    return A


def update(A: PETSc.Mat, scale: np.ndarray) -> None:
    """Put the values of ``laplacian(scale)`` in ``A`` (same pattern)."""
    B = laplacian(scale)
    B.copy(A, structure=PETSc.Mat.Structure.SAME_NONZERO_PATTERN)
    B.destroy()


@pytest.fixture
def system():
    rng = np.random.default_rng(0)
    scale = np.exp(rng.normal(0.0, 0.5, N**3))
    A = laplacian(scale)
    b = A.createVecLeft()
    b.setArray(rng.standard_normal(N**3))
    return A, b, scale


def exact(A, b):
    ksp = PETSc.KSP().create(MPI.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    x = b.duplicate()
    ksp.solve(b, x)
    ksp.destroy()
    return x.getArray().copy()


def lagged_solver(A, b):
    """A lagged iterative solver after its first solve: (solver, x, first record)."""
    solver = LinearSolver(A, "lagtest_", "iterative", {"ksp_initial_guess_nonzero": False}, 3)
    solver.lagged = True
    x = b.duplicate()
    return solver, x, solver.solve(b, x)


def resolve(solver, A, scale, b, x):
    """New matrix values from ``scale``, solved from a zero guess; the record."""
    update(A, scale)
    solver.operator_changed()
    x.set(0.0)
    return solver.solve(b, x)


def test_lagged_preconditioner_kept_for_small_changes_and_solves_to_tolerance(system):
    A, b, scale = system
    solver, x, first = lagged_solver(A, b)
    assert not first.lagged and first.setup_seconds > 0
    for k in range(3):  # an aperture-like change: a few % of the conductivities
        rec = resolve(solver, A, scale * (1.0 + 0.02 * (k + 1)), b, x)
        assert rec.lagged and rec.setup_seconds == 0.0
        assert rec.iterations <= LAG_GROWTH * first.iterations + LAG_SLACK
        ref = exact(A, b)
        assert np.linalg.norm(x.getArray() - ref) <= 1e-9 * np.linalg.norm(ref)
    solver.refresh()  # a new step: a new set-up even for an unchanged matrix
    x.set(0.0)
    assert not solver.solve(b, x).lagged
    solver.destroy()


def test_lagged_preconditioner_rebuilt_when_it_no_longer_pays(system):
    A, b, scale = system
    solver, x, first = lagged_solver(A, b)
    # conductivities up by 10⁴ in a slab of cells: the old hierarchy no longer fits
    big = scale.copy().reshape(N, N, N)
    big[:, :, : N // 2] *= 1e4
    rec = resolve(solver, A, big.ravel(), b, x)
    ref = exact(A, b)
    assert np.linalg.norm(x.getArray() - ref) <= 1e-8 * np.linalg.norm(ref)
    if rec.lagged:  # converged, slowly: the next change gets a new set-up
        assert rec.iterations > LAG_GROWTH * first.iterations + LAG_SLACK
        solver.operator_changed()
        x.set(0.0)
        rec = solver.solve(b, x)
    assert not rec.lagged and rec.setup_seconds > 0
    solver.destroy()


def test_a_direct_solver_is_never_lagged(system):
    A, b, scale = system
    solver = LinearSolver(A, "lagtest_", "direct", None, 3)
    solver.lagged = True
    x = b.duplicate()
    solver.solve(b, x)
    rec = resolve(solver, A, scale * 1.5, b, x)
    assert not rec.lagged
    ref = exact(A, b)
    assert np.linalg.norm(x.getArray() - ref) <= 1e-12 * np.linalg.norm(ref)
    solver.destroy()
