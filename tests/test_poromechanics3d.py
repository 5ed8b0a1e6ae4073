"""3D poromechanics: Terzaghi's column (orders in time and space), Mandel's slab (pressure
against the series, the Mandel–Cryer effect), an injected disc fracture that opens and closes
(mass conservation, contact states), restart after an interruption and 1 rank vs 2 ranks."""

import json
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, mpirun, sigterm_after_steps
from test_coupling import assert_same_fixed_point

from poromech import stepping
from poromech.analytic import (
    mandel_displacement_x,
    mandel_displacement_z,
    mandel_parameters,
    mandel_pressure,
    mandel_roots,
)
from poromech.io.xdmf import read_series
from poromech.run import Run, run_scene
from poromech.scene.expressions import compile_expression
from poromech.scene.loading import load_scene
from poromech.verification.consolidation import fluid_volume, mandel_errors, terzaghi_errors

TERZAGHI3D = ROOT / "configs" / "terzaghi3d.yaml"
MANDEL3D = ROOT / "configs" / "mandel3d.yaml"
INJECTION3D = ROOT / "configs" / "injection3d.yaml"


def run(tmp_path, path, *overrides):
    scene = load_scene(path, overrides)
    out = tmp_path / ("_".join(o.replace("=", "") for o in overrides) or "default")
    summary = run_scene(scene, out)
    assert summary["status"] == "converged"
    return scene, out, summary


def orders(errors) -> np.ndarray:
    errors = np.array(errors)
    return np.log2(errors[:-1] / errors[1:])


@pytest.mark.slow
def test_terzaghi3d_time_order(tmp_path):
    """Implicit Euler in the 3D column (444 tetrahedra): errors halve with the time step."""
    errors = [terzaghi_errors(*run(tmp_path, TERZAGHI3D, f"time.steps={n}")[:2])[:2]
              for n in (5, 10, 20)]
    rates = orders(errors)
    assert np.all(rates > 0.9) and np.all(rates < 1.1), rates
    assert errors[-1][0] < 0.01 and errors[-1][1] < 0.01, errors


@pytest.mark.slow
def test_terzaghi3d_space_order(tmp_path):
    """Against the exact solution of the time-discrete problem (4 implicit Euler steps), under
    uniform refinement of a mesh of size 0.125 (159, 1,272, 10,176 tetrahedra): the settlement
    converges at order 2, the pressure at 1.76 then 1.94 (the coarsest mesh has one cell across
    the column and is not yet in the asymptotic range)."""
    errors = []
    for m in (0, 1, 2):
        scene, out, _ = run(tmp_path, TERZAGHI3D, "time.steps=4", "mesh.size=0.125",
                            f"mesh.refinement={m}")
        errors.append(terzaghi_errors(scene, out, steps=4)[:2])
    rates = orders(errors)
    assert np.all(rates[:, 1] > 1.9) and np.all(rates[:, 1] < 2.2), (errors, rates)
    assert rates[0, 0] > 1.7 and 1.9 < rates[1, 0] < 2.2, (errors, rates)
    assert errors[-1][0] < 6e-5 and errors[-1][1] < 6e-5, errors


def test_mandel_series():
    """The series of Mandel's problem: its roots, the undrained start, the drained end, the
    drained side and the two displacements at t → 0 and t → ∞."""
    c = mandel_parameters(1e9, 0.2, 1.0, 1e10, 1e-11, 1.0, 1e6)
    assert c["c"] == pytest.approx(1e-2, rel=1e-12)  # (k/η) M K_v / (K_v + b² M)
    alpha = mandel_roots(c["nu"], c["nu_u"], 200)
    C = (1 - c["nu"]) / (c["nu_u"] - c["nu"])
    assert np.allclose(np.sin(alpha), C * alpha * np.cos(alpha), rtol=0, atol=1e-12 * alpha)
    assert np.all(np.diff(alpha) > 3.0)
    x = np.linspace(0.0, 0.8, 9)
    assert mandel_pressure(x, 1e-3, c) == pytest.approx(c["p0"], rel=2e-3)
    assert mandel_pressure(1.0, 5.0, c) == pytest.approx(0.0, abs=1e-9 * c["p0"])
    assert mandel_pressure(0.0, 5.0, c) > 1.09 * c["p0"]  # Mandel–Cryer
    assert np.all(mandel_pressure(x, 1e4, c) < 1e-12 * c["p0"])
    mu, F = c["mu"], c["F"]
    assert mandel_displacement_z(1.0, 1e-3, c) == pytest.approx(
        -F * (1 - c["nu_u"]) / (2 * mu), rel=2e-3)
    assert mandel_displacement_x(1.0, 1e-3, c) == pytest.approx(F * c["nu_u"] / (2 * mu),
                                                                rel=2e-3)
    assert mandel_displacement_z(1.0, 1e4, c) == pytest.approx(-F * (1 - c["nu"]) / (2 * mu))
    assert mandel_displacement_x(1.0, 1e4, c) == pytest.approx(F * c["nu"] / (2 * mu))
    # the scene functions are these series
    p = {"a": 1.0, "F": 1e6, "E": 1e9, "nu": 0.2, "b": 1.0, "M": 1e10, "k": 1e-11}
    args = "a, F, E, nu, b, M, k"
    points = np.column_stack([x, np.zeros_like(x), np.full_like(x, 0.25)])
    uz = compile_expression(f"mandel_uz(z, t, {args})", p)
    assert uz(points, 3.0) == pytest.approx(mandel_displacement_z(0.25, 3.0, c))
    p0 = compile_expression(f"mandel_p(x, 0, {args})", p)
    assert np.all(p0(points) == c["p0"])


