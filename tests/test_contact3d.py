"""Contact in 3D: Nitsche formulations on penny cracks with known answers, 1 vs 2 ranks.

* Sneddon's pressurized penny is open everywhere: contact terms leave it as without contact
  (exactly for θ = 0, up to Nitsche's O(1/β) consistency term for θ = ±1).
* Segedin's penny under remote shear, closed by a normal compression: frictionless it slips
  parallel to the shear with a known profile; Tresca and Coulomb below the shear slip against a
  uniform friction traction (the same profile for the shear minus that traction); Coulomb above
  it sticks (no jump at all, the uniform far field is in the finite element space).
* A block held on a fault by friction alone (configs/sliding_block3d.yaml): the face tractions
  carry the whole load below the limit the friction cone sets, and beyond it the run fails
  saying which piece only contact holds.
"""

from __future__ import annotations

import csv

import dolfinx_solver  # noqa: F401

import numpy as np
import pytest
from conftest import ROOT, run_parallel
from dolfinx.fem.petsc import assemble_matrix

from poromech.forms.contact import ContactParameters
from poromech.run import Run, run_scene
from poromech.scene.loading import load_scene
from poromech.verification.jumps import exact_jump, face_quadrature, jump_errors, jump_values

PENNY = ROOT / "configs" / "penny.yaml"
SHEAR = ROOT / "configs" / "penny_shear.yaml"
#: A coarse penny (about 2k tetrahedra) for fast checks.
COARSE = ["mesh.size=2.5", "mesh.fracture_size=0.3", "mesh.tip_size=0.075",
          "mesh.transition=3", "output.xdmf=false"]
FINE = ["mesh.size=2.5", "mesh.fracture_size=0.15", "mesh.tip_size=0.0375",
        "mesh.transition=3", "output.xdmf=false"]
#: Coulomb with F = 0.25 under σ = 2 MPa: the crack slips under τ - Fσ = 0.5 MPa.
COULOMB_SLIP = ["contact.friction=coulomb", "contact.friction_coefficient=0.25"]
TRESCA_SLIP = ["contact.friction=tresca", "contact.slip_bound=5.0e5"]


def solve(path, overrides):
    """Errors against the scene's exact jump, jump values, active-set codes, Newton record."""
    scene = load_scene(path, overrides)
    with Run(scene) as run:
        run.execute()
        physics = run.physics
        err = jump_errors(physics.model.u, physics.fm, exact_jump(scene))
        jumps = jump_values(physics.model.u, face_quadrature(physics.fm, 3))
        codes = physics.model.active_set()
        record = physics.solver.record
        reuse = physics.solver.states_determine_jacobian
    assert record.converged, record.reason
    return {"err": err, "jumps": jumps, "codes": codes, "record": record, "reuse": reuse}


def written_states(path, overrides, tmp_path) -> set[str]:
    """The ``state`` words of ``fractures.csv``."""
    run_scene(load_scene(path, overrides), tmp_path)
    with open(tmp_path / "fractures.csv") as fh:
        return {r["state"] for r in csv.DictReader(fh)}


@pytest.mark.parametrize(("friction", "expected"), [("frictionless", True), ("tresca", False),
                                                     ("coulomb", False)])
def test_3d_friction_is_not_piecewise_affine(friction, expected):
    """With friction in 3D the Jacobian depends on the slip direction, not only on the states:
    Newton must assemble it at every iterate. In 2D it is a function of the states."""
    for dim, want in ((2, True), (3, expected)):
        p = ContactParameters("nitsche", friction, -1.0, 1.0, 1.0, dim=dim)
        assert p.piecewise_affine is want


def test_a_tresca_bound_varying_in_z_is_refused_naming_z():
    """It said the bound "must not depend on x or y" of a bound that depends on z only."""
    from poromech.errors import ConfigError

    with pytest.raises(ConfigError, match=r"'contact.slip_bound' = '1e5\*\(1 \+ z\)' is not "
                                          r"allowed: the Tresca slip bound must not depend on "
                                          r"x, y or z \(a number"):
        load_scene(SHEAR, ["contact.friction=tresca", "contact.slip_bound=1e5*(1 + z)"])


