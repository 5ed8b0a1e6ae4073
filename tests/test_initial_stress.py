"""In-situ stress and gravity: a state in equilibrium stays at rest, a fracture carries σ⁰n,
an imbalance is refused before the first solve, and hydrostatic fluid is at rest."""

import numpy as np
import pytest
from mpi4py import MPI

from poromech.errors import ConfigError
from poromech.run import Run
from poromech.scene.loading import scene_from_dict

comm = MPI.COMM_WORLD
FORMULATIONS = ["nitsche", "mean_nitsche", "stabilized_mixed", "mixed"]
RHO, G, K0, E = 2500.0, 9.81, 0.8, 2.0e10
H = 1000.0  # m, depth of the box (surface at y = 0)


def lithostatic(**extra) -> dict:
    """A box under its own weight with the lithostatic stress, rollers, an inclined fault."""
    raw = {
        "name": "lithostatic",
        "physics": "mechanics",
        "parameters": {"rho": RHO, "g": G, "k0": K0},
        "geometry": {"domain": {"rectangle": [0.0, -H, H, 0.0]},
                     "fractures": [{"name": "fault", "points": [[300.0, -700.0],
                                                                 [700.0, -300.0]]}]},
        "mesh": {"size": 100.0, "fracture_size": 40.0},
        "material": {"young": E, "poisson": 0.25, "density": "rho",
                     "initial_stress": ["k0*rho*g*y", "rho*g*y", 0.0]},
        "gravity": [0.0, -G],
        "contact": {"formulation": "nitsche", "friction_coefficient": 0.6},
        "boundary_conditions": [{"boundary": "left", "displacement": [0.0, None]},
                                {"boundary": "right", "displacement": [0.0, None]},
                                {"boundary": "bottom", "displacement": [None, 0.0]}],
    }
    raw.update(extra)
    return raw


def solve(raw: dict):
    """Summary, displacement values and fracture face fields (with midpoints) of a run."""
    with Run(scene_from_dict(raw)) as run:
        summary = run.execute()
        model, faces = run.physics.model, run.mesh.fractures
        return summary, model.u.x.array.copy(), model.face_fields(), faces


def traction_of(sigma: np.ndarray, faces) -> tuple[np.ndarray, np.ndarray]:
    """``σ n⁺·n⁺`` and ``σ n⁺·τ`` per face for stresses ``(n, 2, 2)`` at the face midpoints."""
    n, t = faces.normal, faces.tangents[:, 0]
    sn = np.einsum("fij,fj->fi", sigma, n)
    return np.einsum("fi,fi->f", sn, n), np.einsum("fi,fi->f", sn, t)


@pytest.mark.parametrize("formulation", FORMULATIONS)
def test_lithostatic_box_stays_at_rest_and_the_fault_carries_it(formulation):
    """Weight, lithostatic σ⁰ and rollers: no displacement (to the solver tolerance, against the
    1.2 m the weight would cause without σ⁰), and the fault's tractions are σ⁰n (linear along
    each face, so its face mean is its midpoint value)."""
    summary, u, values, faces = solve(lithostatic(contact={"formulation": formulation,
                                                            "friction_coefficient": 0.6}))
    assert summary["initial_stress_imbalance"]["relative"] < 1e-12
    sag = RHO * G * H**2 / E  # the weight's displacement scale, 1.2 m
    assert comm.allreduce(float(np.abs(u).max(initial=0.0)), op=MPI.MAX) < 1e-12 * sag
    y = faces.midpoint[:, 1]
    sigma = np.zeros((len(y), 2, 2))
    sigma[:, 0, 0], sigma[:, 1, 1] = K0 * RHO * G * y, RHO * G * y
    tn, tt = traction_of(sigma, faces)
    scale = RHO * G * H
    assert np.abs(values["traction_n"] - tn).max(initial=0.0) < 1e-12 * scale
    assert np.abs(values["traction_t"] - tt).max(initial=0.0) < 1e-12 * scale
    states = summary["solves"][0]
    # the face unknowns start consistent with u = 0 (the face means of σ⁰n): nothing to solve
    # (the face-mean formulations took a Newton iteration from zero averages before)
    assert states["converged"] and states["iterations"] == 0


