"""The condensed solve of ``mixed`` (poromech/mechanics/condensed.py): the face problem is the
assembled one, and the condensed solution is the regular Newton's."""

import numpy as np
import pytest
from conftest import ROOT, sigterm_after_steps
from mpi4py import MPI

import poromech.mechanics.condensed as condensed
from poromech import stepping
from poromech.mechanics.physics import MechanicsPhysics
from poromech.run import Run, build_mesh, run_scene
from poromech.scene.loading import load_scene
from poromech.timing import Timer

comm = MPI.COMM_WORLD


def mixed_scene(name: str, *overrides: str):
    return load_scene(ROOT / "configs" / f"{name}.yaml", ["contact.formulation=mixed", *overrides])


def physics(name: str, *overrides: str) -> MechanicsPhysics:
    """The mechanics physics of a scene, set up and not solved (close it)."""
    scene = mixed_scene(name, *overrides)
    return MechanicsPhysics(scene, build_mesh(scene, comm), Timer())


def solved(name: str, *overrides: str) -> tuple[list[dict], list[np.ndarray], dict]:
    """Step records, final unknowns and summary of an in-memory run."""
    with Run(mixed_scene(name, *overrides)) as run:
        summary = run.execute()
        return summary["solves"], [f.x.array.copy() for f in run.physics.model.unknowns], summary


@pytest.mark.parametrize("friction", ["coulomb", "tresca", "frictionless"])
def test_face_residual_and_map_are_those_of_the_assembled_problem(friction):
    """At random multipliers and averages that put faces on every branch (open, stick, slip
    both ways), the face residual of the condensed problem equals the assembled multiplier rows;
    its Jacobian matches central differences; and ``G`` is the averages' response to ``λ``
    through a solve with the condensation matrix."""
    sets = ["contact.friction=" + friction, "time.steps=1"]
    if friction == "tresca":
        sets.append("contact.slip_bound=2.0e6")
    sim = physics("six_fractures_mechanics", *sets)
    c, s = sim.solver.condensed, sim.solver
    assert c is not None
    rng = np.random.default_rng(3)
    p = c.problem
    x = s.x.duplicate()
    x.setRandom()
    x.scale(1e-4)
    values = c.gather(x)
    if comm.rank == 0:  # realistic magnitudes: tractions ~ MPa, β a ~ tractions
        values[c.lam_pos] = rng.normal(0.0, 5e6, c.lam_pos.size)
        beta = np.empty(c.avg_pos.size)
        beta[p.an] = p.beta_n
        if p.at is not None:
            beta[p.at] = p.beta_t
        values[c.avg_pos] = rng.normal(0.0, 5e6, c.avg_pos.size) / beta
    c.scatter_faces(values, x)
    f = s.b.duplicate()
    s.snes.computeFunction(x, f)
    assembled = c.gather(f)
    coefficient, bound = c.law()
    if comm.rank == 0:
        lam, a = values[c.lam_pos], values[c.avg_pos]
        R, J = p.residual(lam, a, coefficient, bound, jacobian=True)
        assert np.allclose(R, assembled[c.lam_pos], rtol=1e-12, atol=1e-9 * np.abs(R).max())
        pn = -(lam[p.ln] + p.beta_n * a[p.an])
        assert 0 < np.count_nonzero(pn <= 0) < pn.size  # open and closed faces
        if p.lt is not None:
            pt = -(lam[p.lt] + p.beta_t * a[p.at])
            S = -coefficient * np.minimum(pn, 0.0) if friction == "coulomb" else bound
            assert np.any(np.abs(pt) < S) and np.any(pt > S) and np.any(pt < -S)
        d = rng.normal(0.0, 1.0, lam.size) * 1e-7 * np.abs(lam)  # small: no branch switches
        Rp = p.residual(lam + d, a + p.G @ d, coefficient, bound)[0]
        Rm = p.residual(lam - d, a - p.G @ d, coefficient, bound)[0]
        assert np.allclose(J @ d, (Rp - Rm) / 2, rtol=1e-5, atol=1e-6 * np.abs(J @ d).max())
    # G: the averages' response to a change of λ, J₀ y = (0, |σ| δλ, 0)
    step = rng.normal(0.0, 1e6, p.ln.size * (1 if p.lt is None else 2)) if comm.rank == 0 \
        else None
    response = c.response(step)
    if comm.rank == 0:
        assert np.allclose(response[c.lam_pos], step, rtol=1e-10)
        expected = p.G @ step
        assert np.allclose(response[c.avg_pos], expected, rtol=1e-8,
                           atol=1e-10 * np.abs(expected).max())
    sim.close()


def test_condensed_solution_is_the_regular_newtons():
    """The six-fracture mechanics scene in three steps: the condensed candidate passes the
    regular Newton's test at iteration 0 in every step (no factorization of the Jacobian), and
    the unknowns equal those of the regular Newton to its tolerance."""
    runs = {}
    for flag in (True, False):
        records, values, summary = solved("six_fractures_mechanics", "time.steps=3",
                                          f"solver.condensation={str(flag).lower()}")
        assert (summary["condensed"] is not None) == flag
        assert all(r["converged"] for r in records)
        runs[flag] = (records, values)
    cond, regular = runs[True][0], runs[False][0]
    assert [r["iterations"] for r in cond] == [0, 0, 0]
    assert all(r["factorizations"] == 0 for r in cond)
    # the first step switches faces; the next start from the extrapolated solution, exact here
    assert cond[0]["face_iterations"] > 0
    assert regular[0]["iterations"] > 1
    for a, b in zip(runs[True][1], runs[False][1], strict=True):
        scale = comm.allreduce(float(np.abs(b).max(initial=0.0)), op=MPI.MAX)
        err = comm.allreduce(float(np.abs(a - b).max(initial=0.0)), op=MPI.MAX)
        assert err <= 1e-8 * scale