@pytest.mark.parametrize("degree", [1, 2])
def test_contact_points_are_the_quadrature_points(degree):
    """On triangles the active set is read at the points of the contact quadrature (one
    quadrature-element dof each): the point weights are positive and sum to each face's area,
    and every code is a valid one (Lagrange nodes are not Gauss points there: a P2 vertex
    function integrates to 0 on a triangle)."""
    scene = load_scene(SHEAR, COARSE + [f"degree={degree}"])
    with Run(scene) as run:
        run.execute()
        model = run.physics.model
        weights = model._point_weights[model._points.function_space.dofmap.list[
            :len(model.fm.fractures.facets)]]
        assert weights.shape[1] == {1: 3, 2: 6}[degree]
        assert np.all(weights > 0.0)
        np.testing.assert_allclose(weights.sum(axis=1), model.fm.fractures.measure, rtol=1e-12)
        assert set(np.unique(model.active_set())) <= {0, 1}


@pytest.mark.parametrize("formulation", ["nitsche", "mean_nitsche", "stabilized_mixed", "mixed"])
def test_pressurized_penny_stays_open(formulation, tmp_path):
    """Sneddon's penny with contact: all points open; θ = 0 (and mixed, whose multipliers
    vanish on open faces) gives the jump without contact to solver tolerance, θ = -1 within its
    O(1/β) consistency term."""
    none = solve(PENNY, COARSE)
    scale = np.max(np.abs(none["jumps"]))
    thetas = ((None, 1e-9),) if formulation == "mixed" else ((0, 1e-9), (-1, 5e-3))
    for theta, tol in thetas:
        sets = COARSE + [f"contact.formulation={formulation}", "contact.friction=coulomb"]
        sets += [f"contact.theta={theta}"] if theta is not None else []
        out = solve(PENNY, sets)
        assert np.max(np.abs(out["jumps"] - none["jumps"])) < tol * scale
        assert np.all(out["codes"] == 0)  # open, and no friction on open points
    assert written_states(PENNY, sets, tmp_path) == {"open"}


def test_segedin_slip_converges():
    """Frictionless penny under shear (P2): slip parallel to τ, no opening, error falls."""
    coarse, fine = solve(SHEAR, COARSE), solve(SHEAR, FINE)
    assert coarse["err"]["l2"] < 0.095 and fine["err"]["l2"] < 0.055
    assert np.log2(coarse["err"]["l2"] / fine["err"]["l2"]) > 0.6
    for out in (coarse, fine):
        assert out["err"]["l2_n"] < 1e-3  # closed: [[u]]_n ≈ 0 (β_n large)
        assert np.all(out["codes"] == 1)  # in contact
        # frictionless in contact: one linear solve; a Krylov solve (the fine mesh) is inexact
        # at first (poromech.mechanics.linear.forcing_term): one more
        krylov = out["record"].linear_iterations > 0
        assert out["record"].iterations == (2 if krylov else 1)


def test_segedin_slip_is_parallel_to_the_shear():
    """The component of the slip across τ is small against the slip."""
    scene = load_scene(SHEAR, FINE)
    phi = scene.parameters["phi"]
    with Run(scene) as run:
        run.execute()
        q = face_quadrature(run.physics.fm, 3)
        jumps = jump_values(run.physics.model.u, q)
    shear = np.array([np.cos(phi), np.sin(phi), 0.0])
    along = jumps @ shear
    across = jumps @ np.cross([0.0, 0.0, 1.0], shear)
    norm = np.sqrt(np.sum(q.weights * along**2))
    assert np.sqrt(np.sum(q.weights * across**2)) < 0.02 * norm


@pytest.mark.parametrize("degree", [1, 2])
@pytest.mark.parametrize("formulation", ["mean_nitsche", "stabilized_mixed", "mixed"])
def test_facewise_formulations_slip_like_nitsche(formulation, degree):
    """The facewise formulations on the sheared penny: the error of pointwise Nitsche (the
    slip error is the displacement space's), closed, every face in contact after one linear
    solve; mixed P1 is not inf-sup stable: its displacement is right, but its multipliers (and
    with them the face states) are not unique."""
    deg = [f"degree={degree}"]
    mean = solve(SHEAR, COARSE + deg + [f"contact.formulation={formulation}"])
    point = solve(SHEAR, COARSE + deg)
    assert mean["err"]["l2"] == pytest.approx(point["err"]["l2"], rel=0.01)
    assert mean["err"]["l2_n"] < 2e-3
    if not (formulation == "mixed" and degree == 1):  # P1: the multipliers are not unique
        assert np.all(mean["codes"] == 1)
        assert mean["record"].iterations <= 1