@pytest.mark.parametrize("formulation", ["nitsche", "mixed"])
def test_prestressed_fracture_carries_sigma0_n_exactly(formulation):
    """A uniform, sheared σ⁰ in a clamped box with no other load: u = 0, and every face of the
    inclined fracture carries exactly σ⁰n (normal and tangential, below the friction bound)."""
    s0 = np.array([[-3.0e7, 4.0e6], [4.0e6, -2.0e7]])
    raw = lithostatic(
        material={"young": E, "poisson": 0.25,
                  "initial_stress": [s0[0, 0], s0[1, 1], s0[0, 1]]},
        contact={"formulation": formulation, "friction_coefficient": 0.6},
        boundary_conditions=[{"boundary": b, "displacement": [0.0, 0.0]}
                             for b in ("left", "right", "bottom", "top")])
    del raw["gravity"]
    summary, u, values, faces = solve(raw)
    tn, tt = traction_of(np.broadcast_to(s0, (len(faces.facets), 2, 2)), faces)
    assert comm.allreduce(float(np.abs(u).max(initial=0.0)), op=MPI.MAX) < 1e-12
    assert np.allclose(values["traction_n"], tn, rtol=1e-10, atol=0)
    assert np.allclose(values["traction_t"], tt, rtol=1e-10, atol=0)
    assert np.all(np.abs(tt) < 0.6 * np.abs(tn))  # stick: the prestress holds


def test_an_initial_stress_out_of_balance_is_refused_with_where():
    """A traction-free top where σ⁰n ≠ 0 (the overburden left out), and a density that does not
    carry the stress gradient: refused before the first solve, naming where it is largest."""
    raw = lithostatic(material={"young": E, "poisson": 0.25, "density": "rho",
                                "initial_stress": ["k0*rho*g*(y - 100)", "rho*g*(y - 100)",
                                                   0.0]})
    with pytest.raises(ConfigError, match="not in equilibrium.*on boundary 'top' .give that "
                                          "boundary the traction σ⁰n"):
        solve(raw)
    raw = lithostatic(material={"young": E, "poisson": 0.25, "density": "0.5*rho",
                                "initial_stress": ["k0*rho*g*y", "rho*g*y", 0.0]})
    # it said "give that boundary the traction σ⁰n" there too, naming no boundary
    with pytest.raises(ConfigError, match=r"not in equilibrium.*in the interior \(give the "
                                          "density and gravity that balance div σ⁰") as info:
        solve(raw)
    assert "that boundary" not in str(info.value)


def deep_box(density: str, size: float) -> dict:
    """A 400 m box at 1.8–2.2 km depth: lithostatic σ⁰ of ``rho``, the overburden as the top's
    traction, rollers elsewhere; its weight from ``density``."""
    raw = lithostatic(
        geometry={"domain": {"rectangle": [0.0, -2200.0, 400.0, -1800.0]}},
        mesh={"size": size},
        material={"young": E, "poisson": 0.25, "density": density,
                  "initial_stress": ["k0*rho*g*y", "rho*g*y", 0.0]},
        boundary_conditions=[{"boundary": "left", "displacement": [0.0, None]},
                             {"boundary": "right", "displacement": [0.0, None]},
                             {"boundary": "bottom", "displacement": [None, 0.0]},
                             {"boundary": "top", "traction": [0.0, "rho*g*y"]}])
    raw.pop("contact")
    return raw


