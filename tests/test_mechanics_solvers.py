"""The linear solvers of the mechanics: direct (MUMPS) and iterative (CG + GAMG), and the choice."""

import copy
import json
import re
import subprocess
import sys

import dolfinx_solver  # noqa: F401

import numpy as np
import pytest
import ufl
from conftest import ROOT, mechanics_scene, run_parallel
from dolfinx import fem
from dolfinx.fem.petsc import assemble_matrix
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import ConfigError, SolverError
from poromech.forms.elasticity import elastic_form
from poromech.io.checkpoint import cell_dof_rows
from poromech.mechanics.linear import ITERATIVE_OPTIONS, rigid_body_modes
from poromech.mesh.fractured import cracked_space
from poromech.run import Run, build_mesh
from poromech.scene import resources
from poromech.scene.loading import load_scene, scene_from_dict
from poromech.scene.resources import ITERATIVE_FROM_UNKNOWNS_3D, mechanics_solver

PENNY = ROOT / "configs" / "penny.yaml"
#: A coarse penny crack (about 5,000 P2 unknowns): seconds per solve.
COARSE = ["mesh.size=3.0", "mesh.fracture_size=0.5", "mesh.tip_size=0.15",
          "output.xdmf=false", "output.fractures_csv=false"]


def _gather_sorted(comm, keys, values):
    """Rows of every rank, sorted by key, on rank 0 (None elsewhere)."""
    parts = comm.gather((keys, values), root=0)
    if comm.rank != 0:
        return None
    k = np.concatenate([p[0] for p in parts])
    v = np.concatenate([p[1] for p in parts])
    return v[np.argsort(k, kind="stable")]


def penny_solution(comm, *overrides: str, crack_on_process_boundary: bool = False,
                   prepare=None) -> dict:
    """Solve the coarse penny crack: summary, displacement rows by input cell and openings by
    fracture face, gathered on rank 0 (collective)."""
    scene = load_scene(PENNY, COARSE + list(overrides))
    owner = None
    if crack_on_process_boundary:  # cells above the crack on rank 1: every face on the boundary

        def owner(centroids):
            return (centroids[:, 2] > 0).astype(np.int32) if comm.size > 1 else None

    fm = build_mesh(scene, comm, owner=owner)
    with Run(scene, comm=comm, mesh=fm, prepare=prepare) as run:
        summary = run.execute()
        model = run.physics.model
        keys, rows = cell_dof_rows(fm, model.V, model.u.x.array)
        u = _gather_sorted(comm, keys, rows)
        w = _gather_sorted(comm, fm.fractures.index, model.face_fields()["jump_n"])
    return {"summary": summary, "u": u, "w": w}


def _relative(a, b) -> float:
    return float(np.abs(a - b).max() / np.abs(b).max())


def test_iterative_matches_direct_on_the_penny_crack():
    """CG + GAMG to ``ksp_rtol`` 1e-11 gives MUMPS' displacement to 1e-8 (measured ~1e-12)."""
    comm = MPI.COMM_WORLD
    direct = penny_solution(comm, "solver.linear_solver=direct")
    iterative = penny_solution(comm, "solver.linear_solver=iterative")
    sd, si = direct["summary"], iterative["summary"]
    assert sd["linear_solver"]["kind"] == "direct" and sd["linear_solver"]["pc_type"] == "lu"
    setup = si["linear_solver"].pop("time_preconditioner")
    assert si["linear_solver"] == {"kind": "iterative", "choice": "iterative", "ksp_type": "cg",
                                   "pc_type": "gamg", "krylov_iterations": si["solves"][0][
                                       "linear_iterations"], "preconditioner_setups": 1}
    assert 0 < setup <= si["wall_time"]["linear_solve"]
    # a linear problem: one Newton iteration, the linear solve meets the Newton's tolerance
    assert si["solves"][0]["iterations"] == 1 and 10 <= si["linear_solver"][
        "krylov_iterations"] <= 80
    assert _relative(iterative["u"], direct["u"]) < 1e-8
    assert _relative(iterative["w"], direct["w"]) < 1e-8
    assert np.abs(iterative["w"]).max() > 1e-5  # the crack opens (m)


