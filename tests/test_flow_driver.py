"""Flow-only runs through ``run_scene``: outputs, probes, report, failures, input."""

import csv
import re

import numpy as np
import pytest
from conftest import ROOT, network_geometry, sigterm_after_steps
from mpi4py import MPI
from petsc4py import PETSc

from poromech.errors import ConfigError, SolverError
from poromech.run import Run, build_mesh, run_scene
from poromech.scene.loading import load_scene, scene_from_dict

comm = MPI.COMM_WORLD


def flow_scene(**flow) -> dict:
    """A small flow scene on the test network: inflow left, pressure right."""
    scene = {
        "name": "flow_test",
        "physics": "flow",
        "geometry": network_geometry(),
        "mesh": {"size": 0.1, "fracture_size": 0.05},
        "flow": {
            "permeability": [1.0e-12, 2.0e-13, 5.0e-13],
            "viscosity": 1.0e-3,
            "aperture": 1.0e-4,
            "boundary_conditions": [
                {"boundary": "left", "flux": -1.0e-6},
                {"boundary": "right", "pressure": "1e5 + 1e3*y"},
            ],
        },
        "probes": [{"name": "bar", "start": [0.0, 0.5], "end": [2.0, 0.5], "samples": 81},
                   {"name": "vertical", "start": [1.0, 0.0], "end": [1.0, 1.0], "samples": 11}],
    }
    scene["flow"].update(flow)
    return scene


def run(raw: dict, outdir) -> dict:
    """The summary of a run of a raw scene."""
    return run_scene(scene_from_dict(raw), outdir, comm)


def read_csv(path):
    with open(path) as f:
        rows = list(csv.reader(f))
    return rows[0], rows[1:]


def test_steady_outputs_and_report(tmp_path):
    summary = run(flow_scene(), tmp_path)
    for name in ("flow.xdmf", "fractures_flow.xdmf", "probe_bar.csv", "probe_vertical.csv"):
        assert (tmp_path / name).exists(), name
    text = (tmp_path / "fractures_flow.xdmf").read_text()
    for field in ("p_f", "p_plus", "p_minus", "d_f", "u_plus", "u_minus", "q_f"):
        assert f'Name="{field}"' in text
    assert 'Name="p_m"' in (tmp_path / "flow.xdmf").read_text()
    rep = summary["flow"]
    assert rep["unknowns"]["total"] > 1000 and rep["unknowns"]["nodes"] > 0
    solve = rep["solves"][0]
    assert solve["reason"].startswith("CONVERGED") and 0 < solve["iterations"] < 100
    assert solve["seconds"] > 0
    cons = rep["conservation"]
    assert cons["relative_residual"] < 1e-8 and cons["max_local_residual"] < 1e-8
    flux = cons["boundary_fluxes"]
    assert set(flux) == {"bottom", "right", "top", "left"}
    assert flux["left"]["total"] == pytest.approx(-1e-6, rel=1e-9)  # imposed inflow
    assert flux["right"]["total"] == pytest.approx(1e-6, rel=1e-6)  # steady: all leaves right
    header, rows = read_csv(tmp_path / "probe_bar.csv")
    assert header == ["time", "arc_length", "x", "y", "p_m", "p_f"]
    assert {r[0] for r in rows} == {"0"}  # steady: one output time
    x = np.array([float(r[2]) for r in rows])
    has_pf = np.array([r[5] != "" for r in rows])
    assert np.array_equal(has_pf, (x >= 0.2 - 1e-12) & (x <= 0.8 + 1e-12))
    assert all(r[4] != "" for r in rows)
    _, rows = read_csv(tmp_path / "probe_vertical.csv")
    assert all(r[5] == "" for r in rows)  # crosses no fracture lengthwise


def test_transient_with_storage(tmp_path):
    raw = flow_scene(biot_modulus=1e9, porosity=0.2, initial_pressure=1e5)
    raw["time"] = {"final": 100.0, "steps": 4}
    raw["output"] = {"every": 2}
    summary = run(raw, tmp_path)
    rep = summary["flow"]
    assert len(rep["solves"]) == 4
    assert [s["time"] for s in rep["solves"]] == pytest.approx([25, 50, 75, 100])
    assert all(s["mass_balance"]["relative_residual"] < 1e-8 for s in rep["solves"])
    first = rep["solves"][0]["mass_balance"]
    assert abs(first["storage_rate"]) > 1e-3 * abs(first["outflow"])  # storage is active
    times = re.findall(r'<Time Value="([^"]+)"', (tmp_path / "flow.xdmf").read_text())
    assert sorted({float(t) for t in times}) == [0.0, 50.0, 100.0]


