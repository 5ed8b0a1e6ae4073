"""The Python API of docs/api.md: load a scene with overrides, run it, read the results back;
the study example (scripts/study_example.py) on a coarse mesh; ``import poromech`` first."""

import csv
import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, load_script

import poromech
from poromech.errors import ConfigError
from poromech.io.results import STATES, open_results, read_table
from poromech.run import run_scene
from poromech.scene.loading import load_scene, load_scene_and_raw

COARSE = ["mesh.size=0.5", "mesh.fracture_size=0.2", "mesh.tip_size=0.1"]


def load_example():
    return load_script("study_example")


def test_study_example(tmp_path):
    """Two friction coefficients: one slips as the exact solution says, one sticks."""
    example = load_example()
    example.main(["--values", "0.5", "3", "--out", str(tmp_path / "runs"), "--docs",
                  str(tmp_path / "docs"), *(f"--set={s}" for s in COARSE)])
    rows = list(csv.DictReader(open(tmp_path / "docs" / "friction_sweep.csv")))
    assert [r["F"] for r in rows] == ["0.5", "3.0"]
    assert all(r["status"] == "converged" for r in rows)
    slip, stick = rows
    assert int(slip["slip_faces"]) == int(slip["faces"]) and int(stick["slip_faces"]) == 0
    assert float(slip["rel_l2_error"]) < 0.1
    assert abs(float(slip["max_slip"]) / float(slip["max_slip_exact"]) - 1) < 0.1
    assert float(stick["max_slip"]) < 1e-12
    assert (tmp_path / "docs" / "friction_sweep.png").stat().st_size > 10_000


def test_load_run_read(tmp_path):
    scene, raw = load_scene_and_raw("flow_six_fractures", [
        "mesh.size=0.25", "mesh.fracture_size=0.125", "time.steps=2", "output.every=1"])
    assert scene.name == "flow_six_fractures" and scene.time.steps == 2
    summary = run_scene(scene, tmp_path / "flow", raw=raw)
    res = open_results(tmp_path / "flow")
    assert res.summary == summary | {"wall_time": res.summary["wall_time"]}
    assert res.series_names == ("flow", "fractures_flow")
    assert res.times() == res.times("fractures_flow") == [0.0, 1000.0, 2000.0]
    flow = res.series("flow")
    p_m = flow.at(2000.0)["p_m"]
    assert p_m.shape == (len(flow.cells),) and 1e5 <= p_m.min() < p_m.max() <= 2e5 * (1 + 1e-9)
    assert res.probes == ("fracture_5", "y_0.5")
    probe = res.probe("y_0.5")
    assert sorted(set(probe["time"])) == [0.0, 1000.0, 2000.0]  # every output time
    probe = res.probe("y_0.5", time=2000.0)
    assert probe["x"][0] == 0.0 and np.isnan(probe["p_f"]).any()
    assert res.scene["name"] == "flow_six_fractures" and res.scene["time"]["steps"] == 2
    with pytest.raises(FileNotFoundError, match="no series 'displacement'"):
        res.series("displacement")
    with pytest.raises(FileNotFoundError, match="not a poromech output directory"):
        open_results(tmp_path)
    with pytest.raises(ConfigError):
        load_scene("flow_six_fractures", ["time.steps=0"])


def test_fracture_table(tmp_path):
    scene = load_scene("inclined_crack_slip", COARSE)
    run_scene(scene, tmp_path / "crack")
    res = open_results(tmp_path / "crack")
    rows = res.fractures(time=0.0)
    assert set(rows["state"]) <= set(STATES) and set(rows["fracture"]) == {"crack"}
    assert rows["jump_t"].dtype == np.float64 and len(rows["s"]) == res.summary["mesh"][
        "fracture_faces"]
    assert read_table(tmp_path / "crack" / "fractures.csv").keys() == rows.keys()
    assert res.scene is None  # run_scene stores the scene only when given raw


def test_import_poromech_loads_mpi_first():
    """``import poromech`` lets DOLFINx and petsc4py be imported next (a fresh interpreter)."""
    code = ("import poromech, dolfinx; from petsc4py import PETSc; "
            "print(dolfinx.__version__, PETSc.COMM_WORLD.size)")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.split()[1] == "1"
    assert poromech.__version__