def test_a_density_off_at_depth_is_refused_on_every_mesh():
    """A density 5 % low at 2 km depth: the imbalance was measured against the reactions of
    the imposed rows (σ⁰ h, large at depth) and shrank with the cells: 8e-4 on 25 m cells,
    accepted, and the body rose 4 mm at t = 0. Measured as a force density it is the missing
    weight on every mesh, refused."""
    found = []
    for size in (100.0, 25.0):
        with pytest.raises(ConfigError, match=r"not in equilibrium.*residual is ([0-9.e-]+) of "
                                              r"the loads.*in the interior") as info:
            solve(deep_box("0.95*rho", size))
        found.append(float(str(info.value).split("residual is ")[1].split(" ")[0]))
    assert found[0] > 10 * 1e-3 and abs(found[1] / found[0] - 1.0) < 0.1, found
    summary = solve(deep_box("rho", 25.0))[0]
    assert summary["initial_stress_imbalance"]["relative"] < 1e-12


def test_a_density_linear_in_depth_is_in_exact_equilibrium_with_p2():
    """ρ = ρ0 − 0.5 y (denser with depth) and its quadratic lithostatic σ⁰: exactly balanced by
    P2. The density was interpolated in DG0: an imbalance of a cell size times its gradient,
    and 64 µm of motion at t = 0 in this box."""
    raw = lithostatic(degree=2, material={
        "young": E, "poisson": 0.25, "density": "rho - 0.5*y",
        "initial_stress": ["k0*g*(rho*y - 0.25*y**2)", "g*(rho*y - 0.25*y**2)", 0.0]})
    summary, u, values, faces = solve(raw)
    assert summary["initial_stress_imbalance"]["relative"] < 1e-12
    sag = RHO * G * H**2 / E
    assert comm.allreduce(float(np.abs(u).max(initial=0.0)), op=MPI.MAX) < 1e-12 * sag


def test_without_contact_a_compressed_fracture_is_refused():
    """``contact.formulation: none`` leaves the fault to its fluid pressure: under the
    lithostatic σ⁰ (checked on the continuous space, which has no fracture) its faces went
    0.57 m through each other at the first solve, every face written ``open``."""
    with pytest.raises(ConfigError, match=r"loads fracture 'fault' with a traction of .* "
                                          r"contact.formulation none lets nothing carry it"):
        solve(lithostatic(contact={"formulation": "none"}))
    # a fluid pressure that carries an isotropic σ⁰ leaves the fracture at rest (to the
    # pressure's facewise constant values against σ⁰n linear along each face: 1.4e-8 of sag)
    raw = lithostatic(contact={"formulation": "none"}, fracture_pressure="-rho*g*y",
                      material={"young": E, "poisson": 0.25, "density": "rho",
                                "initial_stress": ["rho*g*y", "rho*g*y", 0.0]})
    summary, u, values, faces = solve(raw)
    sag = RHO * G * H**2 / E
    assert comm.allreduce(float(np.abs(u).max(initial=0.0)), op=MPI.MAX) < 1e-7 * sag


@pytest.mark.parametrize(("change", "message"), [
    ({"gravity": None}, "'material.density' has no effect without gravity"),
    ({"material": {"young": E, "poisson": 0.25, "initial_stress": [0.0, 0.0, 0.0]}},
     "'material.density' is required with gravity"),
    ({"material": {"young": E, "poisson": 0.25, "density": 1.0,
                   "initial_stress": [0.0, 0.0]}}, "has 2 components: a 2D stress has 3"),
    ({"material": {"young": E, "poisson": 0.25, "density": 1.0,
                   "initial_stress": ["1e6*t", 0.0, 0.0]}}, "depends on t"),
    ({"gravity": [0.0, -9.81, 0.0]}, "'gravity' = \\[0.0, -9.81, 0.0\\] must have 2 components"),
])
def test_weight_and_stress_input_is_checked(change, message):
    raw = lithostatic(**change)
    if raw.get("gravity") is None:
        raw.pop("gravity")
    with pytest.raises(ConfigError, match=message):
        scene_from_dict(raw)


def test_a_density_without_gravity_in_3d_suggests_a_3d_gravity():
    """The refusal's example had two components in a 3D scene too."""
    raw = {"name": "d3", "geometry": {"domain": {"box": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]}},
           "mesh": {"size": 0.5}, "material": {"young": E, "poisson": 0.25, "density": 2400.0},
           "boundary_conditions": [{"boundary": "bottom", "displacement": [0.0, 0.0, 0.0]}]}
    with pytest.raises(ConfigError, match=r"give gravity \(e.g. \[0, 0, -9.81\]\)"):
        scene_from_dict(raw)