@pytest.mark.parametrize("law", [COULOMB_SLIP, TRESCA_SLIP], ids=["coulomb", "tresca"])
def test_friction_below_the_shear_slips(law, tmp_path):
    """Coulomb F = 0.25 (Fσ = 0.5 MPa) and Tresca s = 0.5 MPa under τ = 1 MPa: the slip of
    τ - 0.5 MPa, every point slipping; the Jacobian is assembled at every iterate."""
    out = solve(SHEAR, COARSE + law)
    assert out["err"]["l2"] < 0.095 and out["err"]["l2_n"] < 1e-3
    for formulation in ("mean_nitsche", "stabilized_mixed", "mixed"):
        facewise = solve(SHEAR, COARSE + law + [f"contact.formulation={formulation}"])
        assert facewise["err"]["l2"] == pytest.approx(out["err"]["l2"], rel=0.02)
        assert facewise["record"].iterations <= 6 and np.all(facewise["codes"] == 3)
    assert out["err"]["norm"] == pytest.approx(0.5 * solve(SHEAR, COARSE)["err"]["norm"])
    assert not out["reuse"] and out["record"].jacobian_reuses == 0
    assert out["record"].iterations <= 6
    assert np.all(out["codes"] == 3)  # in contact (1) + slip (2)
    assert written_states(SHEAR, COARSE + law, tmp_path) == {"slip"}


def test_coulomb_above_the_shear_sticks(tmp_path):
    """F = 1 > τ/σ = 0.5: the crack sticks and the uniform far field is the exact solution."""
    sets = COARSE + ["contact.friction=coulomb", "contact.friction_coefficient=1.0"]
    out = solve(SHEAR, sets)
    slip = solve(SHEAR, COARSE)["jumps"]
    assert np.max(np.abs(out["jumps"])) < 1e-8 * np.max(np.abs(slip))
    assert np.all(out["codes"] == 1)  # in contact, stick
    assert written_states(SHEAR, sets, tmp_path) == {"stick"}


#: configs/sliding_block3d.yaml: the upper block of a box cut through by a fault of slope 0.2
#: is held by nothing but Coulomb friction (F = 0.6) under a top traction (a t, 0, -σ).
BLOCK = ROOT / "configs" / "sliding_block3d.yaml"
#: The shear the block holds at most: the resultant (a, 0, -σ) on the fault leaves the friction
#: cone, (a - sσ)/(s a + σ) = F with s = 0.2, at a = σ (F + s)/(1 - F s).
BLOCK_LIMIT = 1.0e6 * (0.6 + 0.2) / (1.0 - 0.6 * 0.2)


def block_scene(a, formulation):
    """The block scene loaded in one step from rest to the shear traction ``a`` (Pa)."""
    return load_scene(BLOCK, [f"parameters.a={a!r}", f"contact.formulation={formulation}",
                              "time.final=1.0", "time.steps=1", "time.max_cuts=0",
                              "output.xdmf=false"])


@pytest.mark.parametrize("formulation", ["nitsche", "mean_nitsche"])
def test_a_block_held_by_friction_balances_the_load_up_to_its_limit(formulation, monkeypatch):
    """Below the limit the written face tractions carry the whole load (to rounding: the
    contact residual tested with a translation of the block is their sum); beyond it there is
    no equilibrium, and the failure says which piece only contact holds."""
    from poromech.errors import SolverError
    from poromech.mechanics.physics import MechanicsPhysics

    a = 0.5 * BLOCK_LIMIT
    forces = []
    accept = MechanicsPhysics.accept

    def balance(physics, t):  # the written (not yet accepted) face tractions
        v, faces = physics.model.face_fields(), physics.fm.fractures
        traction = v["traction_n"][:, None] * faces.normal + np.column_stack(
            [v[f"traction_t{c}"] for c in "xyz"])
        forces.append((traction * faces.measure[:, None]).sum(axis=0))
        states = set(physics.model.states(v).tolist())
        assert states >= {1, 2}  # stick and slip on the fault
        accept(physics, t)

    monkeypatch.setattr(MechanicsPhysics, "accept", balance)
    with Run(block_scene(a, formulation)) as run:
        run.execute()
    assert np.allclose(forces[-1], [a, 0.0, -1.0e6], rtol=0.0, atol=1e-6)
    with pytest.raises(SolverError) as failed:
        with Run(block_scene(1.1 * BLOCK_LIMIT, formulation)) as run:
            run.execute()
    assert "only contact holds piece 2 of 2 (free in xyz)" in str(failed.value)