def _elastic_operator(V):
    """The elastic stiffness on ``V`` without any Dirichlet condition."""
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    A = assemble_matrix(fem.form(elastic_form(u, v, 1.0e10, 0.25, ufl.dx)))
    A.assemble()
    return A


@pytest.mark.parametrize("scene", ["penny", "sneddon"])
def test_rigid_body_modes_are_the_kernel_of_the_cracked_elastic_operator(scene):
    """Translations and rotations at the dofs of the cracked space: ``‖A z‖ ≈ 0`` (round-off),
    orthonormal; a crack opening (a mode on one side only) is not in the kernel."""
    comm = MPI.COMM_WORLD
    overrides = COARSE if scene == "penny" else ["mesh.size=0.5"]
    fm = build_mesh(load_scene(ROOT / "configs" / f"{scene}.yaml", overrides), comm)
    V = cracked_space(fm, 2)
    d = fm.msh.geometry.dim
    modes = rigid_body_modes(V)
    assert modes.shape[0] == (6 if d == 3 else 3)
    assert np.allclose(comm.allreduce(modes @ modes.T), np.eye(len(modes)), atol=1e-12)
    A = _elastic_operator(V)
    z, y = A.createVecRight(), A.createVecLeft()
    norm_a = A.norm(PETSc.NormType.FROBENIUS)
    for mode in modes:
        z.getArray()[:] = mode
        A.mult(z, y)
        assert y.norm() <= 1e-12 * norm_a * z.norm()
    # translation of the '+' side only: it opens the fracture and is resisted
    z.set(0.0)
    plus = np.unique(V.dofmap.list[fm.fractures.plus[:, 0]])
    plus = plus[plus < V.dofmap.index_map.size_local]
    z.getArray().reshape(-1, d)[plus, d - 1] = 1.0
    A.mult(z, y)
    assert comm.allreduce(len(plus)) > 0 and y.norm() > 1e-6 * norm_a * z.norm()


def test_p_multigrid_coarse_level_is_the_p1_space_of_the_cracked_mesh():
    """The p-multigrid's interpolation maps any P1 function of the cracked space, one that
    jumps across the crack included (random dof values), to the same function in P2; so the
    Galerkin operator ``Pᵀ A₂ P`` of the P2 stiffness is the P1 stiffness of the cracked
    space (to round-off), with no entry between the two sides of the crack. It fails if the
    interpolation joined the sides (``P`` of the uncracked space) or lost a component."""
    from poromech.mechanics.multigrid import p1_interpolation

    comm = MPI.COMM_WORLD
    fm = build_mesh(load_scene(PENNY, COARSE), comm)
    V2, V1 = cracked_space(fm, 2), cracked_space(fm, 1)
    P = p1_interpolation(V2, V1)
    u1, u2 = fem.Function(V1), fem.Function(V2)
    u1.x.array[:] = np.random.default_rng(comm.rank).random(u1.x.array.size)
    u1.x.scatter_forward()
    u2.interpolate(u1)
    y = P.createVecLeft()
    P.mult(u1.x.petsc_vec, y)
    n2 = V2.dofmap.index_map.size_local * V2.dofmap.index_map_bs
    assert np.abs(y.getArray() - u2.x.array[:n2]).max() < 1e-12
    A1, A2 = _elastic_operator(V1), _elastic_operator(V2)
    G = A2.ptap(P)
    G.axpy(-1.0, A1, structure=PETSc.Mat.Structure.DIFFERENT_NONZERO_PATTERN)
    assert G.norm(PETSc.NormType.FROBENIUS) < 1e-10 * A1.norm(PETSc.NormType.FROBENIUS)


