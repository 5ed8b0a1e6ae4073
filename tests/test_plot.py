"""Pictures (poromech.io.plot, ``poromech plot``) and the outputs as VTK reads them (pyvista).

The pyvista check is the test-suite twin of ``scripts/paraview_check.py``: every series of a
mechanics, a flow and a coupled run, and of a run killed with SIGKILL, loads through VTK's XDMF
reader with the index's time steps and exactly the stored arrays.
"""

import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from conftest import ROOT

from poromech.io.plot import (
    MAX_PNG_BYTES,
    choose_backend,
    fracture_edges,
    mesh_edges,
    nice_scale,
    plot_run,
)
from poromech.io.results import open_results
from poromech.run import run_scene
from poromech.scene.loading import load_scene

#: Coarse meshes of the six-fracture network (~300 cells): each run takes a second or two.
TINY = ["mesh.size=0.25", "mesh.fracture_size=0.125"]
RUNS = {
    "coupled": ("six_fractures", ["time.steps=2", "time.final=200"]),  # P2, flow + mechanics
    "mech": ("six_fractures_mechanics", ["time.steps=2", "degree=1"]),  # P1
    "flow": ("flow_six_fractures", ["time.steps=2", "output.every=1"]),
}


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("runs")
    for name, (scene, extra) in RUNS.items():
        summary = run_scene(load_scene(scene, [*TINY, *extra]), root / name)
        assert summary["status"] == "converged"
    return {name: root / name for name in RUNS}


# -- geometry: exact on the written data -----------------------------------------------------
def face_mean_jumps(disp, frac, step=-1):
    """(jump_n, jump_t) per face from the two sides' nodes of the displacement mesh: the exact
    face means of the P1 (trapezoid) or P2 (Simpson) jump."""
    u = disp.fields(step)["u"][:, :2]
    e = fracture_edges(disp.points, disp.cells, frac.points)
    a, b = frac.points[0::2], frac.points[1::2]
    t = (b - a) / np.linalg.norm(b - a, axis=1)[:, None]
    n = np.column_stack([-t[:, 1], t[:, 0]])
    mean = np.zeros((len(frac.cells), 2, 2))
    for k, side in enumerate((1, -1)):
        for face in range(len(frac.cells)):
            edges = e.nodes[(e.face == face) & (e.side == side)]
            if len(edges) == 1:  # P1: one edge per side
                mean[face, k] = u[edges[0]].mean(axis=0)
            else:  # P2: two half-edges sharing the midpoint node
                (i, j), (p, q) = edges
                m = ({i, j} & {p, q}).pop()
                ends = list({i, j, p, q} - {m})
                mean[face, k] = (u[ends[0]] + u[ends[1]] + 4 * u[m]) / 6
    jump = mean[:, 0] - mean[:, 1]
    return np.einsum("ij,ij->i", jump, n), np.einsum("ij,ij->i", jump, t)


@pytest.mark.parametrize("run", ["coupled", "mech"])
def test_fracture_sides_give_the_written_jumps(runs, run):
    """Both sides of every face are found, on the side given by n⁺ (round-off)."""
    res = open_results(runs[run])
    disp, frac = res.series("displacement"), res.series("fractures")
    e = fracture_edges(disp.points, disp.cells, frac.points)
    per_side = np.bincount(2 * e.face + (e.side > 0), minlength=2 * len(frac.cells))
    assert set(per_side) == ({2} if run == "coupled" else {1})  # P2: two half-edges per side
    jn, jt = face_mean_jumps(disp, frac)
    fields = frac.fields(-1)
    scale = np.abs(fields["jump_t"]).max()
    assert scale > 1e-5
    assert np.abs(jn - fields["jump_n"]).max() < 1e-10 * scale
    assert np.abs(jt - fields["jump_t"]).max() < 1e-10 * scale


def test_mesh_edges_of_a_p2_split_triangle():
    # the P2 triangle 0-5 split as poromech.io.output._P2_SPLIT: the six outer half-edges only
    split = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2], [5, 3, 4]])
    assert sorted(map(tuple, mesh_edges(split))) == [(0, 4), (0, 5), (1, 3), (1, 5), (2, 3),
                                                       (2, 4)]
    assert sorted(map(tuple, mesh_edges(np.array([[0, 1, 2], [1, 3, 2]])))) == [
        (0, 1), (0, 2), (1, 2), (1, 3), (2, 3)]