def test_solver_failure_raises(tmp_path):
    raw = flow_scene(linear_solver="iterative", petsc={"ksp_max_it": 2, "ksp_rtol": 1e-14})
    with Run(scene_from_dict(raw), tmp_path, comm) as failed:
        with pytest.raises(SolverError) as err:
            failed.execute()
    assert err.value.reason == "DIVERGED_MAX_IT"
    assert len(err.value.history) == 3
    assert "did not converge" in str(err.value)
    assert "flow.linear_solver: direct solves it" in str(err.value)  # what to do about it
    assert "flow" in failed.summary and failed.summary["status"].startswith("failed")


def test_command_line_options_win_and_are_not_left(tmp_path):
    opts = PETSc.Options()
    opts["flow_ksp_rtol"] = 1e-4
    try:
        summary = run(flow_scene(petsc={"ksp_rtol": 1e-12, "pc_type": "jacobi",
                                    "ksp_max_it": 5000}), tmp_path)
    finally:
        opts.delValue("flow_ksp_rtol")
    solver = summary["flow"]["solver"]
    assert solver["pc_type"] == "jacobi" and solver["max_it"] == 5000  # scene over defaults
    assert solver["rtol"] == 1e-4  # the command line over the scene
    assert not [k for k in opts.getAll() if k.startswith("flow_")]


def test_direct_solver_matches_iterative(tmp_path):
    it = run(flow_scene(), tmp_path / "it")["flow"]["conservation"]
    lu = run(flow_scene(linear_solver="direct"), tmp_path / "lu")["flow"]
    assert lu["solver"]["pc_type"] == "lu"
    assert lu["conservation"]["boundary_fluxes"]["right"]["matrix"] == pytest.approx(
        it["boundary_fluxes"]["right"]["matrix"], rel=1e-7)


def test_a_krylov_method_other_than_cg_measures_its_own_norm(tmp_path):
    """``flow.petsc.ksp_type: gmres`` (or bicg, bcgs) stopped at PETSc's set-up with "KSP gmres
    does not support norm type NATURAL", the default of CG: another method now measures its
    own default norm, and gives CG's fluxes."""
    it = run(flow_scene(), tmp_path / "cg")["flow"]["conservation"]
    for ksp_type in ("gmres", "bcgs"):
        other = run(flow_scene(petsc={"ksp_type": ksp_type}), tmp_path / ksp_type)["flow"]
        assert other["solver"]["ksp_type"] == ksp_type
        assert other["conservation"]["boundary_fluxes"]["right"]["matrix"] == pytest.approx(
            it["boundary_fluxes"]["right"]["matrix"], rel=1e-6)


def test_a_where_that_selects_no_face_is_refused(tmp_path):
    """A ``where`` narrower than the boundary faces (tested at their midpoints) selected nothing:
    the inflow was dropped without a word (a pressure left the system singular). Refused after
    meshing, naming the condition; a ``where`` that selects faces runs."""
    bcs = [{"boundary": "left", "flux": -1.0e-6, "where": "y > 0.9999"},
           {"boundary": "right", "pressure": 0.0}]
    with pytest.raises(ConfigError, match=r"'flow.boundary_conditions.0' \(boundary left"):
        run(flow_scene(boundary_conditions=bcs), tmp_path / "none")
    bcs[0]["where"] = "y > 0.5"
    assert run(flow_scene(boundary_conditions=bcs), tmp_path / "half")["status"] == "converged"


BAD = [
    ({"permeability": [1.0, 2.0, 1.0]}, "flow.permeability' = [1.0, 2.0, 1.0]"),
    ({"permeability": [1.0, 2.0, 3.0, 4.0]}, "has 4 entries"),
    ({"fracture_permeability": 1e-8, "fracture_conductivity": 1e-12}, "not both"),
    ({"fractures": [{"fracture": "nope", "aperture": 1e-3}]}, "'nope' is not a fracture"),
    ({"aperture": "1e-4*(x - 1)"}, "flow.aperture"),
    ({"petsc": {"flow_ksp_rtol": 1e-8}}, "without '-' and without the flow_ prefix"),
    ({"boundary_conditions": [{"boundary": "west", "pressure": 1.0}]}, "'west' is not a boundary"),
    ({"boundary_conditions": [{"boundary": "left", "pressure": 1.0, "flux": 1.0}]},
     "exactly one of pressure, flux"),
    ({"boundary_conditions": [{"boundary": "left", "pressure": 1.0},
                              {"boundary": "left", "flux": 1.0}]}, "already has a flow condition"),
    ({"boundary_conditions": [{"boundary": "left", "flux": 1.0}]}, "has no pressure condition"),
    ({"linear_solver": "amg"}, "flow.linear_solver' = 'amg' is not one of"),
]