def test_p_multigrid_fine_operator_is_a_block_copy_of_the_jacobian():
    """The Krylov method and the P2 smoother use a copy of the Jacobian stored in 3 × 3 blocks
    (BAIJ, a faster product); the copy applies the same operator (to round-off) and is
    refreshed at each set-up, and the coarse operator is still ``Pᵀ A P`` of the AIJ
    Jacobian."""
    from poromech.mechanics.linear import near_nullspace
    from poromech.mechanics.multigrid import PMultigrid, p1_interpolation

    comm = MPI.COMM_WORLD
    fm = build_mesh(load_scene(PENNY, COARSE), comm)
    V2, V1 = cracked_space(fm, 2), cracked_space(fm, 1)
    A = _elastic_operator(V2)
    near_nullspace(A, rigid_body_modes(V2))
    ksp = PETSc.KSP().create(comm)
    mg = PMultigrid(ksp, p1_interpolation(V2, V1), rigid_body_modes(V1), near_nullspace)
    z, y, w = A.createVecRight(), A.createVecLeft(), A.createVecLeft()
    z.setRandom()
    for scale in (1.0, 2.0):  # the second set-up refreshes the copy
        A.scale(scale)
        fine = mg.set_up(A)
        assert fine.getType().endswith("baij") and fine.getBlockSize() == 3
        A.mult(z, y)
        fine.mult(z, w)
        w.axpy(-1.0, y)
        assert w.norm() < 1e-13 * y.norm()
        G = A.ptap(mg.P)
        G.axpy(-1.0, mg.A_coarse)
        assert G.norm(PETSc.NormType.FROBENIUS) == 0.0
    mg.destroy()
    ksp.destroy()


SERIAL_VS_PARALLEL = """
import sys, json
sys.path.insert(0, "tests")
import dolfinx_solver
from mpi4py import MPI
from test_mechanics_solvers import penny_solution
comm = MPI.COMM_WORLD
out = penny_solution(comm, "solver.linear_solver=iterative", crack_on_process_boundary=True)
if comm.rank == 0:
    print(json.dumps({"w": out["w"].tolist(), "u": out["u"].tolist(),
                      "ranks": out["summary"]["mpi_ranks"],
                      "its": out["summary"]["linear_solver"]["krylov_iterations"]}))
"""


@pytest.mark.mpi
def test_iterative_solver_one_rank_equals_two_ranks():
    """Openings and displacements on 1 and on 2 ranks (every crack face on the process boundary)
    agree to the solver tolerance; the iteration count hardly changes."""
    serial = penny_solution(MPI.COMM_SELF, "solver.linear_solver=iterative")
    par = run_parallel(SERIAL_VS_PARALLEL)
    assert par["ranks"] == 2
    w, u = np.asarray(par["w"]), np.asarray(par["u"])
    assert w.shape == serial["w"].shape and u.shape == serial["u"].shape
    assert _relative(w, serial["w"]) < 1e-9
    assert _relative(u, serial["u"]) < 1e-9
    assert abs(par["its"] - serial["summary"]["linear_solver"]["krylov_iterations"]) <= 10


@pytest.mark.parametrize(("overrides", "reuses", "setups"), [
    # the Jacobian of open fractures is kept: neither assembled nor set up again
    ((), [0, 1, 1], [1, 0, 0]),
    # a Young's modulus "in time" is assembled every step, found equal by its fingerprint
    (("material.young=E + 0*t",), [0, 0, 0], [1, 0, 0]),
    # solver.reuse_jacobian false: assembled and set up every step
    (("solver.reuse_jacobian=false",), [0, 0, 0], [1, 1, 1]),
])
def test_preconditioner_kept_while_the_operator_is_unchanged(overrides, reuses, setups):
    """A linear problem in time: the GAMG hierarchy of step 1 serves every step unless the
    scene asks otherwise; scene PETSc options win over the choice's defaults."""
    def no_predictor(physics) -> None:  # which would make later steps exact, without a solve
        physics.predictor.extrapolate = False

    out = penny_solution(MPI.COMM_WORLD, "solver.linear_solver=iterative",
                         "fracture_pressure=1e6*t", "time={final: 1.0, steps: 3}",
                         "solver.petsc.ksp_type=gmres", *overrides, prepare=no_predictor)
    records = out["summary"]["solves"]
    assert [r["jacobian_reuses"] for r in records] == reuses
    assert [r["factorizations"] for r in records] == setups
    assert all(r["iterations"] == 1 and r["linear_iterations"] > 0 for r in records)
    assert all((r["time_preconditioner"] > 0) == (n > 0) for r, n in zip(records, setups,
                                                                          strict=True))
    assert out["summary"]["linear_solver"]["ksp_type"] == "gmres"
    assert out["summary"]["linear_solver"]["preconditioner_setups"] == sum(setups)