def test_nice_scale():
    x = np.array([[0.0, 0.0], [2.0, 1.0]])
    assert nice_scale(x, np.array([[0.0, 0.0], [0.0054, 0.0]])) == 20.0  # 0.2/0.0054 = 37
    assert nice_scale(x, np.array([[0.0, 0.0], [0.001, 0.0]])) == 200.0
    assert nice_scale(x, np.zeros((2, 2))) == 1.0


# -- pictures --------------------------------------------------------------------------------
def backends():
    out = ["matplotlib"]
    try:
        out.insert(0, choose_backend("pyvista"))
    except Exception as err:  # noqa: BLE001
        out.insert(0, pytest.param("pyvista", marks=pytest.mark.skip(reason=str(err))))
    return out


@pytest.mark.parametrize("backend", backends())
def test_plot_run_writes_small_pngs(runs, tmp_path, backend):
    from PIL import Image

    names = {}
    for run in RUNS:
        paths = plot_run(runs[run], out=tmp_path / run, backend=backend)
        names[run] = sorted(p.name for p in paths)
        for p in paths:
            assert 10_000 < p.stat().st_size < MAX_PNG_BYTES, p
            with Image.open(p) as im:  # not a blank picture
                assert len(im.convert("RGB").getcolors(maxcolors=1 << 20)) > 20, p
    assert names["coupled"] == ["deformed_t200.png", "jumps_t200.png", "pressure_t200.png"]
    assert names["mech"] == ["deformed_t500.png", "jumps_t500.png"]
    assert names["flow"] == ["pressure_t2000.png"]
    earlier = plot_run(runs["coupled"], time=90.0, scale=50.0, out=tmp_path / "t",
                       backend=backend)
    assert sorted(p.name for p in earlier)[0] == "deformed_t100.png"