def test_a_script_run_gets_the_petsc_checks_of_poromech_run(tmp_path):
    """``run_scene`` skipped the PETSc checks of ``poromech run``: a scene asking for
    ``snes_type: ksponly`` wrote a contact problem as converged after one linear step (slip
    1e5 times too small). Refused before meshing, as a ``ConfigError``, from the scene and from
    PETSc's options database."""
    from petsc4py import PETSc

    scene = load_scene("six_fractures_mechanics", [*COARSE, "solver.petsc={snes_type: ksponly}"])
    with pytest.raises(ConfigError, match="takes one linear step"):
        run_scene(scene, tmp_path / "a")
    assert not (tmp_path / "a").exists()  # nothing meshed or written
    opts = PETSc.Options()
    opts["mech_snes_linesearch_type"] = "bt"
    try:
        with pytest.raises(ConfigError, match="would search again"):
            run_scene(load_scene("six_fractures_mechanics", COARSE), tmp_path / "b")
    finally:
        opts.delValue("mech_snes_linesearch_type")


def test_a_restart_from_a_script_stores_the_scene_it_goes_on_with(tmp_path):
    """A run extended through the API by more steps kept the scene of its first part in
    ``poromech_scene.yaml``: ``Results.scene`` said 3 steps, and ``poromech run --restart`` of
    the folder was refused (the checkpoint ended after step 6)."""
    sets = [*COARSE, "degree=1", "output.xdmf=false"]
    scene, raw = load_scene_and_raw("injection", [*sets, "time.final=40", "time.steps=2"])
    run_scene(scene, tmp_path / "run", raw=raw)
    scene, raw = load_scene_and_raw("injection", [*sets, "time.final=80", "time.steps=4"])
    run_scene(scene, tmp_path / "run", raw=raw, restart=True)
    res = open_results(tmp_path / "run")
    assert res.summary["completed_steps"] == 4 and res.scene["time"] == {"final": 80,
                                                                          "steps": 4}
    # each part's first step and ranks (a restart on other ranks recorded only its own)
    assert res.summary["parts"] == [{"from_step": 0, "mpi_ranks": 1},
                                    {"from_step": 2, "mpi_ranks": 1}]
    again = subprocess.run([sys.executable, "-m", "poromech", "run", "-q", "--restart",
                            str(tmp_path / "run")], capture_output=True, text=True, timeout=600)
    assert again.returncode == 0, again.stderr


def test_a_script_restart_without_a_checkpoint_is_a_config_error(tmp_path):
    """``run_scene(restart=True)`` of a folder without a checkpoint raised h5py's error text;
    ``poromech run --restart`` says in one line that there is nothing to continue from."""
    with pytest.raises(ConfigError, match="wrote no checkpoint.h5"):
        run_scene(load_scene("six_fractures_mechanics", COARSE), tmp_path, restart=True)


def test_a_script_scene_with_a_relative_mesh_file_restarts_from_elsewhere(tmp_path, monkeypatch):
    """``scene_from_dict`` reads a relative file name from the working directory, but the
    stored ``poromech_scene.yaml`` kept the name, and ``poromech run --restart`` took it from
    the output folder: "there is no file .../run/my.msh"."""
    import shutil

    import yaml

    from poromech.scene.loading import scene_from_dict

    work = tmp_path / "work"
    work.mkdir()
    shutil.copy(ROOT / "meshes" / "six_fractures.msh", work / "my.msh")
    raw = yaml.safe_load((ROOT / "configs" / "six_fractures_msh.yaml").read_text())
    raw["geometry"]["mesh"]["file"] = "my.msh"
    raw.update(degree=1, time={"final": 200.0, "steps": 2}, output={"xdmf": False})
    monkeypatch.chdir(work)
    run_scene(scene_from_dict(raw), tmp_path / "run", raw=raw)
    stored = yaml.safe_load((tmp_path / "run" / "poromech_scene.yaml").read_text())
    assert stored["geometry"]["mesh"]["file"] == str((work / "my.msh").resolve())
    again = subprocess.run([sys.executable, "-m", "poromech", "run", "-q", "--restart",
                            str(tmp_path / "run")], capture_output=True, text=True, timeout=600,
                           cwd=tmp_path)
    assert again.returncode == 0, again.stderr
