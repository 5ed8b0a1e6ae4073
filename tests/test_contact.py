"""Contact formulations against exact solutions: Sneddon and the inclined frictional crack.

Thresholds are the measured errors with a 10% margin (docs/verification.md has the full study);
rates are checked over two refinements. The tip singularity limits every method to L² rate 1.
"""

import numpy as np
import pytest
from conftest import ROOT
from mpi4py import MPI

from poromech.run import Run, build_mesh
from poromech.scene.loading import load_scene
from poromech.verification.jumps import exact_jump, jump_errors

comm = MPI.COMM_WORLD
FORMULATIONS = ["nitsche", "mean_nitsche", "stabilized_mixed", "mixed"]


def solve(name: str, *overrides: str):
    """Scene, mesh, physics (its solver freed, its model kept) and step records of a run."""
    scene = load_scene(ROOT / "configs" / f"{name}.yaml", list(overrides))
    with Run(scene) as run:
        records = run.execute()["solves"]
        return scene, run.mesh, run.physics, records


def errors(name: str, *overrides: str):
    scene, fm, sim, records = solve(name, *overrides)
    err = jump_errors(sim.model.u, fm, exact_jump(scene))
    return err, sim.model.face_fields(), sim, records


def four(values: dict) -> np.ndarray:
    """Jumps and tractions of the owned faces, ``(faces, 4)``."""
    return np.column_stack([values[k] for k in ("jump_n", "jump_t", "traction_n", "traction_t")])


def rate(e0: float, e1: float) -> float:
    return float(np.log2(e0 / e1))


@pytest.mark.parametrize(("degree", "bounds"), [(1, (2.9e-2, 1.42e-2, 6.9e-3)),
                                                (2, (7.7e-3, 3.9e-3, 2.05e-3))])
def test_sneddon_opening(degree, bounds):
    errs = [errors("sneddon", f"degree={degree}", f"mesh.refinement={m}")[0] for m in range(3)]
    for e, bound in zip(errs, bounds, strict=False):
        assert e["l2"] < bound
        assert e["l2_t"] < 0.15 * e["l2"]  # no spurious sliding of the open crack
    assert rate(errs[1]["l2"], errs[2]["l2"]) > 0.9
    assert rate(errs[1]["max"], errs[2]["max"]) > 0.45  # √ singularity at the tips


#: Nitsche parameters of the Sneddon crack with contact switched on (100 E).
SNEDDON_BETA = ("contact.beta_n=1e12", "contact.beta_t=1e12")


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_sneddon_fully_open_with_contact(formulation):
    """With contact switched on, the pressurized crack stays open and the answer is unchanged."""
    ref, *_ = errors("sneddon")
    err, values, sim, _ = errors("sneddon", f"contact.formulation={formulation}",
                                 *SNEDDON_BETA)
    assert abs(err["l2"] - ref["l2"]) < 0.01 * ref["l2"]
    states = sim.model.states(values)
    assert comm.allreduce(int(np.count_nonzero(states)), op=MPI.SUM) == 0


@pytest.mark.slow
@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_inclined_crack_slip(formulation):
    """The whole crack slips; slip converges at rate ≈ 1; normal jump and traction are exact."""
    scene = load_scene(ROOT / "configs" / "inclined_crack_slip.yaml")
    p = scene.parameters
    tn_exact = -p["sigma"] * np.sin(p["psi"]) ** 2
    errs = []
    for m in (0, 1):
        err, values, sim, _ = errors("inclined_crack_slip", f"contact.formulation={formulation}",
                                     f"mesh.refinement={m}")
        errs.append(err)
        assert err["l2_n"] < 0.02 * err["l2"]
        inner = np.abs(sim.model.fm.fractures.s - p["b"]) < 0.8 * p["b"]
        assert np.all(sim.model.states(values)[inner] == 2)  # tip faces may differ
        assert np.allclose(values["traction_n"][inner], tn_exact, rtol=0.02)
        assert np.allclose(np.abs(values["traction_t"][inner]), p["F"] * abs(tn_exact), rtol=0.02)
    assert errs[0]["l2"] < 1.1e-2 and errs[1]["l2"] < 5.5e-3
    assert 0.85 < rate(errs[0]["l2"], errs[1]["l2"]) < 1.2