def hydrostatic(physics: str = "flow", **extra) -> dict:
    """A water-saturated column with gravity: pressure fixed on top, impervious elsewhere."""
    raw = {
        "name": "hydrostatic",
        "physics": physics,
        "geometry": {"domain": {"rectangle": [0.0, -10.0, 2.0, 0.0]},
                     "fractures": [{"name": "f", "points": [[0.3, -8.0], [1.5, -2.0]]}]},
        "mesh": {"size": 0.5, "fracture_size": 0.25},
        "gravity": [0.0, -9.81],
        "flow": {"permeability": [1.0e-13, 2.0e-14], "fluid_density": 1000.0,
                 "aperture": 1.0e-4,
                 "boundary_conditions": [{"boundary": "top", "pressure": 1.0e5}]},
    }
    raw.update(extra)
    return raw


def test_hydrostatic_fluid_is_at_rest():
    """Darcy on the potential p - ρ_f g·x: the steady pressure is hydrostatic in the matrix and
    in the fracture (HFV is exact for it), and nothing flows."""
    with Run(scene_from_dict(hydrostatic())) as run:
        run.execute()
        pb = run.physics.problem
        exact = 1.0e5 - 1000.0 * 9.81 * pb.dofs.points[:, 1]
        assert np.abs(pb.p - exact).max() < 1e-8 * 1.0e5
        from poromech.flow.balance import compute_fluxes

        fluxes = compute_fluxes(pb)
        scale = 1e-13 / 1e-3 * 1000.0 * 9.81  # K ρ_f g / η: the flux gravity would drive
        assert np.abs(fluxes.cell).max() < 1e-9 * scale


def test_poroelastic_column_at_rest_under_gravity():
    """Lithostatic σ⁰ (total) with a hydrostatic p⁰, transient: nothing moves, nothing flows,
    the pressure stays hydrostatic over the steps, and the fixed point needs one iteration."""
    raw = hydrostatic(
        "poromechanics",
        parameters={"rho": 2300.0, "g": 9.81, "k0": 0.7},
        material={"young": 1.0e10, "poisson": 0.25, "biot": 0.8, "density": "rho",
                  "initial_stress": ["k0*rho*g*y", "rho*g*y", 0.0]},
        contact={"formulation": "nitsche", "friction_coefficient": 0.6},
        boundary_conditions=[{"boundary": "left", "displacement": [0.0, None]},
                             {"boundary": "right", "displacement": [0.0, None]},
                             {"boundary": "bottom", "displacement": [None, 0.0]}],
        time={"final": 100.0, "steps": 2})
    # the fluid pressure is 0 at the surface, as the total stress: the fracture stays closed
    raw["flow"].update(biot_modulus=1.0e10, porosity=0.2, initial_pressure="-1000*9.81*y",
                       boundary_conditions=[{"boundary": "top", "pressure": 0.0}])
    with Run(scene_from_dict(raw)) as run:
        summary = run.execute()
        pb, u = run.physics.flow, run.physics.model.u.x.array
        exact = -1000.0 * 9.81 * pb.dofs.points[:, 1]
        assert np.abs(pb.p - exact).max() < 1e-6 * 1000.0 * 9.81 * 10.0
        sag = 2300.0 * 9.81 * 10.0**2 / 1.0e10
        assert np.abs(u).max(initial=0.0) < 1e-7 * sag
    assert all(r["converged"] and r["g_evaluations"] <= 2 for r in summary["solves"])