def test_auto_is_direct_in_2d_and_iterative_for_large_3d():
    sneddon = load_scene(ROOT / "configs" / "sneddon.yaml", ["mesh.size=0.5"])
    assert mechanics_solver(sneddon, 1e9) == "direct"
    penny = load_scene(PENNY)
    assert mechanics_solver(penny, ITERATIVE_FROM_UNKNOWNS_3D) == "direct"
    assert mechanics_solver(penny, ITERATIVE_FROM_UNKNOWNS_3D + 1) == "iterative"
    with Run(sneddon) as run:
        summary = run.execute()
    assert summary["linear_solver"].pop("time_preconditioner") > 0
    assert summary["dofs"] > 0 and summary["linear_solver"] == {
        "kind": "direct", "choice": "auto", "ksp_type": "preonly", "pc_type": "lu",
        "krylov_iterations": 0, "preconditioner_setups": 1}


@pytest.mark.parametrize(("threshold", "kind"), [(100_000, "direct"), (1_000, "iterative")])
def test_auto_decides_on_the_unknowns_of_the_mesh(monkeypatch, threshold, kind):
    """The coarse penny crack (about 5,000 unknowns) below and above the threshold."""
    monkeypatch.setattr(resources, "ITERATIVE_FROM_UNKNOWNS_3D", threshold)
    with Run(load_scene(PENNY, COARSE)) as run:
        summary = run.execute()
        modes = run.physics.solver.linear.near_nullspace_size
    assert 1_000 < summary["dofs"] < 100_000
    assert summary["linear_solver"]["kind"] == kind
    assert summary["linear_solver"]["choice"] == "auto"
    assert (summary["linear_solver"]["krylov_iterations"] > 0) == (kind == "iterative")
    assert modes == (6 if kind == "iterative" else 0)


def test_iterative_2d_matches_direct():
    """The 2D path of the iterative solver (3 rigid-body modes) gives MUMPS' solution."""
    out = {}
    for kind in ("direct", "iterative"):
        scene = load_scene(ROOT / "configs" / "sneddon.yaml",
                           ["mesh.size=0.5", f"solver.linear_solver={kind}"])
        with Run(scene) as run:
            summary = run.execute()
            out[kind] = run.physics.model.u.x.array.copy()
    assert summary["linear_solver"]["krylov_iterations"] > 0
    assert _relative(out["iterative"], out["direct"]) < 1e-8


def test_iterative_refused_for_multiplier_formulations():
    """Multipliers make a saddle-point system: ``iterative`` is refused, naming the key."""
    raw = mechanics_scene(contact__formulation="mixed", solver={"linear_solver": "iterative"})
    with pytest.raises(ConfigError, match=r"solver\.linear_solver.*'iterative'.*mixed"):
        scene_from_dict(raw)
    raw["contact"]["formulation"] = "nitsche"
    assert scene_from_dict(raw).solver.linear_solver == "iterative"


def test_p_multigrid_refused_without_p2():
    """``pc_type mg`` is the p-multigrid (P1 as the coarse level of P2): with P1 displacements
    it is refused before meshing, naming the key, the value and what to use."""
    raw = mechanics_scene(degree=1, solver={"linear_solver": "iterative",
                                            "petsc": {"pc_type": "mg"}})
    with pytest.raises(ConfigError, match=r"solver\.petsc\.pc_type.*'mg'.*degree 2, not 1"):
        scene_from_dict(raw)
    raw["degree"] = 2
    assert scene_from_dict(raw).solver.petsc["pc_type"] == "mg"