@pytest.mark.parametrize("formulation", FORMULATIONS)
@pytest.mark.parametrize("degree", [1, 2])
def test_inclined_crack_stick_is_exact(formulation, degree):
    """In the stick regime the exact field is affine: every method reproduces it to round-off."""
    err, values, sim, _ = errors("inclined_crack_stick", f"contact.formulation={formulation}",
                                 f"degree={degree}")
    slip_scale = 4 * (1 - 0.25**2) / 1e10 * 1e7  # m, the slip of a released crack
    assert err["max"] < 1e-9 * slip_scale  # absolute: the exact jump is zero
    if not (formulation == "mixed" and degree == 1):  # P1-P0: multipliers are not unique
        assert np.all(sim.model.states(values) == 1)


@pytest.mark.parametrize("formulation", ["nitsche", "mixed"])
def test_inclined_crack_frictionless(formulation):
    err, values, *_ = errors("inclined_crack_frictionless", f"contact.formulation={formulation}")
    assert err["l2"] < 1.06e-2
    assert err["l2_n"] < 0.02 * err["l2"]
    assert np.allclose(values["traction_t"], 0.0, atol=1e-6 * np.abs(values["traction_n"]).max())


@pytest.mark.parametrize("degree", [1, 2])
def test_stabilized_mixed_equals_mean_nitsche(degree):
    """Eliminating the multipliers of (5) gives (7): the two must agree to solver tolerance."""
    a = four(errors("inclined_crack_slip", "contact.formulation=stabilized_mixed",
                    f"degree={degree}")[1])
    b = four(errors("inclined_crack_slip", "contact.formulation=mean_nitsche",
                    f"degree={degree}")[1])
    scale = np.abs(a).max(axis=0)
    assert np.all(np.abs(a - b).max(axis=0) <= 1e-8 * scale)


@pytest.mark.parametrize("theta", [-1, 0, 1])
def test_nitsche_theta_variants(theta):
    ref, *_ = errors("inclined_crack_slip")
    err, _, _, records = errors("inclined_crack_slip", f"contact.theta={theta}")
    assert abs(err["l2"] - ref["l2"]) < 0.05 * ref["l2"]
    assert records[-1]["converged"]


def test_tresca_with_the_coulomb_bound_reproduces_coulomb():
    """A Tresca bound s = F |t_N| (t_N uniform in the exact solution) gives the Coulomb slip up
    to the discretization error of the normal traction (< 1%)."""
    scene = load_scene(ROOT / "configs" / "inclined_crack_slip.yaml")
    p = scene.parameters
    s = float(p["F"] * p["sigma"] * np.sin(p["psi"]) ** 2)
    e_coulomb, coulomb, *_ = errors("inclined_crack_slip")
    e_tresca, tresca, *_ = errors("inclined_crack_slip", "contact.friction=tresca",
                                  f"contact.slip_bound={s!r}")
    slip = np.abs(coulomb["jump_t"]).max()
    assert np.abs(tresca["jump_t"] - coulomb["jump_t"]).max() < 0.01 * slip
    assert abs(e_tresca["l2"] - e_coulomb["l2"]) < 0.05 * e_coulomb["l2"]


def test_only_what_is_needed_is_built():
    """Nitsche: u only. Mixed: λ (2) and jump averages. Frictionless: no tangential unknowns.
    Open pressurized crack: a linear problem without contact terms."""
    _, _, sim, _ = solve("inclined_crack_slip")
    assert [f.name for f in sim.model.unknowns] == ["u"]
    _, _, sim, _ = solve("inclined_crack_slip", "contact.formulation=mixed")
    names = [f.name for f in sim.model.unknowns]
    assert names == ["u", "lambda", "averages"]
    assert sim.model.lam.function_space.dofmap.index_map_bs == 2
    _, _, sim, _ = solve("inclined_crack_frictionless", "contact.formulation=mixed")
    assert sim.model.lam.function_space.dofmap.index_map_bs == 1
    assert sim.model.avg.function_space.dofmap.index_map_bs == 1
    _, _, sim, records = solve("sneddon")
    assert sim.model.linear and [f.name for f in sim.model.unknowns] == ["u"]
    assert records[0]["iterations"] == 1