def test_a_face_newton_that_fails_leaves_the_solve_to_the_regular_newton(monkeypatch):
    """No face iteration allowed: the candidate is dropped and the regular Newton solves from
    the original start, to the same solution as with condensation off."""
    monkeypatch.setattr(condensed, "MAX_IT", 0)
    (rec,), got, _ = solved("six_fractures_mechanics", "time.steps=1")
    (ref,), expected, _ = solved("six_fractures_mechanics", "time.steps=1",
                                 "solver.condensation=false")
    assert rec["converged"] and rec["iterations"] == ref["iterations"] > 0
    assert rec["face_iterations"] == 0
    for a, b in zip(got, expected, strict=True):
        assert np.array_equal(a, b)


@pytest.mark.parametrize("overrides, said", [
    (["degree=1"], None), (["contact.formulation=stabilized_mixed"], None),
    (["solver.petsc={ksp_type: gmres, pc_type: gamg}"], "the mechanics solver is gmres + gamg"),
    (["solver.petsc={pc_factor_mat_solver_type: superlu_dist}"],
     "the mechanics solver is superlu_dist")])
def test_condensation_is_used_only_where_it_applies(overrides, said, caplog):
    """Not with P1 (singular face problem), not for other formulations, not with an iterative
    mechanics solver or another factorization than MUMPS', which forms the face problem: those
    two are said in the log (the scene chose them; the formulation asked for the condensation)."""
    with caplog.at_level("INFO", logger="poromech"):
        sim = physics("six_fractures_mechanics", "time.steps=1", *overrides)
    assert sim.solver.condensed is None
    assert sim.describe()["condensed"] is None
    sim.close()
    lines = [r.getMessage() for r in caplog.records if "not condensed" in r.getMessage()]
    assert lines == ([] if said is None else [
        "the mixed contact problem is not condensed: its face problem is formed by a MUMPS "
        f"factorization, and {said}"])


def test_a_block_held_only_by_contact_is_solved_without_condensation(caplog):
    """A fault through the whole domain with no displacement condition above it: the elastic
    operator is singular, the condensation matrix cannot be factorized, the run warns and the
    regular Newton solves it (with MUMPS' null-pivot detection)."""
    from conftest import mechanics_scene

    from poromech.scene.loading import scene_from_dict

    raw = mechanics_scene(contact={"formulation": "mixed", "friction_coefficient": 0.5})
    raw["geometry"]["fractures"] = [{"name": "fault", "points": [[0.0, 0.5], [2.0, 0.5]]}]
    raw["boundary_conditions"] = [{"boundary": "bottom", "displacement": [0.0, 0.0]},
                                  {"boundary": "top", "traction": [0.0, -1.0e6]}]
    scene = scene_from_dict(raw)
    with caplog.at_level("WARNING", logger="poromech"), Run(scene) as run:
        summary = run.execute()
        tn = run.physics.model.face_fields()["traction_n"]
    assert summary["condensed"] is None
    assert "not condensed" in caplog.text
    assert summary["solves"][0]["converged"]
    assert np.all(tn < 0.0) and abs(tn.mean() + 1.0e6) < 1e-2 * 1.0e6  # it carries the load


def test_a_face_newton_stagnating_at_round_off_hands_its_result_to_the_regular_check(
        monkeypatch):
    """A face tolerance below round-off (a very large ``β^sm`` does that): the face Newton stops
    when it no longer decreases its residual, and its result, within the regular tolerance, is
    accepted by the regular Newton at iteration 0 instead of being thrown away."""
    monkeypatch.setattr(condensed, "SAFETY", 1e-30)
    (rec,), got, _ = solved("six_fractures_mechanics", "time.steps=1")
    assert rec["converged"] and rec["iterations"] == 0
    assert rec["face_iterations"] > condensed.MAX_WATCHDOG
    _, expected, _ = solved("six_fractures_mechanics", "time.steps=1", "solver.condensation=false")
    for a, b in zip(got, expected, strict=True):
        assert np.abs(a - b).max() <= 1e-8 * np.abs(b).max()


def test_a_restart_repeats_the_condensed_solves_bit_for_bit(tmp_path):
    """The coupled 2D fault scene stopped after its fourth step and continued: its fracture
    table equals the uninterrupted run's byte for byte. The face solves update a kept inverse
    by Woodbury from its base; a restart that inverted anew at its first solve differed by
    round-off (jump_n 7e-19 m, jump_t 3e-17 m): the checkpoint holds where the base was taken."""
    scene = mixed_scene("fault_reactivation", "time.final=12000", "time.steps=12")
    full = run_scene(scene, tmp_path / "full")

    with Run(scene, tmp_path / "part", prepare=sigterm_after_steps(4)) as run, \
            pytest.raises(stepping.Interrupted):
        run.execute()
    resumed = run_scene(scene, tmp_path / "part", restart=True)
    assert resumed["restarted_from"]["step"] == 4 and resumed["status"] == "converged"
    # the inverse is updated, not taken anew at every face iteration
    assert 0 < full["condensed"]["dense_inversions"] < sum(r["face_iterations"]
                                                           for r in full["solves"])
    assert [r["face_iterations"] for r in resumed["solves"]] == \
        [r["face_iterations"] for r in full["solves"]]
    table = [(d / "fractures.csv").read_bytes() for d in (tmp_path / "full", tmp_path / "part")]
    assert table[0] == table[1]