def test_validate_with_mesh_runs_the_checks_on_the_mesh(tmp_path, capsys):
    """``poromech validate`` checks the keys without meshing, and says so; ``--mesh`` also meshes
    and builds the solvers, and refuses (exit 2) what a run would refuse after meshing: here an
    initial stress out of balance at the traction-free top (validate said "valid" for it)."""
    import yaml

    from poromech.cli import main

    raw = lithostatic(material={"young": E, "poisson": 0.25, "density": "rho",
                                "initial_stress": ["k0*rho*g*(y - 100)", "rho*g*(y - 100)",
                                                   0.0]})
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(raw))
    assert main(["validate", str(path)]) == 0
    assert "not meshed: --mesh also runs the checks on the mesh" in capsys.readouterr().out
    assert main(["validate", str(path), "--mesh"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert "scene key 'material.initial_stress' is not in equilibrium" in last
    path.write_text(yaml.safe_dump(lithostatic()))
    assert main(["validate", str(path), "--mesh"]) == 0
    assert "meshed: " in capsys.readouterr().out
    assert not (tmp_path / "results").exists()  # nothing written


@pytest.mark.parametrize(("formulation", "degree"), [("stabilized_mixed", 1),
                                                     ("mean_nitsche", 1), ("mixed", 2),
                                                     ("mixed", 1)])
def test_an_inclined_3d_fault_at_depth_stays_at_rest(formulation, degree):
    """A disc dipping 37° at 2 km depth under a lithostatic σ⁰ with unequal horizontal stresses:
    the facewise formulations carry the face mean of a traction σ⁰n that varies along each face,
    and moved the body by 1.5e-6 m (1.3e-4 of the weight's scale) with 8.7e-8 m of slip at rest
    before the remainder was applied pointwise; now u = 0 to round-off and the face tractions are
    σ⁰n at the centroids (σ⁰ is linear). The face unknowns start at the face means of σ⁰n:
    no Newton iteration (``mixed`` P1, not inf-sup stable, took 44 from zero multipliers and
    stopped 1e-9 m from rest)."""
    rho = 2400.0
    raw = {
        "name": "rest3d", "parameters": {"rho": rho, "g": G},
        "geometry": {"domain": {"box": [0.0, 0.0, -2100.0, 100.0, 100.0, -2000.0]},
                     "fractures": [{"name": "f", "disc": {"center": [50.0, 50.0, -2050.0],
                                                          "normal": [0.6, 0.0, 0.8],
                                                          "radius": 30.0}}]},
        "mesh": {"size": 25.0, "fracture_size": 10.0}, "degree": degree,
        "material": {"young": 2.0e10, "poisson": 0.25, "density": "rho",
                     "initial_stress": ["0.7*rho*g*z", "0.8*rho*g*z", "rho*g*z", 0.0, 0.0, 0.0]},
        "gravity": [0.0, 0.0, -G],
        "contact": {"formulation": formulation, "friction_coefficient": 0.6},
        "boundary_conditions": [
            {"boundary": "left", "displacement": [0.0, None, None]},
            {"boundary": "right", "displacement": [0.0, None, None]},
            {"boundary": "front", "displacement": [None, 0.0, None]},
            {"boundary": "back", "displacement": [None, 0.0, None]},
            {"boundary": "bottom", "displacement": [None, None, 0.0]},
            {"boundary": "top", "traction": [0.0, 0.0, "rho*g*z"]}],
    }
    summary, u, values, faces = solve(raw)
    assert summary["solves"][0]["converged"] and summary["solves"][0]["iterations"] == 0
    sag = rho * G * 100.0**2 / 2.0e10
    assert comm.allreduce(float(np.abs(u).max(initial=0.0)), op=MPI.MAX) < 1e-12 * sag
    assert np.abs(values["jump_t"]).max(initial=0.0) < 1e-12 * sag
    z = faces.midpoint[:, 2]
    sigma = np.zeros((len(z), 3, 3))
    for i, k in enumerate((0.7, 0.8, 1.0)):
        sigma[:, i, i] = k * rho * G * z
    n = faces.normal
    sn = np.einsum("fij,fj->fi", sigma, n)
    scale = rho * G * 2100.0
    assert np.abs(values["traction_n"] - np.einsum("fi,fi->f", sn, n)).max(initial=0.0) \
        < 1e-9 * scale