# -- contact states (issue 7 §2) ----------------------------------------------------------------
@pytest.mark.parametrize("formulation", ["nitsche", "mixed"])
def test_closed_frictionless_faces_slip(formulation):
    """Without friction a closed face slides: its state is slip, never stick."""
    _, values, sim, _ = errors("inclined_crack_frictionless", f"contact.formulation={formulation}")
    states = sim.model.states(values)
    closed = values["traction_n"] < 0
    assert closed.sum() > 0.9 * len(closed)
    assert np.all(states[closed] == 2) and not np.any(states == 1)


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_states_agree_with_the_written_face_means(formulation):
    """Open exactly where the written traction_n is zero; slip exactly where the written
    tractions are on the Coulomb cone. The slipping crack is closed everywhere, tips included."""
    scene, _, sim, _ = solve("inclined_crack_slip", f"contact.formulation={formulation}")
    values = sim.model.face_fields()
    states = sim.model.states(values)
    tn, tt = values["traction_n"], values["traction_t"]
    assert np.array_equal(states == 0, tn >= 0)
    closed = tn < 0
    on_cone = np.abs(tt) >= (1 - 1e-6) * scene.contact.friction_coefficient * np.abs(tn)
    assert np.array_equal(states[closed] == 2, on_cone[closed])
    assert np.all(states > 0)


def test_readme_defines_contact_states():
    """README: the state definition, and codes in fractures.xdmf against words in fractures.csv."""
    from poromech.mechanics.model import STATE_NAMES

    text = (ROOT / "README.md").read_text()
    assert "**Contact states.**" in text
    paragraph = text.split("**Contact states.**")[1].split("\n\n")[0]
    assert "fractures.xdmf" in paragraph and "fractures.csv" in paragraph
    for code, name in enumerate(STATE_NAMES):
        assert f"`{code}`/`{name}`" in paragraph


def test_face_means_use_the_contact_quadrature():
    """Face fields are integrated with the Gauss points of the contact terms: the contact
    fraction of a face is a multiple of the Gauss weights (P2: 5/18, 8/18, 5/18)."""
    fraction = errors("inclined_crack_slip", "mesh.refinement=0")[1]["contact_fraction"]
    weights = np.array([5, 8, 5]) / 18
    sums = {round(float(np.dot(weights, c)), 12) for c in np.ndindex(2, 2, 2)}
    assert {round(float(f), 12) for f in fraction} <= sums
    assert np.any((fraction > 0) & (fraction < 1))  # a tip face partly in contact


# -- Nitsche parameters (issue 7 §3) ------------------------------------------------------------
def model_of(name: str, *overrides: str):
    from poromech.mechanics.model import MechanicsModel

    scene = load_scene(ROOT / "configs" / f"{name}.yaml", list(overrides))
    fm = build_mesh(scene, comm)
    return scene, fm, MechanicsModel(fm, scene)


def test_beta_defaults_are_relative_to_the_largest_young_modulus():
    """β_n⁰ = 250 E_max, β_τ⁰ = 10 E_max by default (E_max over the cells); absolute values
    given in the scene are kept."""
    import dolfinx

    scene, fm, model = model_of("inclined_crack_slip", "contact.beta_n=null",
                                "contact.beta_t=null", "material.young=E*(2 + x)")
    msh = fm.msh
    n = msh.topology.index_map(2).size_local
    x = dolfinx.mesh.compute_midpoints(msh, 2, np.arange(n, dtype=np.int32))
    e_max = comm.allreduce(float((1e10 * (2 + x[:, 0])).max()), op=MPI.MAX)
    assert model.young_max == pytest.approx(e_max, rel=1e-12)
    assert model.beta0 == pytest.approx((250 * e_max, 10 * e_max), rel=1e-12)
    _, _, model = model_of("inclined_crack_slip", "contact.beta_n=3e11", "contact.beta_t=null")
    assert model.beta0 == pytest.approx((3e11, 1e11), rel=1e-12)


def test_default_beta_far_stiffer_than_the_rock_at_a_fracture_is_reported(caplog):
    """β⁰ defaults to multiples of the largest Young's modulus: a fracture in rock 1000 times
    softer stalled the Newton (100 iterations), silently. Warned from a ratio of 30 on, when a
    β⁰ is left to its default; not for a homogeneous rock nor with β⁰ given, nor for a crack
    along an interface with the stiffest rock (it was, and the advised ``beta_scaling: local``,
    which scales by the stiffer side, changed nothing)."""
    from poromech.mechanics.model import SOFT_CONTRAST

    soft = f"material.young=where(y > 1.5, 1e10, {1e10 / (1.5 * SOFT_CONTRAST)})"
    interface = (f"material.young=where(x * cos(psi) - y * sin(psi) > 0, 1e10, "
                 f"{1e10 / (1.5 * SOFT_CONTRAST)})")
    default = ["contact.beta_n=null", "contact.beta_t=null"]
    for sets, warned in (([soft, *default], True), (default, False), ([soft], False),
                         ([interface, *default], False)):
        caplog.clear()
        with caplog.at_level("WARNING", logger="poromech"):
            _, _, model = model_of("inclined_crack_slip", *sets)
        said = [m for m in model.warnings if "times softer than the largest" in m]
        assert len(said) == int(warned), sets
        assert ("times softer" in caplog.text) == warned