@pytest.mark.slow
def test_mandel3d_pressure_and_mandel_cryer_effect(tmp_path):
    """Mandel's slab (294 tetrahedra, 50 steps of 1 s): the pressure at c t/a² = 0.1 and 0.5
    within 2 % (L² over the cells) of the series, the horizontal displacement of the drained
    side within 1 %, and at the centre the pressure rises above its undrained value p₀ (peak
    1.089 p₀ at t = 7 s; the series at the same cells 1.097) before it decays."""
    scene, out, summary = run(tmp_path, MANDEL3D)
    times = read_series(out, "flow").times
    for t, tol in ((10.0, 0.015), (50.0, 0.012)):
        e = mandel_errors(scene, out, times.index(t))
        assert e["pressure"] < tol and e["ux"] < 0.01, e
    centre = [mandel_errors(scene, out, k) for k in range(len(times))]
    peak = max(range(len(times)), key=lambda k: centre[k]["centre"])
    assert 3.0 <= times[peak] <= 8.0, times[peak]
    assert centre[peak]["centre"] > 1.08, centre[peak]
    assert abs(centre[peak]["centre"] - centre[peak]["centre_exact"]) < 0.01, centre[peak]
    assert centre[-1]["centre"] < 0.6


@pytest.mark.slow
def test_injection3d_opens_closes_and_conserves_mass(tmp_path):
    """The disc fracture (106 faces, mean_nitsche P2) is closed under the confining stress, opens
    completely under injection, closes after shut-in; every step conserves the fluid."""
    scene, out, summary = run(tmp_path, INJECTION3D)
    frac = read_series(out, "fractures")
    states = [frac.fields(k)["state"] for k in range(len(frac.times))]
    d0 = frac.fields(0)["aperture"]
    assert np.all(states[0] > 0)  # closed at t = 0 under the confining stress
    opened = [k for k, s in enumerate(states) if np.all(s == 0)]
    assert opened and frac.fields(opened[0])["aperture"].max() > 10 * d0.max()
    assert np.all(states[-1] > 0) and opened[-1] < len(states) - 1  # closed again
    dt = scene.time.final / scene.time.steps
    for k, rec in enumerate(summary["solves"], start=1):
        mb = rec["mass_balance"]
        assert mb["relative_residual"] < 1e-8
        change = fluid_volume(out, k) - fluid_volume(out, k - 1)
        assert change == pytest.approx(dt * (mb["sources"] - mb["outflow"]), rel=1e-7,
                                       abs=1e-12 * dt * abs(mb["sources"]) + 1e-18)


@pytest.mark.parametrize("darcy", ["direct", "iterative"])
def test_restart_reproduces_the_uninterrupted_run_3d(tmp_path, darcy):
    """The injected disc, four steps (it opens in the second): a run stopped by SIGTERM after
    its second step and continued with ``restart`` gives the uninterrupted run's contact
    states, apertures, pressures, displacement and fixed-point work, with the direct Darcy
    solver and with the iterative one, whose AMG is kept across the ``g`` of a step."""
    scene = load_scene(INJECTION3D, ["time.final=80", "time.steps=4",
                                     f"flow.linear_solver={darcy}"])
    full = run_scene(scene, tmp_path / "full")

    part = tmp_path / "part"
    with Run(scene, part, prepare=sigterm_after_steps(2)) as run_, \
            pytest.raises(stepping.Interrupted):
        run_.execute()
    summary = json.loads((part / "summary.json").read_text())
    assert summary["completed_steps"] == 2 and summary["status"].startswith("interrupted")
    resumed = run_scene(scene, part, restart=True)
    assert resumed["status"] == "converged" and len(resumed["solves"]) == 4
    assert_same_fixed_point(tmp_path / "full", part, rtol=1e-6)
    ua = read_series(tmp_path / "full", "displacement").fields(-1)["u"]
    ub = read_series(part, "displacement").fields(-1)["u"]
    assert np.abs(ua - ub).max() <= 1e-6 * np.abs(ua).max()
    assert full["coupling"]["g_evaluations"] == resumed["coupling"]["g_evaluations"]
    opened = read_series(part, "fractures").fields(2)["state"]
    assert np.all(opened == 0)  # the restart continued from an open fracture