def test_symmetric_nitsche_with_friction_in_3d():
    """θ = 1 with Coulomb friction in 3D: its coercivity ratio (tangential traction in the face
    plane) is computed, and the crack slips as with θ = -1."""
    sets = COARSE + COULOMB_SLIP
    scene = load_scene(SHEAR, sets + ["contact.theta=1"])
    with Run(scene) as run:
        run.execute()
        model = run.physics.model
        err = jump_errors(model.u, run.physics.fm, exact_jump(scene))
        assert 0.0 < model.coercivity_ratio < 1.0
        assert np.all(model.active_set() == 3)
    assert err["l2"] == pytest.approx(solve(SHEAR, sets)["err"]["l2"], rel=0.02)


def test_coulomb_jacobian_at_rest_is_finite():
    """At rest ``P_τ = 0``: the ball projection takes its stick branch (``|P_τ| <= S``), and
    ``P_τ/|P_τ|`` of the other branch never reaches the Jacobian (no regularization)."""
    scene = load_scene(SHEAR, COARSE + COULOMB_SLIP)
    with Run(scene) as run:
        run.execute()
        model = run.physics.model
        model.u.x.array[:] = 0.0
        A = assemble_matrix(model.J[0][0])
        A.assemble()
        assert np.isfinite(A.norm()) and A.norm() > 0.0
        A.destroy()


def two_ranks(path, overrides) -> dict:
    """Jump errors of a scene on 2 ranks, with the Newton and Krylov iterations."""
    code = f"""
import json
import dolfinx_solver
from mpi4py import MPI
from poromech.run import Run
from poromech.scene.loading import load_scene
from poromech.verification.jumps import exact_jump, jump_errors
scene = load_scene({str(path)!r}, {overrides!r})
with Run(scene) as run:
    run.execute()
    err = jump_errors(run.physics.model.u, run.physics.fm, exact_jump(scene))
    err["iterations"] = run.physics.solver.record.iterations
    err["krylov"] = run.physics.solver.record.linear_iterations
if MPI.COMM_WORLD.rank == 0:
    print(json.dumps(err))
"""
    return run_parallel(code)


@pytest.mark.mpi
@pytest.mark.parametrize("formulation", ["nitsche", "mixed"])
def test_segedin_on_two_ranks_equals_one_rank(formulation):
    sets = COARSE + COULOMB_SLIP + [f"contact.formulation={formulation}"]
    two = two_ranks(SHEAR, sets)
    one = solve(SHEAR, sets)
    for key in ("l2", "l2_n", "l2_t", "max"):
        assert two[key] == pytest.approx(one["err"][key], rel=1e-8, abs=1e-12)
    assert two["iterations"] == one["record"].iterations


@pytest.mark.mpi
def test_face_elimination_on_two_ranks_equals_one_rank():
    """stabilized_mixed with GMRES + GAMG on the displacement Schur complement (multipliers and
    averages eliminated face by face, on the rank owning the face) gives the same slip on 2 ranks
    as on 1 and as MUMPS, to the inexact Newton's tolerance."""
    sets = COARSE + COULOMB_SLIP + ["contact.formulation=stabilized_mixed"]
    iterative = sets + ["solver.linear_solver=iterative"]
    two = two_ranks(SHEAR, iterative)
    one, direct = solve(SHEAR, iterative), solve(SHEAR, sets)
    assert two["krylov"] > 0 and one["record"].linear_iterations > 0
    for key in ("l2", "l2_t", "max"):
        assert two[key] == pytest.approx(one["err"][key], rel=1e-6)
        assert one["err"][key] == pytest.approx(direct["err"][key], rel=1e-6)


#: GAMG on the P2 Jacobian instead of the p-multigrid (the smoother choice is GAMG's).
GAMG_ON_P2 = "solver.petsc={pc_type: gamg}"


def level_smoothers(physics) -> set[str]:
    """The PC types of GAMG's level smoothers in the mechanics KSP."""
    pc = physics.solver.snes.getKSP().getPC()
    return {pc.getMGSmoother(k).getPC().getType() for k in range(1, pc.getMGLevels())}