def test_krylov_failure_fails_the_run_with_its_reason(tmp_path):
    """Two CG iterations cannot reach the tolerance: status 3, the KSP reason and count said."""
    out = tmp_path / "fail"
    args = [a for o in COARSE for a in ("--set", o)]
    proc = subprocess.run(
        [sys.executable, "-m", "poromech", "run", str(PENNY), "-o", str(out), *args,
         "--set", "solver.linear_solver=iterative", "--set", "solver.petsc.ksp_max_it=2"],
        capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "DIVERGED_LINEAR_SOLVE" in proc.stderr
    assert "(cg + gamg) did not converge: DIVERGED_MAX_IT after 2 iterations" in proc.stderr
    assert "solver.linear_solver: direct solves it with MUMPS" in proc.stderr
    # the Krylov history, relative to the right-hand side: it starts at 1 and has not converged
    history = re.search(r"relative residual at iteration 0: ([0-9.e+-]+), 1: ([0-9.e+-]+), "
                        r"2: ([0-9.e+-]+)", proc.stderr)
    assert history, proc.stderr
    r0, _, r2 = map(float, history.groups())
    assert r0 == 1.0 and 1e-11 < r2 < 1.0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("failed") and "DIVERGED_MAX_IT" in summary["status"]
    assert ITERATIVE_OPTIONS["ksp_max_it"] > 2


#: A box cut in two by a tilted fracture plane, each piece clamped on its own face.
CUT = {
    "name": "cut",
    "geometry": {"domain": {"box": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]},
                 "fractures": [{"name": "A", "polygon": [[0.0, 0.0, 0.4], [1.0, 0.0, 0.6],
                                                         [1.0, 1.0, 0.6], [0.0, 1.0, 0.4]]}]},
    "mesh": {"size": 0.3, "fracture_size": 0.15},
    "degree": 2,
    "material": {"young": 1.0e9, "poisson": 0.25},
    "fracture_pressure": 1.0e5,
    "contact": {"formulation": "none"},
    "boundary_conditions": [{"boundary": "bottom", "displacement": [0.0, 0.0, 0.0]},
                            {"boundary": "top", "displacement": [0.0, 0.0, 0.0]}],
    "output": {"xdmf": False, "fractures_csv": False},
}


def test_iterative_on_a_body_cut_in_two_pieces():
    """Two pieces, one rigid-body near-nullspace for the whole body: GAMG's aggregates do not
    straddle the fracture, CG + GAMG gives MUMPS' solution in as few iterations as one piece."""
    u, its = {}, {}
    for kind in ("direct", "iterative"):
        raw = copy.deepcopy(CUT)
        raw["solver"] = {"linear_solver": kind}
        with Run(scene_from_dict(raw)) as run:
            summary = run.execute()
            u[kind] = run.physics.model.u.x.array.copy()
            its[kind] = summary["linear_solver"]["krylov_iterations"]
            pieces = run.mesh.pieces
    assert [edges for _, edges in pieces] == [(0, 1, 2, 3, 4), (0, 1, 2, 3, 5)]  # bottom, top
    assert MPI.COMM_WORLD.allreduce(run.mesh.msh.topology.index_map(3).size_local) == sum(
        cells for cells, _ in pieces)
    assert 10 <= its["iterative"] <= 60
    assert _relative(u["iterative"], u["direct"]) < 1e-8


def test_a_floating_piece_is_refused():
    """Open fractures and a piece without displacement condition: a one-line error naming the
    piece, before any assembly."""
    raw = copy.deepcopy(CUT)
    raw["boundary_conditions"][1] = {"boundary": "top", "traction": [0.0, 0.0, -1.0e5]}
    with pytest.raises(ConfigError) as info, Run(scene_from_dict(raw)) as run:
        run.execute()
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith("scene key 'boundary_conditions': the fractures cut the body "
                              "into 2 pieces and piece 2 of 2 (")
    assert "on back, front, left, right, top) has no displacement condition in xyz" in message


