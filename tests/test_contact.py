"""Contact formulations against exact solutions: Sneddon and the inclined frictional crack.

Thresholds are the measured errors with a 10% margin (docs/verification.md has the full study);
rates are checked over two refinements. The tip singularity limits every method to L² rate 1.
"""

import numpy as np
import pytest
from conftest import ROOT
from mpi4py import MPI

from poromech.config import load_scene
from poromech.run import MechanicsSimulation, build_mesh
from poromech.timing import Timer
from poromech.verification import exact_jump, jump_errors

comm = MPI.COMM_WORLD
FORMULATIONS = ["nitsche", "mean_nitsche", "stabilized_mixed", "mixed"]


def solve(name: str, *overrides: str):
    scene = load_scene(ROOT / "configs" / f"{name}.yaml", list(overrides))
    fm = build_mesh(scene, comm)
    sim = MechanicsSimulation(scene, fm, Timer())
    sim.run()
    return scene, fm, sim


def errors(name: str, *overrides: str):
    scene, fm, sim = solve(name, *overrides)
    err = jump_errors(sim.model.u, fm, exact_jump(scene))
    values = sim.model.face_fields()
    sim.close()
    return err, values, sim


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


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_sneddon_fully_open_with_contact(formulation):
    """With contact switched on, the pressurized crack stays open and the answer is unchanged."""
    ref, _, _ = errors("sneddon")
    err, values, sim = errors("sneddon", f"contact.formulation={formulation}")
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
        err, values, sim = errors("inclined_crack_slip", f"contact.formulation={formulation}",
                                  f"mesh.refinement={m}")
        errs.append(err)
        assert err["l2_n"] < 0.02 * err["l2"]
        inner = np.abs(sim.model.fm.fractures.s - p["b"]) < 0.8 * p["b"]
        assert np.all(sim.model.states(values)[inner] == 2)  # tip faces may differ
        assert np.allclose(values[inner, 2], tn_exact, rtol=0.02)
        assert np.allclose(np.abs(values[inner, 3]), p["F"] * abs(tn_exact), rtol=0.02)
    assert errs[0]["l2"] < 1.1e-2 and errs[1]["l2"] < 5.5e-3
    assert 0.85 < rate(errs[0]["l2"], errs[1]["l2"]) < 1.2


@pytest.mark.parametrize("formulation", FORMULATIONS)
@pytest.mark.parametrize("degree", [1, 2])
def test_inclined_crack_stick_is_exact(formulation, degree):
    """In the stick regime the exact field is affine: every method reproduces it to round-off."""
    err, values, sim = errors("inclined_crack_stick", f"contact.formulation={formulation}",
                              f"degree={degree}")
    slip_scale = 4 * (1 - 0.25**2) / 1e10 * 1e7  # m, the slip of a released crack
    assert err["max"] < 1e-9 * slip_scale  # absolute: the exact jump is zero
    if not (formulation == "mixed" and degree == 1):  # P1-P0: multipliers are not unique
        assert np.all(sim.model.states(values) == 1)


@pytest.mark.parametrize("formulation", ["nitsche", "mixed"])
def test_inclined_crack_frictionless(formulation):
    err, values, sim = errors("inclined_crack_frictionless", f"contact.formulation={formulation}")
    assert err["l2"] < 1.06e-2
    assert err["l2_n"] < 0.02 * err["l2"]
    assert np.allclose(values[:, 3], 0.0, atol=1e-6 * np.abs(values[:, 2]).max())


@pytest.mark.parametrize("degree", [1, 2])
def test_stabilized_mixed_equals_mean_nitsche(degree):
    """Eliminating the multipliers of (5) gives (7): the two must agree to solver tolerance."""
    _, a, _ = errors("inclined_crack_slip", "contact.formulation=stabilized_mixed",
                     f"degree={degree}")
    _, b, _ = errors("inclined_crack_slip", "contact.formulation=mean_nitsche",
                     f"degree={degree}")
    scale = np.abs(a[:, :4]).max(axis=0)
    assert np.all(np.abs(a[:, :4] - b[:, :4]).max(axis=0) <= 1e-8 * scale)


@pytest.mark.parametrize("theta", [-1, 0, 1])
def test_nitsche_theta_variants(theta):
    ref, _, _ = errors("inclined_crack_slip")
    err, _, sim = errors("inclined_crack_slip", f"contact.theta={theta}")
    assert abs(err["l2"] - ref["l2"]) < 0.05 * ref["l2"]
    assert sim.records[-1]["converged"]


def test_tresca_with_the_coulomb_bound_reproduces_coulomb():
    """A Tresca bound s = F |t_N| (t_N uniform in the exact solution) gives the Coulomb slip up
    to the discretization error of the normal traction (< 1%)."""
    scene = load_scene(ROOT / "configs" / "inclined_crack_slip.yaml")
    p = scene.parameters
    s = float(p["F"] * p["sigma"] * np.sin(p["psi"]) ** 2)
    e_coulomb, coulomb, _ = errors("inclined_crack_slip")
    e_tresca, tresca, _ = errors("inclined_crack_slip", "contact.friction=tresca",
                                 f"contact.slip_bound={s!r}")
    slip = np.abs(coulomb[:, 1]).max()
    assert np.abs(tresca[:, 1] - coulomb[:, 1]).max() < 0.01 * slip
    assert abs(e_tresca["l2"] - e_coulomb["l2"]) < 0.05 * e_coulomb["l2"]


def test_only_what_is_needed_is_built():
    """Nitsche: u only. Mixed: λ (2) and jump averages. Frictionless: no tangential unknowns.
    Open pressurized crack: a linear problem without contact terms."""
    _, _, sim = solve("inclined_crack_slip")
    assert [f.name for f in sim.model.unknowns] == ["u"]
    _, _, sim = solve("inclined_crack_slip", "contact.formulation=mixed")
    names = [f.name for f in sim.model.unknowns]
    assert names == ["u", "lambda", "averages"]
    assert sim.model.lam.function_space.dofmap.index_map_bs == 2
    _, _, sim = solve("inclined_crack_frictionless", "contact.formulation=mixed")
    assert sim.model.lam.function_space.dofmap.index_map_bs == 1
    assert sim.model.avg.function_space.dofmap.index_map_bs == 1
    _, _, sim = solve("sneddon")
    assert sim.model.linear and [f.name for f in sim.model.unknowns] == ["u"]
    assert sim.records[0]["iterations"] == 1
