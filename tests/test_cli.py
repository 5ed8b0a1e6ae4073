"""The command line: outputs of a run, a run that does not converge, PETSc options, MPI."""

import csv
import json
import subprocess
import sys

import h5py
import numpy as np
from conftest import ROOT, mpirun

from poromech.io.output import CSV_COLUMNS

POROMECH = [sys.executable, "-m", "poromech"]


def run(args, cwd=ROOT, timeout=600):
    return subprocess.run(POROMECH + args, capture_output=True, text=True, cwd=cwd,
                          timeout=timeout)


def test_default_scene_outputs(tmp_path):
    """The default scene is the paper's coupled six-fracture scene; two steps of T/2."""
    out = tmp_path / "out"
    proc = run(["run", "-o", str(out), "--set", "time.steps=2"])
    assert proc.returncode == 0, proc.stderr
    for name in ("displacement.xdmf", "displacement.h5", "fractures.xdmf", "fractures.h5",
                 "fractures.csv", "flow.xdmf", "flow.h5", "summary.json", "checkpoint.h5",
                 "poromech_scene.yaml"):
        assert (out / name).exists(), name
    summary = json.loads((out / "summary.json").read_text())
    assert summary["scene"] == "six_fractures" and summary["status"] == "converged"
    assert summary["physics"] == "poromechanics" and summary["completed_steps"] == 2
    assert summary["formulation"] == "mixed" and summary["degree"] == 2
    assert summary["mpi_ranks"] == 1 and summary["dofs"] > 10000
    assert summary["initial"]["reason"].startswith("CONVERGED")
    # the condensed solve's work at t = 0 (the log said "0 Newton iterations")
    assert summary["initial"]["iterations"] == 0 and summary["initial"]["face_iterations"] > 0
    assert len(summary["solves"]) == 2
    for s in summary["solves"]:
        assert s["converged"] and s["reason"].startswith("CONVERGED")
        assert s["g_evaluations"] == len(s["residuals"]) == len(s["newton_per_evaluation"])
        assert s["residuals"][-1] <= 1e-5 * s["residuals"][0]
        assert s["mass_balance"]["relative_residual"] < 1e-8
    totals = summary["coupling"]
    assert totals["g_evaluations"] == sum(s["g_evaluations"] for s in summary["solves"])
    assert {"mesh", "setup", "assembly", "linear_solve", "output", "total"} <= set(
        summary["wall_time"])
    rows = list(csv.reader(open(out / "fractures.csv")))
    assert tuple(rows[0]) == (*CSV_COLUMNS, "p_f", "aperture")
    faces = summary["mesh"]["fracture_faces"]
    assert len(rows) == 1 + 3 * faces  # t = 0 (the initial equilibrium), T/2, T
    assert {r[9] for r in rows[1:]} <= {"open", "stick", "slip"}
    assert {r[1] for r in rows[1:]} == {"1", "2", "3", "4", "5", "6"}
    assert all(float(r[11]) > 0 for r in rows[1:])  # apertures
    # the duplicated-node output mesh has more points than the connected mesh has vertices
    with h5py.File(out / "displacement.h5") as f:
        points = f["mesh/points"].shape[0]
    steps = sorted((out / "displacement_steps").glob("*.h5"))
    with h5py.File(steps[-1]) as f:
        u = np.asarray(f["u"])
    assert points > summary["mesh"]["vertices"]
    assert len(steps) == 3 and np.all(np.isfinite(u)) and np.abs(u).max() > 1e-3
    flow = sorted((out / "flow_steps").glob("*.h5"))
    with h5py.File(flow[-1]) as f:
        assert {"p_m", "u_m", "overpressure", "porosity"} <= set(f)
    assert "poromech" in proc.stdout and "step 2/2" in proc.stdout


def test_quiet_and_petsc_option(tmp_path):
    proc = run(["run", "configs/sneddon.yaml", "-q", "-o", str(tmp_path / "q"),
                "-mech_ksp_type", "preonly", "--set", "output.xdmf=false"])
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == ""
    assert not (tmp_path / "q" / "displacement.xdmf").exists()


def test_non_convergence_keeps_results_and_exits_3(tmp_path):
    """Step 1 sticks (one Newton iteration), step 2 must slip but gets one iteration only."""
    out = tmp_path / "fail"
    proc = run(["run", "configs/inclined_crack_slip.yaml", "-o", str(out),
                "--set", "contact.friction=tresca",
                "--set", "contact.slip_bound=where(t < 1.5, 1e12, 1e5)",
                "--set", "time={final: 2.0, steps: 2}",
                "-mech_snes_max_it", "1"])
    assert proc.returncode == 3, proc.stdout + proc.stderr
    assert "DIVERGED_MAX_IT" in proc.stderr and "residual history" in proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("failed")
    assert summary["solves"][0]["converged"]
    rows = list(csv.reader(open(out / "fractures.csv")))
    assert len(rows) > 1 and {r[0] for r in rows[1:]} == {"1"}


