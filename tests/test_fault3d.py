"""The shipped 3D fault-reactivation scene, coarse and short: it slips under injection, sticks
again after shut-in, conserves mass, and its probe reads the fault along its dip."""

import csv

import numpy as np
import pytest
from conftest import ROOT

from poromech.io.xdmf import read_series
from poromech.run import run_scene
from poromech.scene.loading import load_scene

SCENE = ROOT / "configs" / "fault_reactivation3d.yaml"
COARSE = ["mesh.size=80", "mesh.fracture_size=30", "mesh.zones=[]", "time.steps=6",
          "time.final=24000"]


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    out = tmp_path_factory.mktemp("fault3d")
    scene = load_scene(SCENE, COARSE)
    return scene, out, run_scene(scene, out)


def fault_faces(scene, series):
    """Faces of the fault (the first fracture) and their areas."""
    pts = np.asarray(scene.geometry.fractures[0].polygon, dtype=float)
    n = np.cross(pts[1] - pts[0], pts[2] - pts[0])
    n /= np.linalg.norm(n)
    x = series.points[series.cells]
    area = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    on = np.abs((x.mean(axis=1) - pts[0]) @ n) < 1e-3
    return on, area


def test_fault_slips_under_injection_and_sticks_after_shut_in(run):
    scene, out, summary = run
    assert summary["status"] == "converged"
    s = read_series(out, "fractures")
    on, area = fault_faces(scene, s)
    assert on.sum() > 100
    t = np.array(s.times)
    shut_in = int(np.flatnonzero(t == 20000.0)[0])
    slipping = [float(area[on] @ (s.fields(k)["state"][on] == 2)) for k in range(len(t))]
    slip = [float(area[on] @ s.fields(k)["jump_t"][on] / area[on].sum()) for k in range(len(t))]
    assert slipping[0] == 0 and slipping[1] < slipping[shut_in]  # the patch grows
    assert slipping[shut_in] > 0.05 * area[on].sum()
    assert np.all(np.diff(slip[: shut_in + 1]) > 0)  # slip accumulates while injecting
    assert slipping[-1] == 0  # every face sticks after shut-in
    # a stuck face moves only by the Nitsche compliance ΔT_τ/γ (a few % here)
    assert abs(slip[-1] - slip[shut_in]) < 0.15 * slip[shut_in] and slip[shut_in] > 2e-5
    for rec in summary["solves"]:
        assert rec["mass_balance"]["relative_residual"] < 1e-8
        assert rec["g_evaluations"] <= 10
    # the conjugate fault and the joint stay stuck
    assert np.all(s.fields(shut_in)["state"][~on] != 2)


def test_probe_reads_the_fault_along_its_dip(run):
    _, out, _ = run
    with open(out / "probe_fault_dip.csv") as f:
        rows = [r for r in csv.DictReader(f) if float(r["time"]) == 20000.0]
    assert len(rows) == 151
    p_f = np.array([float(r["p_f"]) for r in rows])
    p_m = np.array([float(r["p_m"]) for r in rows])
    assert np.all(np.isfinite(p_f)) and np.all(np.isfinite(p_m))
    centre = np.argmin([abs(float(r["arc_length"]) - 150.0) for r in rows])
    assert p_f[centre] > p_f[0] + 3e6  # overpressured at the injection point