def test_a_beta_outside_the_verified_range_is_reported():
    """β_τ⁰ = 1e-4 E with θ = -1 converged on the inclined crack with 15 of its 26 sliding faces
    called stick, and 1e8 E stalled at round-off, both without a word. Warned outside
    0.1 E to 1e6 E; not the scene's 100 E, nor β_t under frictionless contact."""
    cases = ((["contact.beta_t=1e6"], ["contact.beta_t = 1e+06 Pa is 0.0001 times"]),
             (["contact.beta_n=1e18"], ["contact.beta_n = 1e+18 Pa is 1e+08 times",
                                         "round-off grows with beta"]),
             ([], []),
             (["contact.friction=frictionless", "contact.beta_t=1e6"], []))
    for sets, fragments in cases:
        _, _, model = model_of("inclined_crack_slip", *sets)
        said = [m for m in model.warnings if "docs/mechanics.md verifies" in m]
        assert len(said) == (1 if fragments else 0), (sets, model.warnings)
        for fragment in fragments:
            assert fragment in said[0], said


def face_beta_n(model, fm) -> float:
    """The mean of ``β_n h_σ`` over the fracture faces (Pa): ``β_n⁰`` where it is uniform."""
    from dolfinx import fem

    from poromech.mesh.fractured import FRACTURE_TAG, face_size, fracture_measure

    dG = fracture_measure(fm)(FRACTURE_TAG)
    h = face_size(fm.msh)("+")
    total = fem.assemble_scalar(fem.form(model.params.beta_n * h * dG))
    area = fem.assemble_scalar(fem.form(1.0 * dG))
    return comm.allreduce(total, op=MPI.SUM) / comm.allreduce(area, op=MPI.SUM)


def test_local_beta_scaling_takes_the_modulus_of_the_rock_at_each_face():
    """The crack lies in rock of 1e8 Pa under rock of 1e11 Pa (y > 1.5). ``largest``: its faces
    take β_n⁰ = 250 E_max; ``local``: 250 E_σ = 250 × 1e8 Pa, no soft-rock warning, and the
    run gives the jumps and tractions of ``largest`` with β⁰ given as 250 and 10 × 1e8 Pa (the
    same discretization) to round-off, while the default β⁰ of ``largest`` gives others. With
    θ = 1 its coercivity ratio is that of a homogeneous 1e8 Pa rock."""
    soft = ["material.young=where(y > 1.5, 1e11, 1e8)", "contact.beta_n=null",
            "contact.beta_t=null"]
    _, fm, model = model_of("inclined_crack_slip", *soft)
    assert face_beta_n(model, fm) == pytest.approx(250 * 1e11, rel=1e-12)
    assert any("times softer" in m for m in model.warnings)
    _, fm, model = model_of("inclined_crack_slip", *soft, "contact.beta_scaling=local")
    assert face_beta_n(model, fm) == pytest.approx(250 * 1e8, rel=1e-12)
    assert model.beta0 == pytest.approx((250 * 1e11, 10 * 1e11), rel=1e-12)
    assert not model.warnings
    fields = {}
    for name, sets in (("local", [*soft, "contact.beta_scaling=local"]),
                       ("given", [*soft[:1], "contact.beta_n=2.5e10", "contact.beta_t=1e9"]),
                       ("largest", soft)):
        fields[name] = four(solve("inclined_crack_slip", *sets)[2].model.face_fields())
    scale = np.abs(fields["given"]).max(axis=0)
    assert (np.abs(fields["local"] - fields["given"]).max(axis=0) <= 1e-9 * scale).all(), \
        np.abs(fields["local"] - fields["given"]).max(axis=0) / scale
    assert np.abs(fields["largest"] - fields["given"]).max(axis=0)[0] > 1e-3 * scale[0]
    ratios = {}
    for name, sets in (("local", [*soft, "contact.beta_scaling=local"]),
                       ("soft rock", ["material.young=1e8", *soft[1:]])):
        ratios[name] = model_of("inclined_crack_slip", *sets, "contact.theta=1")[2] \
            .coercivity_ratio
    assert ratios["local"] == pytest.approx(ratios["soft rock"], rel=1e-9)