@pytest.mark.mpi
def test_one_rank_equals_two_and_four_ranks_3d(tmp_path):
    """The injected disc, two steps (closed, then open) on 1, 2 and 4 ranks (more than the 2
    cores of CI): the same ``g`` evaluations and Newton iterations, and the same fields to
    solver tolerance."""
    out = {}
    for n in (1, 2, 4):
        out[n] = tmp_path / f"n{n}"
        cmd = [mpirun(), "-n", str(n), sys.executable, "-m", "poromech", "run", str(INJECTION3D),
               "-q", "--set", "time.final=40", "--set", "time.steps=2", "-o", str(out[n])]
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=900)
        assert proc.returncode == 0, proc.stderr[-3000:]
    s1 = json.loads((out[1] / "summary.json").read_text())
    f1 = read_series(out[1], "fractures").fields(-1)
    assert np.all(f1["state"] == 0)
    for n in (2, 4):
        sn = json.loads((out[n] / "summary.json").read_text())
        assert sn["mpi_ranks"] == n
        for a, b in zip(s1["solves"], sn["solves"], strict=True):
            assert a["g_evaluations"] == b["g_evaluations"], n
            assert abs(a["newton_iterations"] - b["newton_iterations"]) <= 2, n
        assert np.array_equal(f1["state"], read_series(out[n], "fractures").fields(-1)["state"])
        for stem, name in (("flow", "p_m"), ("fractures", "jump_n"), ("fractures", "p_f"),
                           ("fractures", "aperture"), ("displacement", "u")):
            a, b = (read_series(out[k], stem).fields(-1)[name] for k in (1, n))
            assert np.abs(a - b).max() <= 1e-6 * np.abs(a).max(), (n, stem, name)


def test_p_multigrid_falls_back_to_sor_sweeps_where_chebyshev_stalls(tmp_path):
    """The fault scene's coarse P2 mesh: point-block Jacobi with Chebyshev stalls on the P2
    level (1 and 2 ranks), and so does Chebyshev with SOR on 2 ranks (SOR local to each rank;
    1,000 GMRES iterations from 1.1e9 to 6.6e7), where the run failed every step cut. The
    p-multigrid then falls back to plain SOR sweeps: 2 ranks converge and give 1 rank's
    fractures (1 rank keeps Chebyshev with SOR)."""
    import csv

    fault = ROOT / "configs" / "fault_reactivation3d.yaml"
    sets = ["mesh.size=60", "mesh.fracture_size=30", "mesh.zones=[]", "degree=2",
            "time.steps=1", "time.final=10000", "time.max_cuts=0", "output.xdmf=false"]
    rows, smoothers = {}, {}
    for n in (1, 2):
        out = tmp_path / f"n{n}"
        cmd = [mpirun(), "-n", str(n), sys.executable, "-m", "poromech", "run", str(fault), "-q",
               "-o", str(out), *[a for s in sets for a in ("--set", s)]]
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=900)
        assert proc.returncode == 0, proc.stderr[-3000:]
        summary = json.loads((out / "summary.json").read_text())
        smoothers[n] = summary["linear_solver"]["p_multigrid"]["fine_smoother"]
        with open(out / "fractures.csv") as f:
            rows[n] = list(csv.DictReader(f))
    assert smoothers == {1: "sor", 2: "richardson/sor"}
    assert [r["state"] for r in rows[1]] == [r["state"] for r in rows[2]]
    for key, rtol in (("jump_t", 1e-6), ("jump_n", 1e-5), ("traction_n", 1e-6), ("p_f", 1e-6)):
        a, b = (np.array([float(r[key]) for r in rows[n]]) for n in (1, 2))
        assert np.abs(a - b).max() <= rtol * np.abs(a).max(), key