def test_parallel_run_matches_serial(tmp_path):
    args = ["run", "-q", "--set", "time.steps=1", "--set", "output.xdmf=false"]
    serial = run(args + ["-o", str(tmp_path / "s")])
    assert serial.returncode == 0, serial.stderr
    par = subprocess.run([mpirun(), "-n", "2", *POROMECH, *args, "-o", str(tmp_path / "p")],
                         capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert par.returncode == 0, par.stderr
    a = list(csv.reader(open(tmp_path / "s" / "fractures.csv")))[1:]
    b = list(csv.reader(open(tmp_path / "p" / "fractures.csv")))[1:]
    assert len(a) == len(b)
    va = np.array([[float(v) for v in r[5:9]] for r in a])
    vb = np.array([[float(v) for v in r[5:9]] for r in b])
    scale = np.abs(va).max(axis=0)
    assert np.all(np.abs(va - vb).max(axis=0) <= 1e-6 * scale)
    assert [r[9] for r in a] == [r[9] for r in b]
    sa = json.loads((tmp_path / "s" / "summary.json").read_text())
    sb = json.loads((tmp_path / "p" / "summary.json").read_text())
    assert sb["mpi_ranks"] == 2 and sa["dofs"] == sb["dofs"]
    assert sa["solves"][0]["iterations"] == sb["solves"][0]["iterations"]


def test_superlu_dist_makes_parallel_runs_repeat_bit_for_bit(tmp_path):
    """README's recipe for bitwise repeatable runs on several ranks: SuperLU_DIST in place of
    MUMPS, whose parallel factorization sums in an order that changes from run to run (the
    coupled default scene on 2 ranks: 4 different ``fractures.csv`` in 4 runs with MUMPS)."""
    args = ["run", "-q", "--set", "time.steps=2", "--set", "output.xdmf=false",
            "-mech_pc_factor_mat_solver_type", "superlu_dist",
            "-flow_pc_factor_mat_solver_type", "superlu_dist"]
    tables = []
    for name in ("a", "b"):
        par = subprocess.run([mpirun(), "-n", "2", *POROMECH, *args, "-o", str(tmp_path / name)],
                             capture_output=True, text=True, cwd=ROOT, timeout=600)
        assert par.returncode == 0, par.stderr
        assert "not used" not in par.stderr  # both options reached their solver
        tables.append((tmp_path / name / "fractures.csv").read_bytes())
    assert tables[0] == tables[1] and tables[0].count(b"\n") > 1


def test_parallel_non_convergence_does_not_hang(tmp_path):
    proc = subprocess.run(
        [mpirun(), "-n", "2", *POROMECH, "run", "-q", "-o", str(tmp_path / "f"),
         "--set", "time.steps=1", "--set", "contact.formulation=nitsche",
         "-mech_snes_max_it", "1"],
        capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 3
    assert proc.stderr.count("did not converge") == 1  # reported once, by rank 0
    summary = json.loads((tmp_path / "f" / "summary.json").read_text())
    assert summary["completed_steps"] == 0  # the key was missing when the first step failed


# -- exit status, output directory, shipped scenes ------------------------------------------------
def test_exit_0_flow_run_rerun_and_unused_option(tmp_path):
    """A run exits 0 and warns about an unused PETSc option; a rerun needs --overwrite."""
    out = tmp_path / "flow"
    args = ["run", "flemisch_case2", "-o", str(out), "--set", "output.xdmf=false"]
    # a misspelled scene option was not reported at all; one the solver reads is not reported
    scene_opts = "flow.petsc={ksp_rtol: 1e-10, pc_typ: gamg}"
    proc = run(args + ["--set", scene_opts, "-mech_snes_monitr"], cwd=tmp_path)  # shipped name
    assert proc.returncode == 0, proc.stderr
    assert "-mech_snes_monitr were not used" in proc.stdout
    assert "scene key(s) flow.petsc.pc_typ were not used by any solver" in proc.stdout
    assert json.loads((out / "summary.json").read_text())["status"] == "converged"
    (out / "flow_steps").mkdir()  # a stale output of an earlier, longer run
    proc = run(args, cwd=tmp_path)
    assert proc.returncode == 2 and "--overwrite" in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1
    proc = run(args + ["--overwrite", "-q"], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    assert not (out / "flow_steps").exists() and (out / "summary.json").exists()


def test_exit_1_on_an_io_error_during_the_run(tmp_path):
    """A file-size limit (a full quota) makes writing the probe file fail: one line, status 1."""
    code = ("import resource, sys\n"
            "import dolfinx_solver\n"
            "from mpi4py import MPI\n"
            "resource.setrlimit(resource.RLIMIT_FSIZE, (4096, resource.RLIM_INFINITY))\n"
            "from poromech.cli import main\n"
            "sys.exit(main(sys.argv[1:]))\n")
    out = tmp_path / "o"
    base = [sys.executable, "-c", code, "run", "flemisch_case2", "-o", str(out),
            "--set", "output.xdmf=false"]
    proc = subprocess.run(base + ["-q"], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 1, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, lines
    assert "could not write" in lines[0] and "probe_x_0.5.csv: File too large" in lines[0]
    assert f"readable in {out}" in lines[0]
    assert "Traceback" not in proc.stderr


def test_scenes_show_and_version(tmp_path):
    proc = run(["scenes"], cwd=tmp_path)
    assert proc.returncode == 0
    listed = dict(line.split(None, 1) for line in proc.stdout.strip().splitlines())
    assert "sneddon" in listed and "Sneddon" in listed["sneddon"]
    assert set(listed) == {p.stem for p in (ROOT / "configs").glob("*.yaml")}
    proc = run(["show", "sneddon"], cwd=tmp_path)
    assert proc.returncode == 0
    assert proc.stdout == (ROOT / "configs" / "sneddon.yaml").read_text()
    proc = run(["validate", "sneddon.yaml"], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    proc = run(["show", "nosuchscene"], cwd=tmp_path)
    assert proc.returncode == 2 and "poromech scenes" in proc.stderr
    proc = run(["--version"])
    assert proc.returncode == 0 and proc.stdout.startswith("poromech 0.1.0")


def test_a_probe_along_a_crack_reads_its_plus_side(tmp_path):
    """Sneddon's crack from (-1, 0) to (1, 0): n⁺ = (0, 1), the + side below. A probe along it
    read u from the cell of smallest input index, alternating sides (u_y +1.7e-3 and -1.8e-3
    m at neighbouring points); now every point reads the + side, as a probe 1e-7 m below does,
    on 1 and 2 ranks."""
    line = "[{name: along, start: [-0.95, 0], end: [0.95, 0], samples: 20}, " \
           "{name: below, start: [-0.95, -1e-7], end: [0.95, -1e-7], samples: 20}]"
    args = ["run", "sneddon", "-q", "--set", "output.xdmf=false", "--set", f"probes={line}"]
    tables = {}
    for ranks in (1, 2):
        out = tmp_path / str(ranks)
        launch = [mpirun(), "-n", "2", *POROMECH] if ranks == 2 else POROMECH
        proc = subprocess.run([*launch, *args, "-o", str(out)], capture_output=True, text=True,
                              cwd=ROOT, timeout=600)
        assert proc.returncode == 0, proc.stderr
        for name in ("along", "below"):
            rows = list(csv.DictReader(open(out / f"probe_{name}.csv")))
            tables[ranks, name] = np.array([float(r["u_y"]) for r in rows])
    on, below = tables[1, "along"], tables[1, "below"]
    assert np.all(on < 0.0) and np.abs(on - below).max() <= 1e-4 * np.abs(below).max()
    assert np.abs(tables[2, "along"] - on).max() <= 1e-9 * np.abs(on).max()


def test_a_signal_while_setting_up_stops_with_one_line_and_a_summary(tmp_path):
    """SIGTERM while the mesh and the physics are built (minutes in 3D) ended the run without a
    word or a summary.json (SIGINT: a traceback); now it stops at once like a stop at a step
    boundary: status 128 + 15, one line, the summary says interrupted."""
    script = tmp_path / "signal_setup.py"
    out = tmp_path / "out"
    script.write_text(
        "import os, signal, sys\n"
        "import dolfinx_solver\n"
        "import poromech.cli as cli\n"
        "import poromech.run as run\n"
        "init = run.Run.__init__\n"
        "def term(physics):\n"
        "    os.kill(os.getpid(), signal.SIGTERM)\n"
        "def patched(self, *args, **kwargs):\n"
        "    init(self, *args, **kwargs, prepare=term)\n"
        "run.Run.__init__ = patched\n"
        f"sys.exit(cli.main(['run', 'sneddon', '-q', '-o', {str(out)!r}]))\n")
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True,
                          cwd=ROOT, timeout=300)
    assert proc.returncode == 128 + 15, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "stopped by SIGTERM while setting up" in lines[0], proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("interrupted: stopped by SIGTERM while setting up")