def test_p1_in_a_nearly_incompressible_rock_is_warned_of_locking():
    """P1 at ν = 0.4999 gave 15 % of the slip of P2 (volumetric locking), silently: warned from
    ν = 0.49 on; not for P2 nor at ν = 0.25."""
    for sets, warned in ((["degree=1", "parameters.nu=0.4999"], True),
                         (["degree=2", "parameters.nu=0.4999"], False), (["degree=1"], False)):
        _, _, model = model_of("inclined_crack_slip", *sets)
        assert any("P1 displacements lock" in m for m in model.warnings) == warned, sets


def test_pointwise_coulomb_nitsche_near_incompressibility_is_warned():
    """At ν = 0.4999 the six-fracture scene (P2, Coulomb F = 0.5) fails with pointwise
    ``nitsche`` θ = -1: its friction bound takes σ_n, where λ div u weighs 4,999 μ, and one point
    switches between stick and slip at every iteration (steps of about 0.01), silently. Warned
    from ν = 0.4995, where it failed too; θ = 0 and ``mean_nitsche`` converge there in 7 and 3
    Newton iterations (docs/mechanics/incompressible.md). Not warned at 0.499 (converged in 9),
    with θ = 0, Tresca, F = 0 or the face means. The uncondensed ``mixed`` of 3D (failed on
    configs/network3d.yaml at 0.4995 and 0.4999) is warned of too, the condensed one of 2D not."""
    from poromech.errors import SolverError

    cases = ((["material.poisson=0.4995"], True), (["material.poisson=0.499"], False),
             (["material.poisson=0.4999", "contact.theta=1"], True),
             (["material.poisson=0.4999", "contact.theta=0"], False),
             (["material.poisson=0.4999", "contact.friction=tresca", "contact.slip_bound=1e6"],
              False),
             (["material.poisson=0.4999", "contact.friction_coefficient=0"], False),
             (["material.poisson=0.4999", "contact.formulation=mean_nitsche"], False))
    for sets, warned in cases:
        _, _, model = model_of("six_fractures_mechanics", *sets)
        said = [m for m in model.warnings if "between stick and slip" in m]
        assert len(said) == int(warned), sets
    # mixed: condensed in 2D (converged at every ratio), uncondensed in 3D (failed at 0.4999)
    for name, sets, warned in (
            ("six_fractures_mechanics", [], False),
            ("network3d", ["mesh.size=0.6", "mesh.fracture_size=0.3", "degree=1"], True)):
        _, _, model = model_of(name, "contact.formulation=mixed", "material.poisson=0.4999",
                               *sets)
        said = [m for m in model.warnings if "mixed in 3D" in m]
        assert len(said) == int(warned), name
    one_step = ["material.poisson=0.4999", "time.final=100", "time.steps=1", "time.max_cuts=0"]
    with pytest.raises(SolverError) as failed:
        solve("six_fractures_mechanics", *one_step)
    assert "DIVERGED_MAX_IT" in failed.value.reason
    for sets, most in ((["contact.theta=0"], 7), (["contact.formulation=mean_nitsche"], 3)):
        records = solve("six_fractures_mechanics", *one_step, *sets)[3]
        assert records[0]["converged"] and records[0]["iterations"] <= most, sets


def test_symmetric_nitsche_warns_below_its_coercivity_bound(caplog):
    """θ = 1 with β_τ⁰ = 1.6 E (the issue's 40 GPa on E = 25 GPa) is below the bound: warned;
    θ = 1 at β⁰ = 100 E and θ = -1 at any β⁰ are not."""
    low = ["parameters.E=2.5e10", "contact.theta=1", "contact.beta_t=4e10"]
    with caplog.at_level("WARNING", logger="poromech"):
        _, _, model = model_of("inclined_crack_slip", *low)
    assert model.coercivity_ratio > 1 and "coercivity bound" in caplog.text
    assert model.warnings and "theta -1" in model.warnings[0]
    _, _, model = model_of("inclined_crack_slip", "contact.theta=1")
    assert model.coercivity_ratio < 1 and not model.warnings
    _, _, model = model_of("inclined_crack_slip", *low[:1], "contact.beta_t=4e10")
    assert not model.warnings
    _, _, model = model_of("inclined_crack_frictionless", "contact.theta=1")
    assert 0 < model.coercivity_ratio < 1  # no tangential terms without friction