@pytest.mark.parametrize("flow, message", BAD)
def test_bad_flow_input(flow, message):
    with pytest.raises(ConfigError, match=re.escape(message)) as err:
        scene_from_dict(flow_scene(**flow))
    assert "\n" not in str(err.value)


def test_bad_probes_and_missing_flow():
    raw = flow_scene()
    raw["probes"] = [{"name": "a b", "start": [0, 0], "end": [1, 1]}]
    with pytest.raises(ConfigError, match="probes.0.name"):
        scene_from_dict(raw)
    raw["probes"] = [{"name": "a", "start": [0, 0], "end": [0, 0]}]
    with pytest.raises(ConfigError, match="equals start"):
        scene_from_dict(raw)
    raw = flow_scene()
    del raw["flow"]
    with pytest.raises(ConfigError, match="'flow' is required"):
        scene_from_dict(raw)


@pytest.mark.parametrize("name, probe", [("flemisch_case1", "y_-200"),
                                         ("flemisch_case2", "x_0.5"),
                                         ("flow_six_fractures", "fracture_5")])
def test_shipped_flow_scenes_run(tmp_path, name, probe):
    scene = load_scene(ROOT / "configs" / f"{name}.yaml", ["mesh.refinement=0"])
    summary = run_scene(scene, tmp_path, comm)
    assert summary["status"] == "converged"
    cons = summary["flow"]["conservation"]
    assert cons["relative_residual"] < 1e-8
    assert (tmp_path / f"probe_{probe}.csv").exists()
    if name == "flemisch_case2":  # the fracture y = 0.5 inherits the inflow: d_f q_N = -1e-4
        assert cons["boundary_fluxes"]["left"]["fracture"] == pytest.approx(-1e-4, rel=1e-6)
        assert cons["boundary_fluxes"]["left"]["matrix"] == pytest.approx(-1.0, rel=1e-9)


def test_aperture_change_is_accumulated(tmp_path):
    """d_f = 1e-4 (1 + t/10): the fractures store |Γ| d'(t) = |Γ| 1e-5 m²/s (DESIGN §5)."""
    raw = flow_scene(aperture="1e-4*(1 + t/10)")
    raw["time"] = {"final": 4.0, "steps": 2}
    summary = run(raw, tmp_path)
    from poromech.scene.geometry import scene_geometry

    length = scene_geometry(scene_from_dict(raw)).fracture_lengths().sum()
    for s in summary["flow"]["solves"]:
        bal = s["mass_balance"]
        assert bal["storage_rate"] == pytest.approx(1e-5 * length, rel=1e-9)
        assert bal["relative_residual"] < 1e-8


def test_fracture_storage_keeps_the_solution_it_is_centred_on():
    """``s_f (p_f - p_in)`` in the fracture balance: no change when ``p_in`` is the solution.

    With ``d̂ = d - s_f p_in`` the fracture volume is ``d + s_f (p_f - p_in)``: centred on the
    solution without storage it changes nothing (the fixed point of the coupling's ``g`` is
    the same); centred elsewhere it pulls ``p_f`` towards ``p_in``, and the mass balance
    counts it.
    """
    from dataclasses import replace

    from poromech.flow.balance import compute_fluxes, mass_balance
    from poromech.flow.problem import TimeStep
    from poromech.flow.setup import problem_from_scene

    scene = scene_from_dict(flow_scene(aperture="1e-4*(1 + t/10)"))
    fm = build_mesh(scene, comm)
    pb = problem_from_scene(scene, fm)
    nc = len(pb.cell_pressure)
    d_prev = pb.properties.aperture.copy()
    pb.set_aperture(1.01 * d_prev)  # the fractures grow: fluid is stored in them
    phi = np.full(nc, 0.1)
    step = TimeStep(1.0, phi, phi, d_prev)
    pb.solve(1.0, step)
    p_ref = pb.p.copy()
    pf_ref = pb.fracture_pressure.copy()
    s_f = np.full(len(d_prev), 1e-9)
    pb.set_properties(replace(pb.properties, fracture_storage=s_f))
    d = pb.properties.aperture
    centred = replace(step, aperture_fixed=d - s_f * pf_ref)
    pb.solve(1.0, centred)
    scale = comm.allreduce(np.abs(p_ref).max(initial=0.0), op=MPI.MAX)
    diff = comm.allreduce(np.abs(pb.p - p_ref).max(initial=0.0), op=MPI.MAX)
    assert diff <= 1e-8 * scale
    elsewhere = replace(step, aperture_fixed=d - s_f * (pf_ref + 1e3))
    pb.solve(1.0, elsewhere)
    shift = comm.allreduce(np.abs(pb.fracture_pressure - pf_ref).max(initial=0.0), op=MPI.MAX)
    assert shift > 10.0
    bal = mass_balance(pb, compute_fluxes(pb), 1.0, elsewhere)
    assert bal["relative_residual"] < 1e-8
    assert bal["max_local_residual"] < 1e-8
    volume = pb.fracture_volume(elsewhere)
    assert np.allclose(volume, d + s_f * (pb.fracture_pressure - pf_ref - 1e3), rtol=0, atol=1e-15)


