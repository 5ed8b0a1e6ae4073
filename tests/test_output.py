"""Crash-safe output: a killed, interrupted or disk-full run leaves readable files for every
completed step, a valid summary.json, and can be continued with ``--restart``."""

import csv
import json
import os
import signal
import subprocess
import sys
import textwrap
import time

import h5py
import meshio
import numpy as np
import pytest
from conftest import ROOT, sigterm_after_steps

from poromech.io.xdmf import read_series

SCENE = str(ROOT / "configs" / "six_fractures_mechanics.yaml")
POROMECH = [sys.executable, "-m", "poromech"]


def start(out, *args):
    return subprocess.Popen([*POROMECH, "run", SCENE, "-o", str(out), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)


def wait_for_steps(proc, out, steps, timeout=300):
    """Wait until summary.json reports ``steps`` completed steps."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        assert proc.poll() is None, proc.communicate()
        try:
            done = json.loads((out / "summary.json").read_text()).get("completed_steps", 0)
        except (FileNotFoundError, json.JSONDecodeError):
            done = 0
        if done >= steps:
            return
        time.sleep(0.05)
    proc.kill()
    pytest.fail("the run did not reach the wanted step in time")


def check_readable(out, stems=("displacement", "fractures")) -> int:
    """Every step listed in each index opens with h5py and meshio; returns the smallest count."""
    counts = set()
    for stem in stems:
        series = read_series(out, stem)
        for k in range(len(series.times)):
            fields = series.fields(k)
            assert fields and all(np.all(np.isfinite(v)) for v in fields.values())
            with h5py.File(series.files[k]) as f:
                assert set(f.keys()) == set(fields)
        with meshio.xdmf.TimeSeriesReader(out / f"{stem}.xdmf") as reader:
            reader.read_points_cells()
            assert reader.num_steps == len(series.times)
            for k in range(reader.num_steps):
                reader.read_data(k)
        counts.add(len(series.times))
    # a kill between the writes of two series of one step leaves them one step apart
    assert max(counts) - min(counts) <= 1, counts
    return min(counts)


def test_kill_9_then_restart_reproduces_the_run(tmp_path):
    full, part = tmp_path / "full", tmp_path / "part"
    steps = ["--set", "time.steps=8"]
    proc = start(part, *steps)
    wait_for_steps(proc, part, 3)
    os.kill(proc.pid, signal.SIGKILL)
    proc.communicate()
    summary = json.loads((part / "summary.json").read_text())
    assert summary["status"] == "running" and summary["completed_steps"] >= 3
    listed = check_readable(part)
    assert listed >= summary["completed_steps"]
    assert len(summary["solves"]) == summary["completed_steps"]
    # continue the killed run, then run it uninterrupted: same fields
    resumed = subprocess.run([*POROMECH, "run", "--restart", str(part), "-q"], cwd=ROOT,
                             capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr
    proc = subprocess.run([*POROMECH, "run", SCENE, "-o", str(full), "-q", *steps], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert check_readable(part) == check_readable(full) == 8
    a, b = (json.loads((d / "summary.json").read_text()) for d in (full, part))
    # the checkpoint is written last in a step: a kill during it restarts one step earlier
    assert b["status"] == "converged"
    assert b["restarted_from"]["step"] >= summary["completed_steps"] - 1 >= 2
    assert [r["iterations"] for r in a["solves"]] == [r["iterations"] for r in b["solves"]]
    for stem, name in (("displacement", "u"), ("fractures", "jump_t")):
        fa, fb = read_series(full, stem).fields(-1)[name], read_series(part, stem).fields(-1)[name]
        assert np.abs(fa - fb).max() <= 1e-8 * np.abs(fa).max()
    rows = (part / "fractures.csv").read_text().splitlines()
    assert len(rows) == 1 + 8 * a["mesh"]["fracture_faces"]  # no step written twice
    # a restart of the finished run has nothing to do; its summary still counts the steps
    # (it lost completed_steps)
    again = subprocess.run([*POROMECH, "run", "--restart", str(part), "-q"], cwd=ROOT,
                           capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr
    c = json.loads((part / "summary.json").read_text())
    assert c["status"] == "converged" and c["completed_steps"] == 8 and len(c["solves"]) == 8
    assert (part / "fractures.csv").read_text().splitlines() == rows


@pytest.mark.parametrize("signum, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_stops_cleanly_at_a_step_boundary(tmp_path, signum, code):
    out = tmp_path / "run"
    proc = start(out, "--set", "time.steps=40")
    wait_for_steps(proc, out, 1)
    proc.send_signal(signum)
    out_text, err = proc.communicate(timeout=300)
    assert proc.returncode == code, err
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and signal.Signals(signum).name in lines[0], err
    # heard at once (a step may take minutes), once
    assert out_text.count(f"{signal.Signals(signum).name} received: the run stops after the "
                          "step being solved") == 1, out_text
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("interrupted")
    assert check_readable(out) == summary["completed_steps"] < 40


def test_disk_full_is_one_line_and_keeps_completed_steps(tmp_path):
    """A file-size limit (set after MPI start-up) makes a write fail like a full disk.

    The limit is above every file a step writes anew (the mesh of displacement.h5, 389 kB, and
    the checkpoint, 310 kB since it holds a row per dof block; it was the checkpoint that
    exceeded it before), so that fractures.csv, which grows by 10 kB a step, reaches it
    after about 40 steps.
    """
    out = tmp_path / "full_disk"
    code = textwrap.dedent(f"""
        import resource, sys
        import dolfinx_solver
        from mpi4py import MPI
        resource.setrlimit(resource.RLIMIT_FSIZE, (400_000, resource.RLIM_INFINITY))
        from poromech.cli import main
        sys.exit(main(["run", {SCENE!r}, "-o", {str(out)!r}, "--set", "time.steps=80"]))
    """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          cwd=ROOT, timeout=600)
    assert proc.returncode == 1, proc.stderr
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and "could not write" in lines[0] and "File too large" in lines[0]
    assert "fractures.csv" in lines[0]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("error: OutputError")
    assert check_readable(out) >= summary["completed_steps"] >= 1
    assert not list(out.rglob(".*.part"))


def test_a_run_that_fails_before_its_first_output_step_writes_no_empty_index(tmp_path):
    """A temporal XDMF collection with no grid made VTK's XDMF reader (ParaView's "XDMF
    Reader") report an error and crash; a run that stops before its first output step now
    writes no index at all, and the first completed step writes it."""
    from poromech.cli import main

    out = tmp_path / "failed"
    assert main(["run", str(ROOT / "configs" / "six_fractures_mechanics.yaml"), "-q", "-o",
                 str(out), "--set", "solver.petsc.snes_max_it=1", "--set",
                 "time.max_cuts=0"]) == 3
    assert list(out.glob("*.h5")) and not list(out.glob("*.xdmf"))
    assert json.loads((out / "summary.json").read_text())["status"].startswith("failed")


def test_a_restart_keeps_the_rows_of_a_time_that_prints_rounded_up(tmp_path):
    """Stopped after step 1 of 3 to 500 s, t = 166.66666666666666 s, which fractures.csv prints
    as 166.666667 and the probe as 166.666666667, both above it: the restart cut those rows as
    later than the restart time, and the tables lost the step without a word."""
    from poromech import stepping
    from poromech.run import Run, run_scene
    from poromech.scene.loading import load_scene

    scene = load_scene(SCENE, ["time.steps=3", "output.xdmf=false",
                               "probes=[{name: diag, start: [0.1, 0.1], end: [1.9, 0.9], "
                               "samples: 7}]"])
    run_scene(scene, tmp_path / "full")

    with Run(scene, tmp_path / "part", prepare=sigterm_after_steps(1)) as run, \
            pytest.raises(stepping.Interrupted):
        run.execute()
    rows = (tmp_path / "part" / "fractures.csv").read_text().splitlines()
    assert rows[-1].startswith("166.666667,")
    run_scene(scene, tmp_path / "part", restart=True)
    for name in ("fractures.csv", "probe_diag.csv"):
        full, part = ((tmp_path / d / name).read_text() for d in ("full", "part"))
        assert part == full, name


def test_a_signal_during_the_initial_state_stops_after_it(tmp_path):
    """SIGTERM while the initial equilibrium under p⁰ is solved: the run died at once with
    nothing written (no summary.json). It now stops after the initial state, with the outputs
    of t = 0 and an 'interrupted' summary of 0 completed steps. (In a child process: before the
    fix the signal killed it.)"""
    out = tmp_path / "run"
    code = textwrap.dedent(f"""
        import signal
        from poromech import stepping
        from poromech.run import Run
        from poromech.scene.loading import load_scene

        scene = load_scene({str(ROOT / "configs" / "fault_reactivation.yaml")!r},
                           ["time.steps=4"])

        def signal_in_initialize(physics):
            initialize = physics.initialize

            def initialize_and_signal():
                signal.raise_signal(signal.SIGTERM)  # heard while the initial state is solved
                return initialize()

            physics.initialize = initialize_and_signal

        try:
            with Run(scene, {str(out)!r}, prepare=signal_in_initialize) as run:
                run.execute()
        except stepping.Interrupted:
            print("interrupted")
    """)
    proc = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0 and "interrupted" in proc.stdout, (proc.returncode, proc.stderr)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"].startswith("interrupted") and summary["completed_steps"] == 0
    assert summary["initial"]["reason"].startswith("CONVERGED")
    assert read_series(out, "displacement").times == [0.0]


def test_face_coordinates_far_from_the_origin_keep_their_resolution(tmp_path):
    """A scene moved to UTM coordinates (y = 4e6 m) writes the same face midpoints, shifted, to
    1e-6 m: with 9 digits its 1 m box printed them to 1 mm (0.1 m at this offset's decade) and
    faces shared values. At the origin the columns keep their 9 digits."""
    from conftest import mechanics_scene, network_geometry

    from poromech.run import Run
    from poromech.scene.loading import scene_from_dict

    shift = np.array([500000.0, 4000000.0])
    tables = []
    for name, d in (("origin", np.zeros(2)), ("utm", shift)):
        geometry = network_geometry()
        x0, y0, x1, y1 = geometry["domain"]["rectangle"]
        geometry["domain"]["rectangle"] = [x0 + d[0], y0 + d[1], x1 + d[0], y1 + d[1]]
        for f in geometry["fractures"]:
            f["points"] = [[p[0] + d[0], p[1] + d[1]] for p in f["points"]]
        raw = mechanics_scene(geometry=geometry, degree=1, time={"final": 1.0, "steps": 1},
                              output={"xdmf": False}, mesh={"size": 0.2, "fracture_size": 0.1})
        with Run(scene_from_dict(raw), tmp_path / name) as run:
            run.execute()
        with open(tmp_path / name / "fractures.csv") as fh:
            rows = list(csv.reader(fh))[1:]
        tables.append((rows, np.array([[float(r[3]), float(r[4])] for r in rows])))
    (rows0, xy0), (rows1, xy1) = tables
    assert len(rows0) == len(rows1) > 20
    assert np.abs(xy1 - shift - xy0).max() <= 1e-6
    assert len({(r[3], r[4]) for r in rows1}) == len(rows1)
    assert max(len(r[3].replace(".", "").lstrip("0")) for r in rows0) <= 9


@pytest.mark.parametrize("degree", [1, 2])
def test_displacement_points_are_the_mesh_points_to_the_bit(tmp_path, degree):
    """The points of displacement.xdmf were tabulated dof coordinates: the top nodes of the
    six-fracture box at y = 1 - 1.1e-16, the two copies of a crack node up to 2.2e-16 apart,
    and ParaView's probes found no cell there. Now the mesh's vertices and the means of its
    edges' vertices: every boundary node on its side exactly, every crack node's two copies at
    one point."""
    out = tmp_path / "run"
    proc = subprocess.run([*POROMECH, "run", SCENE, "-o", str(out), "-q", "--set",
                           "time.steps=1", "--set", f"degree={degree}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    x = read_series(out, "displacement").points[:, :2]
    near = np.abs(x[:, 1] - 1.0) < 1e-12
    assert near.sum() > 10 and np.all(x[near, 1] == 1.0)
    near = np.abs(x[:, 0] - 2.0) < 1e-12
    assert near.sum() > 10 and np.all(x[near, 0] == 2.0)
    exact = len(np.unique(x, axis=0))
    rounded = len(np.unique(np.round(x, 12), axis=0))
    assert exact == rounded < len(x)  # the copies of the crack nodes coincide exactly


def _extend(out, **time):
    """Give the scene stored in ``out`` more steps (or other changes), as a user does."""
    import yaml

    path = out / "poromech_scene.yaml"
    raw = yaml.safe_load(path.read_text())
    raw["time"].update(time)
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return raw, path


def test_a_restart_goes_on_with_the_petsc_options_of_its_run(tmp_path):
    """``-mech_snes_rtol 1e-3`` given to a run was dropped by its ``--restart``: steps 6-10
    took 6,6,2,2,2 Newton iterations where the uninterrupted run took 2,0,2,0,1, and nothing
    said so. The restart now runs with them (and records each part's)."""
    opts = ["-mech_snes_rtol", "1e-3"]
    full, part = tmp_path / "full", tmp_path / "part"
    sets = ["--set", "time.final=1000.0"]
    for out, steps in ((full, "10"), (part, "5")):
        proc = subprocess.run([*POROMECH, "run", SCENE, "-q", "-o", str(out), *sets, "--set",
                               f"time.steps={steps}", "--set", f"time.final={100 * int(steps)}",
                               *opts], capture_output=True, text=True, cwd=ROOT, timeout=600)
        assert proc.returncode == 0, proc.stderr
    _extend(part, final=1000.0, steps=10)
    proc = subprocess.run([*POROMECH, "run", "--restart", str(part)], capture_output=True,
                          text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr
    assert "goes on with the PETSc options of the run it continues: -mech_snes_rtol 1e-3" \
        in proc.stdout
    a, b = (json.loads((o / "summary.json").read_text()) for o in (full, part))
    assert [s["iterations"] for s in a["solves"]] == [s["iterations"] for s in b["solves"]]
    assert b["parts"] == [{"from_step": 0, "mpi_ranks": 1,
                           "petsc_options": {"mech_snes_rtol": "1e-3"}},
                          {"from_step": 5, "mpi_ranks": 1,
                           "petsc_options": {"mech_snes_rtol": "1e-3"}}]


def test_a_refused_restart_leaves_the_run_and_its_summary(tmp_path):
    """A restart refused for another mesh rewrote summary.json as an error with no step (the
    XDMF and CSV still held 4); and a geometry scaled by 2 with its mesh sizes, whose mesh has
    as many cells and vertices, was accepted and went on on the other mesh."""
    out = tmp_path / "run"
    proc = subprocess.run([*POROMECH, "run", "injection", "-q", "-o", str(out), "--set",
                           "time.steps=2", "--set", "time.final=100", "--set", "degree=1"],
                          capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stderr
    before = (out / "summary.json").read_text()
    raw, path = _extend(out, steps=4, final=200)
    scaled = json.loads(json.dumps(raw))
    ((x0, y0, x1, y1),) = scaled["geometry"]["domain"].values()
    scaled["geometry"]["domain"] = {"rectangle": [2 * x0, 2 * y0, 2 * x1, 2 * y1]}
    for f in scaled["geometry"]["fractures"]:
        f["points"] = [[2 * x, 2 * y] for x, y in f["points"]]
    for k in ("size", "fracture_size", "tip_size", "transition"):
        if k in (scaled.get("mesh") or {}):
            scaled["mesh"][k] = 2 * scaled["mesh"][k]
    import yaml

    for changed, message in ((scaled, "at other places"),
                             ({**raw, "mesh": {**raw["mesh"], "size": 0.1}}, "another mesh")):
        path.write_text(yaml.safe_dump(changed, sort_keys=False))
        proc = subprocess.run([*POROMECH, "run", "--restart", str(out)], capture_output=True,
                              text=True, cwd=ROOT, timeout=600)
        assert proc.returncode == 2 and message in proc.stderr, proc.stderr
        assert (out / "summary.json").read_text() == before