@pytest.mark.parametrize(("cost", "kept"), [(1e-6, "jacobi"), (1e6, "sor")])
def test_the_level_smoother_is_chosen_at_a_set_up(monkeypatch, cost, kept):
    """GMRES + GAMG on a contact Jacobian without a smoother in the options: at a set-up the
    system is solved with the current smoother (SOR at first), then with the other one within
    the iterations at which it costs less (JACOBI_COST, SWITCH_GAIN); the kept smoother is the
    one GAMG's levels run (through the later set-ups too), and the slip is MUMPS'."""
    import poromech.mechanics.linear as linear

    monkeypatch.setattr(linear, "JACOBI_COST", cost)
    sets = COARSE + COULOMB_SLIP + ["contact.formulation=nitsche"]
    scene = load_scene(SHEAR, sets + ["solver.linear_solver=iterative", GAMG_ON_P2])
    with Run(scene) as run:
        run.execute()
        physics = run.physics
        assert physics.solver.record.converged
        assert physics.solver.linear.smoother == kept
        assert level_smoothers(physics) == {kept}
        err = jump_errors(physics.model.u, physics.fm, exact_jump(scene))
    direct = solve(SHEAR, sets)
    for key in ("l2", "l2_t", "max"):
        assert err[key] == pytest.approx(direct["err"][key], rel=1e-6)


def test_lost_smoother_trials_make_the_next_ones_rarer(monkeypatch):
    """A set-up at every Newton iteration (``solver.reuse_jacobian: false``) and trials that
    cannot win (Jacobi given an eighth of SOR's iterations): after the k-th lost trial in a
    row the next TRIAL_BACKOFF**k - 1 set-ups keep SOR without a trial, and the slip is
    MUMPS'. Tried at every set-up, the trials would be as many as the set-ups."""
    import poromech.mechanics.linear as linear

    monkeypatch.setattr(linear, "SWITCH_GAIN", 20.0)
    monkeypatch.setattr(linear, "TRIAL_BACKOFF", 2)
    set_ups, trials = [], []  # set-ups of the Jacobians; the set-up each trial follows
    set_up = linear.IterativeSolver._set_up

    def counted_set_up(self, record, rebuild=False):
        if not rebuild:
            set_ups.append(len(set_ups))
        elif self.smoother == "jacobi":  # a trial's preconditioner (SOR's rebuild follows)
            trials.append(len(set_ups) - 1)
        return set_up(self, record, rebuild)

    monkeypatch.setattr(linear.IterativeSolver, "_set_up", counted_set_up)
    sets = COARSE + COULOMB_SLIP + ["contact.formulation=nitsche"]
    scene = load_scene(SHEAR, sets + ["solver.linear_solver=iterative", GAMG_ON_P2,
                                      "solver.reuse_jacobian=false"])
    with Run(scene) as run:
        run.execute()
        physics = run.physics
        assert physics.solver.record.converged
        assert physics.solver.linear.smoother == "sor"
        assert level_smoothers(physics) == {"sor"}  # SOR's preconditioner built again
        # each lost trial: its set-up and SOR's again
        assert physics.linear_totals["preconditioner_setups"] == len(set_ups) + 2 * len(trials)
        err = jump_errors(physics.model.u, physics.fm, exact_jump(scene))
    assert len(set_ups) >= 4
    # trials after set-ups 0, 2 (1 skipped), 6 (3 skipped), 14 (7 skipped), ...
    assert trials == [k for k in (0, 2, 6, 14, 30, 62) if k < len(set_ups)]
    direct = solve(SHEAR, sets)
    for key in ("l2", "l2_t", "max"):
        assert err[key] == pytest.approx(direct["err"][key], rel=1e-6)


def test_a_level_smoother_in_the_options_is_not_chosen():
    scene = load_scene(SHEAR, COARSE + COULOMB_SLIP + [
        "solver.linear_solver=iterative", "solver.petsc={pc_type: gamg, mg_levels_pc_type: sor}"])
    with Run(scene) as run:
        run.execute()
        assert run.physics.solver.linear.smoother is None
        assert level_smoothers(run.physics) == {"sor"}


@pytest.mark.parametrize(("formulation", "degree", "said"), [("mixed", 2, True),
                                                             ("stabilized_mixed", 2, False),
                                                             ("mixed", 1, False)])
def test_the_log_says_no_condensation_only_where_it_would_apply(formulation, degree, said,
                                                                caplog):
    """"The mixed contact problem is not condensed in 3D" was logged for ``stabilized_mixed`` and
    for ``mixed`` P1 too, which are never condensed (in 2D either)."""
    import logging

    caplog.set_level(logging.INFO, logger="poromech")
    scene = load_scene(PENNY, [*COARSE, f"contact.formulation={formulation}",
                               f"degree={degree}"])
    with Run(scene) as run:
        assert run.execute()["status"] == "converged"
    assert ("is not condensed in 3D" in caplog.text) == said