def test_a_flow_step_that_cannot_hold_the_mass_balance_fails(tmp_path):
    """Fracture permeabilities 1e16 times the matrix's (Flemisch case 2): the solve met its
    tolerance and was written as converged with 2.6e-3 of the flow unaccounted for (1.0 at
    1e20). Such a step now fails and says why; 1e12 (5.7e-6) runs. A fluid at rest (the
    hydrostatic column of tests/test_initial_stress.py) is measured against the round-off of
    its matrix fluxes: its residual of 6e-20 m²/s was 1.7e-2 of its boundary "flux"."""
    from test_initial_stress import hydrostatic

    from poromech.flow.physics import MASS_BALANCE_FAIL

    def scene(k):
        return load_scene(ROOT / "configs" / "flemisch_case2.yaml",
                          [f"flow.fracture_permeability={k}",
                           f"flow.fracture_normal_permeability={k}"])

    with pytest.raises(SolverError, match="holds the mass balance only to 2.6e-03 of the flow"):
        run_scene(scene(1e16), tmp_path / "k16", comm)
    summary = run_scene(scene(1e12), tmp_path / "k12", comm)
    assert summary["status"] == "converged"
    assert 1e-7 < summary["flow"]["conservation"]["relative_residual"] < 1e-4
    summary = run_scene(scene_from_dict(hydrostatic()), tmp_path / "rest", comm)
    assert summary["flow"]["conservation"]["relative_residual"] < 1e-2 * MASS_BALANCE_FAIL
    # nor a step of 1e-15 s, whose storage rates are round-off over the step (4.6e-2 without
    # their round-off in the scale)
    tiny = load_scene(ROOT / "configs" / "flow_six_fractures.yaml", ["time={times: [1e-15]}"])
    summary = run_scene(tiny, tmp_path / "tiny", comm)
    assert summary["flow"]["conservation"]["relative_residual"] < 1e-2 * MASS_BALANCE_FAIL


def test_an_initial_pressure_without_storage_is_said_to_set_only_the_initial_state(
        tmp_path, caplog):
    """A transient flow without ``flow.biot_modulus`` has no storage: each step is the steady
    solve of its time, whatever the initial pressure, which sets only the written state at
    t = 0; a given ``flow.initial_pressure`` says so (it was accepted silently)."""
    said = "'flow.initial_pressure' sets only the state written at t = 0"
    pressures = []
    for p0 in (0.0, 3.0e5):
        raw = flow_scene(initial_pressure=p0)
        raw["time"] = {"final": 10.0, "steps": 1}
        caplog.clear()
        run(raw, tmp_path / f"p{p0:g}")
        assert any(said in r.getMessage() for r in caplog.records)
        _, rows = read_csv(tmp_path / f"p{p0:g}" / "probe_bar.csv")
        pressures.append({t: np.array([float(r[4]) for r in rows if r[0] == t])
                          for t in ("0", "10")})
    assert len(pressures[0]["10"]) == 81
    assert np.allclose(pressures[0]["0"], 0.0) and np.allclose(pressures[1]["0"], 3.0e5)
    assert np.allclose(pressures[0]["10"], pressures[1]["10"], rtol=1e-8, atol=0.0)
    raw["flow"]["biot_modulus"] = 1.0e9  # storage: the initial pressure acts at every step
    caplog.clear()
    run(raw, tmp_path / "stored")
    assert not any(said in r.getMessage() for r in caplog.records)
    _, rows = read_csv(tmp_path / "stored" / "probe_bar.csv")
    stored = np.array([float(r[4]) for r in rows if r[0] == "10"])
    assert not np.allclose(stored, pressures[0]["10"], rtol=1e-3, atol=0.0)