@pytest.mark.parametrize("formulation", ["nitsche", "mean_nitsche", "stabilized_mixed"])
def test_iterative_on_a_piece_held_only_by_contact(formulation):
    """The top piece of the cut box is pushed down onto the bottom one and sheared below the
    friction bound: only contact holds it (its rigid motions are penalized by β/h alone).
    GMRES with the p-multigrid of P2 converges (face unknowns eliminated for the facewise
    formulations), to the direct solution and states; every point in contact, sticking."""
    u, its, codes = {}, {}, {}
    for kind in ("direct", "iterative"):
        raw = copy.deepcopy(CUT)
        raw.pop("fracture_pressure")
        raw["contact"] = {"formulation": formulation, "theta": -1, "friction": "coulomb",
                          "friction_coefficient": 0.5}
        raw["boundary_conditions"][1] = {"boundary": "top", "traction": [1.0e5, 0.0, -1.0e6]}
        raw["solver"] = {"linear_solver": kind}
        with Run(scene_from_dict(raw)) as run:
            summary = run.execute()
            u[kind] = run.physics.model.u.x.array.copy()
            its[kind] = summary["linear_solver"]["krylov_iterations"]
            codes[kind] = run.physics.model.active_set()
            assert run.physics.solver.record.converged
    assert its["direct"] == 0 and 0 < its["iterative"] <= 400
    assert np.all(codes["iterative"] == 1) and np.array_equal(codes["iterative"], codes["direct"])
    assert _relative(u["iterative"], u["direct"]) < 1e-6


def test_a_piece_held_only_by_frictionless_contact_on_parallel_cuts_is_refused(caplog):
    """The top piece of the cut box on frictionless contact: nothing determines its slide along
    the cut, and the run wrote an arbitrary one (3 µm to 3.6 mm with the same loads, different
    on 2 ranks). Refused before solving, naming the free motions; with friction it runs (only
    contact holds it). The free motions of pieces cut out of a 2D mesh."""
    from poromech.errors import ConfigError
    from poromech.mechanics.physics import check_pieces
    from poromech.mesh.cracking import unblocked_motions
    from poromech.run import build_mesh

    for friction in ("frictionless", "tresca", "coulomb"):
        raw = copy.deepcopy(CUT)
        raw.pop("fracture_pressure")
        raw["contact"] = {"formulation": "nitsche", "friction": friction,
                          "friction_coefficient": 0.5}
        if friction == "tresca":  # a zero slip bound is frictionless (it ran 5 x 100 iterations)
            raw["contact"]["slip_bound"] = 0.0
        raw["boundary_conditions"][1] = {"boundary": "top", "traction": [1.0e5, 0.0, -1.0e6]}
        scene = scene_from_dict(raw)
        fm = build_mesh(scene, MPI.COMM_WORLD)
        # the cut is a plane: two slides and the turn about its normal are free
        assert fm.unblocked == (3, 3)
        caplog.clear()
        with caplog.at_level("WARNING", logger="poromech"):
            if friction != "coulomb":
                with pytest.raises(ConfigError, match="leaves 3 of its rigid motions free"):
                    check_pieces(scene, fm)
            else:
                # returned for the failure message of a Newton that does not converge
                assert check_pieces(scene, fm) == ["piece 2 of 2 (free in xyz)"]
                assert "only contact holds it; pointwise nitsche's Newton creeps" in caplog.text
    # 2D: a wedge cut out on two sides at an angle is held (no motion keeps the normal gaps at
    # the faces' ends); a piece with one straight cut face keeps the slide along it
    x = np.array([[0.0, 0.0], [2.0, 0.0], [1.0, 1.0], [0.0, 1.0], [2.0, 1.0], [1.0, -1.0]])
    cells = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2], [0, 5, 1]])
    assert unblocked_motions(cells, x, np.array([[0, 2], [1, 2]])) == (0, 1, 1)