@pytest.mark.parametrize("degree", [1, 2])
def test_coercivity_ratio_bounds_the_global_eigenvalue(degree):
    """The local bound ρ is sufficient: the largest eigenvalue of the Nitsche consistency term
    against the elastic energy, on the whole cracked space with its Dirichlet conditions, is
    below ρ (and within a factor 3 of it)."""
    import scipy.linalg
    import ufl
    from dolfinx import fem

    from poromech.forms.elasticity import elastic_form
    from poromech.mechanics.coercivity import _traction_form, symmetric_nitsche_ratio
    from poromech.mesh.fractured import FRACTURE_TAG, fracture_measure

    scene, fm, model = model_of("inclined_crack_slip", f"degree={degree}", "mesh.size=0.5",
                                "mesh.tip_size=0.05", "mesh.fracture_size=0.2")
    E, nu, bn, bt = 1e10, 0.25, 3e10, 1e10
    rho = symmetric_nitsche_ratio(fm, degree, E, nu, bn, bt)
    V = model.V
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    n = ufl.FacetNormal(fm.msh)("+")
    h = ufl.FacetArea(fm.msh)("+")
    A = fem.assemble_matrix(fem.form(elastic_form(u, v, E, nu, ufl.dx(domain=fm.msh))))
    B = fem.assemble_matrix(fem.form(_traction_form(u, v, n, h, E, nu, "plus", bn, bt)
                                     * fracture_measure(fm)(FRACTURE_TAG)))
    A, B = A.to_scipy().toarray(), B.to_scipy().toarray()
    fixed = np.unique(np.concatenate([bc.dof_indices()[0] for bc in model.bcs]))
    free = np.setdiff1d(np.arange(A.shape[0]), fixed)
    lam = scipy.linalg.eigvalsh(B[np.ix_(free, free)], A[np.ix_(free, free)]).max()
    assert lam <= rho * (1 + 1e-10)
    assert lam >= rho / 3


def test_small_beta_with_coulomb_nitsche_in_3d_is_reported():
    """β_n⁰ = 0.01 E made the contact Newton of configs/network3d.yaml creep and fail (pointwise
    nitsche, Coulomb, 3D), silently: warned below 0.1 E; not at 0.1 E, nor with Tresca."""
    cases = ((["contact.beta_n=9e8"], True), (["contact.beta_n=1e9"], False),
             (["contact.beta_n=1e8", "contact.friction=tresca", "contact.slip_bound=1e5"], False),
             (["contact.beta_n=1e8", "contact.theta=0"], False))
    for sets, warned in cases:
        _, _, model = model_of("network3d", "degree=1", "mesh.size=0.6",
                               "mesh.fracture_size=0.3", *sets)
        said = [m for m in model.warnings if "may creep and fail" in m]
        assert len(said) == int(warned), sets


def test_small_beta_t_with_coulomb_nitsche_p2_in_3d_is_reported():
    """β_τ⁰ = E against β_n⁰ = 250 E broke the Krylov solves of configs/network3d.yaml (P2,
    Coulomb, θ = -1) and MUMPS' Newton did not converge: warned below β_n⁰/25 for the three
    Nitsche formulations; not at the defaults' ratio, with θ = 0, with Tresca, nor with P1."""
    cases = ((["contact.beta_t=9.9e10"], True),
             (["contact.beta_t=1e11"], False),  # the defaults' ratio, 10/250
             (["contact.beta_t=1e10", "contact.formulation=mean_nitsche"], True),
             (["contact.beta_t=1e10", "contact.beta_n=2.5e11"], False),
             (["contact.beta_t=1e10", "contact.theta=0"], False),
             (["contact.beta_t=1e10", "contact.friction=tresca", "contact.slip_bound=1e5"],
              False),
             (["contact.beta_t=1e10", "degree=1"], False))
    for sets, warned in cases:
        _, _, model = model_of("network3d", "mesh.size=0.6", "mesh.fracture_size=0.3", *sets)
        said = [m for m in model.warnings if "contact.beta_t" in m and "may fail" in m]
        assert len(said) == int(warned), sets