def test_auto_hands_a_failed_krylov_solve_to_mumps(tmp_path, caplog):
    """``flow.linear_solver: auto`` (the default): CG + GAMG, and after a failed Krylov solve
    (here limited to one iteration) MUMPS LU for the rest of the run, said in one warning and
    in the summary; the fluxes are MUMPS'. ``iterative`` keeps the failure."""
    limited = {"ksp_max_it": 1}
    caplog.clear()
    auto = run(flow_scene(petsc=limited), tmp_path / "auto")["flow"]
    assert auto["solver"]["fallback"] == "direct" and auto["solver"]["pc_type"] == "lu"
    said = [r.getMessage() for r in caplog.records if "flow.linear_solver auto" in r.getMessage()]
    assert len(said) == 1 and "switching to MUMPS LU for the rest of the run" in said[0]
    assert "DIVERGED_MAX_IT after 1 iterations" in said[0]
    lu = run(flow_scene(linear_solver="direct"), tmp_path / "lu")["flow"]
    assert auto["conservation"]["boundary_fluxes"]["right"]["matrix"] == pytest.approx(
        lu["conservation"]["boundary_fluxes"]["right"]["matrix"], rel=1e-10)
    assert "fallback" not in run(flow_scene(), tmp_path / "plain")["flow"]["solver"]
    with pytest.raises(SolverError, match="DIVERGED_MAX_IT"):
        run(flow_scene(linear_solver="iterative", petsc=limited), tmp_path / "iterative")


def test_a_restart_keeps_the_switch_to_mumps(tmp_path, caplog):
    """A run that ``auto`` switched to MUMPS, stopped after its first step and continued, goes
    on with MUMPS from the checkpoint (said so) and writes the uninterrupted run's pressures."""

    from poromech import stepping

    raw = flow_scene(petsc={"ksp_max_it": 1}, biot_modulus=1.0e9)
    raw["time"] = {"final": 20.0, "steps": 2}
    scene = scene_from_dict(raw)
    full = run_scene(scene, tmp_path / "full", comm)
    assert full["flow"]["solver"]["fallback"] == "direct"

    part = tmp_path / "part"
    with Run(scene, part, comm, prepare=sigterm_after_steps(1)) as stopped, \
            pytest.raises(stepping.Interrupted):
        stopped.execute()
    caplog.clear()
    resumed = run_scene(scene, part, comm, restart=True)
    assert resumed["flow"]["solver"]["fallback"] == "direct"
    assert any("the run continued here had switched the flow to MUMPS LU" in r.getMessage()
               for r in caplog.records)
    _, a = read_csv(tmp_path / "full" / "probe_bar.csv")
    _, b = read_csv(part / "probe_bar.csv")
    pa = np.array([float(r[4]) for r in a if r[0] == "20"])
    pb = np.array([float(r[4]) for r in b if r[0] == "20"])
    assert len(pa) == 81 and np.allclose(pa, pb, rtol=1e-12, atol=0.0)


def test_a_flow_scene_builds_no_cracked_topology():
    """A flow-only scene has no displacement space: its mesh skips the cracked topology and the
    pieces of the body (work on rank 0 that grows with the mesh), and a displacement space asked
    of it is refused in one line; a mechanics scene on the same geometry has both."""
    from poromech.mesh.fractured import cracked_space

    raw = flow_scene()
    flow = build_mesh(scene_from_dict(raw), comm)
    assert flow.cracked is None and flow.cracked_cells is None and flow.pieces == ()
    with pytest.raises(ValueError, match="built without its cracked topology"):
        cracked_space(flow, 1)
    raw.pop("flow")
    raw.update(physics="mechanics", material={"young": 1.0e9, "poisson": 0.25},
               boundary_conditions=[{"boundary": "bottom", "displacement": [0.0, 0.0]}])
    mech = build_mesh(scene_from_dict(raw), comm)
    assert mech.cracked is not None and len(mech.pieces) >= 1
    assert mech.msh.topology.index_map(2).size_global == flow.msh.topology.index_map(2).size_global