def test_forcing_term_of_the_inexact_newton():
    """The Krylov tolerance: loose far from the solution, following the observed rate, never
    tighter than the options' nor than the Newton's tolerance needs (0.1 of its target)."""
    from poromech.mechanics.linear import FORCING_MAX, FORCING_SWITCHED, forcing_term

    assert forcing_term(1.0, None, 1e-10, 1e-11) == FORCING_MAX  # first iteration
    assert forcing_term(1e-2, 1.0, 1e-10, 1e-11) == pytest.approx(0.9e-4)  # γ (1e-2)²
    assert forcing_term(1e-6, 1e-2, 1e-10, 1e-11) == pytest.approx(1e-5)  # 0.1 target / |F|
    assert forcing_term(1e-6, 1e-2, 1e-20, 1e-11) == pytest.approx(0.9e-8)
    assert forcing_term(1e-6, 1e-2, 1e-30, 1e-7) == 1e-7  # the options' ksp_rtol
    assert forcing_term(1.0, 0.5, 1e-10, 1e-11) == FORCING_MAX  # slow progress: capped
    # within three decades of the target the margin loosens the solve beyond FORCING_MAX
    assert forcing_term(1e3, 1e7, 1e2, 1e-11) == pytest.approx(1e-2)
    assert forcing_term(1e3, None, 1e2, 1e-11) == pytest.approx(1e-2)
    # below the target (a step the Newton is made to take) it stays at FORCING_MAX
    assert forcing_term(50.0, None, 1e2, 1e-11) == FORCING_MAX
    # after a step that switched many contact points: bounded by FORCING_SWITCHED instead
    assert forcing_term(1.0, 0.5, 1e-10, 1e-11, switched=True) == FORCING_SWITCHED
    assert forcing_term(0.1, 1.0, 1e-10, 1e-11, switched=True) == pytest.approx(0.9e-2)
    assert forcing_term(1e-3, 1.0, 1e-10, 1e-11, switched=True) == pytest.approx(0.9e-6)
    assert forcing_term(1.0, None, 1e-10, 1e-11, switched=True) == FORCING_MAX  # first


def test_auto_hands_a_failed_krylov_solve_to_mumps(monkeypatch):
    """``auto``: the first Krylov solve that fails (here one CG iteration is allowed) hands the
    run to MUMPS LU, which then gives the direct solution; the switch is in the summary."""
    monkeypatch.setattr(resources, "ITERATIVE_FROM_UNKNOWNS_3D", 1_000)
    direct = penny_solution(MPI.COMM_WORLD, "solver.linear_solver=direct")
    out = penny_solution(MPI.COMM_WORLD, "solver.petsc.ksp_max_it=1")
    summary = out["summary"]
    assert summary["linear_solver"]["kind"] == "iterative"
    assert summary["linear_solver"]["fallback"] == "direct"
    assert summary["linear_solver"]["preconditioner_setups"] >= 2  # the GAMG set-up, then LU
    assert [w for w in summary["warnings"] if "the mechanics switches to MUMPS LU" in w]
    assert _relative(out["u"], direct["u"]) < 1e-10
    assert _relative(out["w"], direct["w"]) < 1e-10


def test_auto_keeps_a_krylov_failure_where_mumps_would_not_fit(monkeypatch):
    """Without the memory for the factorization the run fails with the Krylov method's reason,
    and says that LU was not tried; an explicit ``iterative`` never switches."""
    monkeypatch.setattr(resources, "ITERATIVE_FROM_UNKNOWNS_3D", 1_000)
    monkeypatch.setattr(resources, "available_memory", lambda comm: (1e6, "MemAvailable"))
    with pytest.raises(SolverError, match="DIVERGED_LINEAR_SOLVE"):
        penny_solution(MPI.COMM_WORLD, "solver.petsc.ksp_max_it=1")
    monkeypatch.undo()
    with pytest.raises(SolverError, match="DIVERGED_LINEAR_SOLVE"):
        penny_solution(MPI.COMM_WORLD, "solver.linear_solver=iterative",
                       "solver.petsc.ksp_max_it=1")