def test_plot_command(runs, tmp_path):
    proc = subprocess.run([sys.executable, "-m", "poromech", "plot", str(runs["flow"]), "-o",
                           str(tmp_path), "--backend", "matplotlib"], capture_output=True,
                          text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stderr
    assert "pressure_t2000.png" in proc.stdout and (tmp_path / "pressure_t2000.png").exists()
    proc = subprocess.run([sys.executable, "-m", "poromech", "plot", str(tmp_path)],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert proc.returncode == 2 and "not a poromech output directory" in proc.stderr


def test_plot_says_what_to_install(runs, tmp_path):
    code = ("import sys; sys.modules['pyvista'] = sys.modules['matplotlib'] = None; "
            "from poromech.cli import main; sys.exit(main(sys.argv[1:]))")
    proc = subprocess.run([sys.executable, "-c", code, "plot", str(runs["flow"]), "-o",
                           str(tmp_path)], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 1
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "pip install 'poromech[plot]'" in lines[0], proc.stderr


# -- the outputs through VTK's XDMF reader (pyvista) -----------------------------------------
def check_vtk_reads(outdir):
    """Every series: VTK's time steps are the index's, and each step's arrays are exact."""
    pv = pytest.importorskip("pyvista")
    res = open_results(outdir)
    for stem in res.series_names:
        series = res.series(stem)
        reader = pv.get_reader(str(outdir / f"{stem}.xdmf"))
        assert np.allclose(reader.time_values, series.times, rtol=1e-14, atol=0), stem
        for k, t in enumerate(series.times):
            reader.set_active_time_value(t)
            mesh = reader.read()
            if isinstance(mesh, pv.MultiBlock):
                mesh = mesh[0]
            assert (mesh.n_points, mesh.n_cells) == (len(series.points), len(series.cells))
            for name, values in series.fields(k).items():
                data = mesh.point_data if len(values) == mesh.n_points else mesh.cell_data
                assert np.array_equal(np.asarray(data[name]), values), (stem, t, name)


@pytest.mark.parametrize("run", list(RUNS))
def test_vtk_reads_every_series(runs, run):
    check_vtk_reads(runs[run])


def test_killed_run_is_readable(tmp_path):
    """A run killed with SIGKILL while writing: every step the index lists loads."""
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "poromech", "run", "six_fractures_mechanics", "-o", str(out),
           "-q", *(f"--set={s}" for s in [*TINY, "degree=1", "time.steps=400"])]
    proc = subprocess.Popen(cmd, cwd=ROOT)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if len(list((out / "fractures_steps").glob("0*.h5"))) >= 3:
                break
            time.sleep(0.002)
        os.kill(proc.pid, signal.SIGKILL)
    finally:
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    res = open_results(out)
    assert res.summary["status"] == "running"
    assert len(res.times("displacement")) >= 3
    check_vtk_reads(out)


@pytest.mark.parametrize("backend", ["pyvista", "matplotlib"])
def test_plot_of_a_3d_flow_run_draws_the_fracture_pressure(tmp_path, backend):
    """A 3D flow run (tetrahedra): the pressure picture assumed triangles and stopped with a
    ValueError; it now draws ``p_f`` on the fracture triangles."""
    out = tmp_path / "berre"
    assert run_scene(load_scene(ROOT / "configs" / "berre_case1.yaml"), out)["status"] \
        == "converged"
    written = plot_run(out, backend=backend)
    assert [p.name for p in written] == ["pressure_t0.png"]
    assert 5_000 < written[0].stat().st_size < 300_000


def test_plot_refuses_a_time_or_scale_that_is_not_a_finite_number(capsys):
    """``--time inf`` drew the first output time (the nearest to inf by argmin), ``--scale nan``
    a blank picture, ``--scale 0`` or ``-1`` were accepted: refused with exit 2."""
    from poromech.cli import main

    for args in (["--time", "inf"], ["--time", "nan"], ["--time", "abc"], ["--scale", "0"],
                 ["--scale", "-1"], ["--scale", "nan"]):
        assert main(["plot", "nowhere", *args]) == 2, args
        assert "is not" in capsys.readouterr().err


@pytest.mark.parametrize("backend", backends())
def test_plot_of_a_run_without_fractures_draws_the_deformed_mesh(tmp_path, backend):
    """A mechanics scene without fractures wrote its displacement, but ``poromech plot`` said
    there was nothing to draw: it now draws the deformed mesh (no fracture lines, no legend)."""
    from PIL import Image

    from poromech.scene.loading import scene_from_dict

    raw = {"name": "block", "physics": "mechanics",
           "geometry": {"domain": {"rectangle": [0.0, 0.0, 1.0, 1.0]}}, "mesh": {"size": 0.2},
           "degree": 2, "material": {"young": 1.0e10, "poisson": 0.25},
           "boundary_conditions": [{"boundary": "bottom", "displacement": [0.0, 0.0]},
                                   {"boundary": "top", "displacement": [0.001, -0.001]}]}
    out = tmp_path / "block"
    assert run_scene(scene_from_dict(raw), out)["status"] == "converged"
    written = plot_run(out, backend=backend)
    assert [p.name for p in written] == ["deformed_t0.png"]
    with Image.open(written[0]) as im:
        assert len(im.convert("RGB").getcolors(maxcolors=1 << 20)) > 20


@pytest.mark.parametrize(("name", "cut", "fragment"), [
    ("summary.json", 5, "summary.json cannot be read as JSON"),
    ("flow.h5", 300, "flow.h5 cannot be read as HDF5 (Unable"),
    ("flow.xdmf", 20, "flow.xdmf cannot be read as XML"),
])
def test_plot_of_a_damaged_run_is_refused_in_one_line(runs, tmp_path, capsys, name, cut,
                                                      fragment):
    """A file of the run cut short gave a raw exception (exit 1): one line naming it, exit 2."""
    import shutil

    from poromech.cli import main

    damaged = tmp_path / "run"
    shutil.copytree(runs["flow"], damaged)
    with open(damaged / name, "r+b") as f:
        f.truncate(cut)
    assert main(["plot", str(damaged), "-o", str(tmp_path / "png"),
                 "--backend", "matplotlib"]) == 2
    err = capsys.readouterr().err.strip()
    assert f"cannot plot {damaged}: " in err and fragment in err and "\n" not in err, err


def test_colour_bar_labels_tell_their_ticks_apart():
    """A fracture pressure of 10.42-10.54 MPa was labelled 10.4, 10.5, 10.5, 10.5, 10.5."""
    from poromech.io.plot import bar_format

    for lo, hi in ((10.42, 10.54), (0.0, 1.5e7), (-3.0, 3.0), (1.0, 1.0 + 1e-6), (2e5, 2.0001e5)):
        fmt = bar_format(np.linspace(lo, hi, 11))
        labels = [fmt % t for t in np.linspace(lo, hi, 5)]
        assert len(set(labels)) == 5, (lo, hi, labels)
    assert bar_format(np.linspace(0.0, 1.5e7, 11)) == "%.3g"  # no more digits than needed
    assert bar_format([5.0, 5.0]) == "%.3g"
