"""Parallel outputs (poromech.io.mpiio): every rank writes its own rows, in a numbering that does
not depend on the partition, so a run gives the same files on 1 and on 2 ranks.

3D: a P2 field written on the duplicated-node tetrahedra is exact at its nodes and the same on
1 and 2 ranks (a process boundary on the crack); a penny-shaped crack run on 1 and 2 ranks reads
back the same (``open_results``), its XDMF files are consistent and its crack opens; a run that
died after two steps continues (``--restart``, on 1 or 2 ranks) to the same outputs. 2D: the
files are a renumbering of those written before, with the same values.
"""

import json
import shutil
import subprocess
import sys
import xml.etree.ElementTree as ET

import dolfinx_solver  # noqa: F401

import h5py
import numpy as np
import pytest
from conftest import ROOT, load_script, mechanics_scene, mpirun, run_parallel
from dolfinx import fem
from mpi4py import MPI

from poromech.io.output import FractureTable, displacement_mesh, fracture_mesh, owned_blocks
from poromech.io.plot import MAX_PNG_BYTES, choose_backend, plot_run
from poromech.io.results import open_results
from poromech.io.xdmf import XDMFSeries, read_series
from poromech.mechanics.physics import WRITTEN_FACE_FIELDS_3D
from poromech.mesh.fractured import cracked_space
from poromech.run import Run, build_mesh, run_scene
from poromech.scene.loading import load_scene, load_scene_and_raw, scene_from_dict

PENNY = str(ROOT / "configs" / "penny.yaml")
#: The penny-shaped crack on a coarse mesh (947 tetrahedra, 61 crack faces), pressure p·t.
SMALL = ["mesh.size=5", "mesh.transition=6", "mesh.fracture_size=0.5", "mesh.tip_size=0.25",
         "fracture_pressure=p*t", "time.final=3", "time.steps=3"]
FACES = 61
TIMES = [1.0, 2.0, 3.0]
COLUMNS_3D = ["time", "fracture", "x", "y", "z", "jump_n", "jump_t", "jump_tx", "jump_ty",
              "jump_tz", "traction_n", "traction_t", "traction_tx", "traction_ty",
              "traction_tz", "state"]


def cli(*args, ranks: int = 1) -> None:
    """``poromech run ARGS -q`` on ``ranks`` ranks; fails the test when it fails."""
    cmd = [sys.executable, "-m", "poromech", "run", *args, "-q"]
    if ranks > 1:
        cmd = [mpirun(), "-n", str(ranks), *cmd]
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The small penny run on 1 rank (here) and on 2 ranks (mpirun)."""
    root = tmp_path_factory.mktemp("penny")
    scene, raw = load_scene_and_raw(PENNY, SMALL)
    assert run_scene(scene, root / "one", raw=raw)["status"] == "converged"
    cli(PENNY, "-o", str(root / "two"), *(f"--set={s}" for s in SMALL), ranks=2)
    return root / "one", root / "two"


def assert_close(a, b, rtol):
    """Arrays of the same shape equal to ``rtol`` times the largest value of ``a``."""
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape
    assert np.abs(a - b).max(initial=0.0) <= rtol * max(np.abs(a).max(initial=0.0), 1e-300)


# -- the writers on a P2 field with known values ---------------------------------------------
def quadratic(x):
    """A quadratic vector field, represented exactly by P2 (x: (3, n))."""
    return np.stack([x[0] ** 2 + x[1], x[1] * x[2] - 2.0, 3.0 * x[2] ** 2 - x[0] * x[1]])


def write_fields(outdir: str) -> None:
    """Write a P2 field and face fields known in closed form, on the ranks of COMM_WORLD.

    On 2 ranks the cells above the crack's plane go to rank 1: the process boundary lies on it.
    """
    comm = MPI.COMM_WORLD
    scene = load_scene(PENNY, SMALL[:4])
    owner = (lambda c: (c[:, 2] > 0).astype(np.int32)) if comm.size == 2 else None
    fm = build_mesh(scene, comm, owner=owner)
    V = cracked_space(fm, 2)
    u = fem.Function(V, name="u")
    u.interpolate(quadratic)
    disp = XDMFSeries(comm, outdir, "displacement", displacement_mesh(fm, V), "u")
    frac = XDMFSeries(comm, outdir, "fractures", fracture_mesh(fm), "fractures")
    table = FractureTable(fm, f"{outdir}/fractures.csv", (*WRITTEN_FACE_FIELDS_3D, "state"))
    k = fm.fractures.index.astype(np.float64)
    for t in (0.5, 1.0):
        disp.write(t, point_data={"u": t * owned_blocks(u)})
        faces = {name: t * np.cos(k + i) * 10.0 ** -i
                 for i, name in enumerate(WRITTEN_FACE_FIELDS_3D)}
        faces["state"] = np.mod(k, 3)
        frac.write(t, cell_data={**faces, "n": fm.fractures.normal})
        table.write(t, faces)


@pytest.mark.mpi
def test_p2_field_exact_and_files_equal_on_one_and_two_ranks(tmp_path):
    one, two = tmp_path / "one", tmp_path / "two"
    one.mkdir()
    two.mkdir()
    write_fields(str(one))
    run_parallel(f"""
        import sys
        import dolfinx_solver
        sys.path.insert(0, "tests")
        from mpi4py import MPI
        from test_output3d import write_fields
        write_fields({str(two)!r})
        print("{{}}" if MPI.COMM_WORLD.rank == 0 else "")
    """)
    assert (one / "fractures.csv").read_bytes() == (two / "fractures.csv").read_bytes()
    rows = (one / "fractures.csv").read_text().splitlines()
    assert rows[0].split(",") == COLUMNS_3D and len(rows) == 1 + 2 * FACES
    first = [r.split(",") for r in rows[1:1 + FACES]]
    assert [r[-1] for r in first[:4]] == ["open", "stick", "slip", "open"]  # face k: k mod 3
    assert [float(r[5]) for r in first[:3]] == [float(f"{0.5 * np.cos(k):.9e}") for k in range(3)]
    for stem in ("displacement", "fractures"):
        a, b = read_series(one, stem), read_series(two, stem)
        np.testing.assert_array_equal(a.cells, b.cells)
        assert_close(a.points, b.points, 1e-15)
        assert a.times == b.times == [0.5, 1.0]
        for k in (0, 1):
            fa, fb = a.fields(k), b.fields(k)
            assert fa.keys() == fb.keys()
            for name in fa:
                assert_close(fa[name], fb[name], 1e-14)
    disp = read_series(one, "displacement")
    assert disp.points.shape == (len(np.unique(disp.cells)), 3)
    for k, t in enumerate(disp.times):
        assert_close(disp.fields(k)["u"], t * quadratic(disp.points.T).T, 1e-13)
    frac = read_series(one, "fractures")
    assert np.array_equal(frac.fields(1)["jump_n"], np.cos(np.arange(float(FACES))))
    assert frac.fields(1)["n"].shape == (FACES, 3)


# -- a run on 1 and on 2 ranks ---------------------------------------------------------------
@pytest.mark.mpi
def test_one_and_two_ranks_read_back_equal(runs):
    a, b = (open_results(d) for d in runs)
    assert (a.summary["mpi_ranks"], b.summary["mpi_ranks"]) == (1, 2)
    assert a.series_names == b.series_names == ("displacement", "fractures")
    for stem in a.series_names:
        sa, sb = a.series(stem), b.series(stem)
        assert sa.times == sb.times == TIMES
        np.testing.assert_array_equal(sa.cells, sb.cells)
        assert_close(sa.points, sb.points, 1e-15)
        for k in range(len(TIMES)):
            fa, fb = sa.fields(k), sb.fields(k)
            assert fa.keys() == fb.keys()
            for name in fa:
                assert_close(fa[name], fb[name], 1e-9)
    ta, tb = a.fractures(), b.fractures()
    assert list(ta) == list(tb) == COLUMNS_3D
    assert len(ta["time"]) == 3 * a.summary["mesh"]["fracture_faces"] == 3 * FACES
    for name in COLUMNS_3D:
        if name in ("fracture", "state"):
            assert np.array_equal(ta[name], tb[name])
        else:
            assert_close(ta[name], tb[name], 1e-8)


@pytest.mark.mpi
def test_fracture_table_is_in_face_order(runs):
    """The rows of a time are the faces in the order of ``fractures.xdmf`` (global number)."""
    res = open_results(runs[1])
    frac = res.series("fractures")
    centroids = frac.points[frac.cells].mean(axis=1)
    for k, t in enumerate(TIMES):
        rows, fields = res.fractures(time=t), frac.fields(k)
        assert_close(np.column_stack([rows["x"], rows["y"], rows["z"]]), centroids, 1e-8)
        assert_close(rows["jump_n"], fields["jump_n"], 1e-9)
    assert set(rows["state"]) == {"open"} and np.all(fields["jump_n"] < 0)


@pytest.mark.mpi
def test_xdmf_files_are_consistent(runs):
    for out in runs:
        for stem, kind, nodes in (("displacement", "Tetrahedron", 4),
                                  ("fractures", "Triangle", 3)):
            with h5py.File(out / f"{stem}.h5") as f:
                points, cells = f["mesh/points"][()], f["mesh/cells"][()]
            assert cells.shape[1] == nodes and points.shape[1] == 3
            assert np.array_equal(np.unique(cells), np.arange(len(points)))  # every point used
            grids = [g for g in ET.parse(out / f"{stem}.xdmf").getroot().iter("Grid")
                     if g.get("GridType") == "Uniform"]
            assert [float(g.find("Time").get("Value")) for g in grids] == TIMES
            for g in grids:
                topo = g.find("Topology")
                assert topo.get("TopologyType") == kind
                assert int(topo.get("NumberOfElements")) == len(cells)
                for item in g.iter("DataItem"):
                    file, name = item.text.strip().split(":/")
                    with h5py.File(out / file) as f:
                        shape = f[name].shape
                        if file != f"{stem}.h5":
                            assert f.attrs["time"] == float(g.find("Time").get("Value"))
                    assert tuple(int(d) for d in item.get("Dimensions").split()) == shape
                    assert shape[0] in (len(points), len(cells))
        check_tetrahedra(out)


def check_tetrahedra(out):
    """Eight sub-tetrahedra of positive volume per P2 cell, filling it; midpoints on edges."""
    disp = read_series(out, "displacement")
    tets = json.loads((out / "summary.json").read_text())["mesh"]["cells"]
    assert disp.cells.shape == (8 * tets, 4)  # 8 sub-tetrahedra per P2 tetrahedron
    x = disp.points[disp.cells]
    vol = np.einsum("ni,ni->n", np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]),
                    x[:, 3] - x[:, 0]) / 6.0
    assert vol.min() > 0
    parent = disp.cells.reshape(-1, 8, 4)
    vertices = np.column_stack([parent[:, i, i] for i in range(4)])
    px = disp.points[vertices]
    pvol = np.einsum("ni,ni->n", np.cross(px[:, 1] - px[:, 0], px[:, 2] - px[:, 0]),
                     px[:, 3] - px[:, 0]) / 6.0
    assert_close(vol.reshape(-1, 8).sum(axis=1), pvol, 1e-12)
    assert abs(pvol.sum() - 1000.0) < 1e-9  # the box [-5, 5]^3
    edge_01 = disp.points[parent[:, 0, 1]]  # node 9, the midpoint of edge (0, 1)
    assert_close(edge_01, 0.5 * (px[:, 0] + px[:, 1]), 1e-15)


@pytest.mark.mpi
def test_crack_opens_when_warped(runs):
    """The disc's nodes are written twice; the upper copy moves up, the lower one down."""
    disp = read_series(runs[1], "displacement")
    u, x = disp.fields(-1)["u"], disp.points
    assert u.shape == (len(x), 3)
    height = np.zeros(len(x))  # sum of the heights of the cells around each point
    np.add.at(height, disp.cells.ravel(), np.repeat(x[disp.cells][:, :, 2].mean(axis=1), 4))
    r = np.hypot(x[:, 0], x[:, 1])
    on_disc = np.flatnonzero((np.abs(x[:, 2]) < 1e-12) & (r < 1.0))
    _, inverse, counts = np.unique(np.round(x[on_disc], 12), axis=0, return_inverse=True,
                                   return_counts=True)
    twice = counts[inverse] == 2
    assert set(counts) == {1, 2} and r[on_disc[~twice]].min() > 0.98  # once: the rim
    pairs = on_disc[twice][np.argsort(inverse[twice], kind="stable")].reshape(-1, 2)
    up = np.where(height[pairs[:, 0]] > height[pairs[:, 1]], pairs[:, 0], pairs[:, 1])
    lo = pairs.sum(axis=1) - up
    assert len(pairs) > 20 and np.all(height[up] > 0) and np.all(height[lo] < 0)
    opening = u[up, 2] - u[lo, 2]
    assert opening.min() > 0
    jump = -open_results(runs[1]).fractures(time=3.0)["jump_n"]
    assert 0.5 < opening.max() / jump.max() < 2.0  # nodal values against face means


@pytest.mark.mpi
@pytest.mark.parametrize("backend", ["pyvista", "matplotlib"])
def test_plot_draws_the_opening(runs, tmp_path, backend):
    if backend == "pyvista" and choose_backend("auto") != "pyvista":
        pytest.skip("pyvista cannot render off-screen here")
    paths = plot_run(runs[0], out=tmp_path, backend=backend)
    assert [p.name for p in paths] == ["opening_t3.png", "jumps_t3.png"]
    assert all(10_000 < p.stat().st_size <= MAX_PNG_BYTES for p in paths)


# -- restart ---------------------------------------------------------------------------------
def crash_at(call: int):
    """A ``prepare`` hook making the physics' ``write`` fail at its ``call``-th call."""
    def prepare(physics):
        write, calls = physics.write, []

        def failing(*args, **kwargs):
            calls.append(1)
            if len(calls) == call:
                raise RuntimeError("died")
            return write(*args, **kwargs)
        physics.write = failing
    return prepare


@pytest.mark.mpi
def test_restart_keeps_earlier_steps(runs, tmp_path):
    """A run dead in its third step's output (after a partial table block) continues on 1 and
    on 2 ranks: the steps written before are kept as they were, the rest is the full run's."""
    scene, raw = load_scene_and_raw(PENNY, SMALL)
    died = tmp_path / "died"
    with pytest.raises(RuntimeError, match="died"), Run(scene, died, raw=raw,
                                                         prepare=crash_at(3)) as run:
        run.execute()
    with open(died / "fractures.csv", "ab") as fh:  # a block cut by the kill
        fh.write(b"3,penny,0.1,0.2,0\0\0\0\0\n3,penny,0.2")
    (died / "displacement_steps" / "000002.h5").write_bytes(b"not indexed")
    kept = {f.name: f.read_bytes() for f in (died / "displacement_steps").glob("00000[01].h5")}
    again = tmp_path / "again"
    shutil.copytree(died, again)
    assert run_scene(scene, died, raw=raw, restart=True)["status"] == "converged"
    cli("--restart", str(again), ranks=2)
    full = open_results(runs[0])
    for out in (died, again):
        res = open_results(out)
        for name, data in kept.items():
            assert (out / "displacement_steps" / name).read_bytes() == data
        for stem in ("displacement", "fractures"):
            a, b = full.series(stem), res.series(stem)
            assert b.times == TIMES
            for k in range(3):
                for name, values in a.fields(k).items():
                    assert_close(values, b.fields(k)[name], 1e-9)
        table = res.fractures()
        assert len(table["time"]) == 3 * FACES
        assert_close(table["jump_n"], full.fractures()["jump_n"], 1e-8)
    assert (died / "fractures.csv").read_bytes() == (runs[0] / "fractures.csv").read_bytes()


# -- 2D: the same values as before ----------------------------------------------------------
def test_2d_outputs_are_the_former_ones_renumbered(tmp_path):
    """The 2D displacement file holds the values the former writer put in the DOLFINx dof
    numbering (compared by scripts/regression_outputs.py); the fracture files are unchanged.
    The points are the mesh's own since 2026-11-29, where the former writer tabulated them:
    equal to 1e-15 (they were 1e-16 off), the values to the bit."""
    regression = load_script("regression_outputs")
    raw = mechanics_scene(**{"mesh__size": 0.25, "mesh__fracture_size": 0.1})
    new, old = tmp_path / "new", tmp_path / "old"
    with Run(scene_from_dict(raw), new) as run:
        assert run.execute()["status"] == "converged"
        model, fm = run.physics.model, run.mesh
        V, u = model.V, owned_blocks(model.u)
        faces = run.physics.face_output()
    ncells = fm.msh.topology.index_map(2).size_local
    blocks = V.dofmap.list[:ncells]  # the former numbering: DOLFINx's dofs, its cell order
    split = np.array([[0, 5, 4], [5, 1, 3], [4, 3, 2], [5, 3, 4]])
    shutil.copytree(new, old)
    with h5py.File(old / "displacement.h5", "w") as f:
        f["mesh/points"] = V.tabulate_dof_coordinates()[: len(u), :2]
        f["mesh/cells"] = blocks[:, split].reshape(-1, 3).astype(np.int64)
    with h5py.File(old / "displacement_steps" / "000000.h5", "w") as f:
        f["u"] = np.column_stack([u, np.zeros(len(u))])
    orders = regression.SeriesOrders(old, new)
    for file, rtol in (("displacement.h5", 1e-15), ("displacement_steps/000000.h5", 0.0)):
        diffs, worst = regression.compare_h5(old / file, new / file, rtol,
                                             orders(old / file, new / file))
        assert diffs == [] and worst <= rtol
        with h5py.File(old / file) as fa, h5py.File(new / file) as fb:  # a renumbering
            assert all(not np.array_equal(fa[k], fb[k]) for k in ("mesh/cells", "u") if k in fa)
    order = np.argsort(fm.fractures.index)
    frac = read_series(new, "fractures")
    for name in ("jump_n", "jump_t", "traction_n", "traction_t", "state"):
        assert np.array_equal(frac.fields(0)[name], faces[name][order])
    rows = open_results(new).fractures()
    assert list(rows) == ["time", "fracture", "s", "x", "y", "jump_n", "jump_t", "traction_n",
                          "traction_t", "state"]
    assert np.array_equal(rows["jump_n"], [float(f"{v:.9e}") for v in faces["jump_n"][order]])
    assert json.loads((new / "summary.json").read_text())["mpi_ranks"] == 1


def test_a_probe_typed_to_a_few_digits_lies_in_its_fracture():
    """A line in an inclined fracture written to 4-5 digits is ~5e-6 off its plane: it still
    samples the fracture (its columns were empty), and a line 1e-3 away does not."""
    import dolfinx

    from poromech.io.probes import LineSampler

    msh = dolfinx.mesh.create_unit_cube(MPI.COMM_WORLD, 2, 2, 2)
    c, s = np.cos(0.5), np.sin(0.5)  # a triangle in the plane z = 0.3 + tan(0.5) x
    tri = np.array([[[0.0, 0.0, 0.3], [c, 0.0, 0.3 + s], [0.0, 1.0, 0.3]]])
    keys = np.array([0.0])
    on = lambda x, y: [x, y, 0.3 + np.tan(0.5) * x]  # noqa: E731
    for off, found in ((0.0, True), (5e-6, True), (1e-3, False)):
        start, end = np.array(on(0.1, 0.2)), np.array(on(0.3, 0.3))
        start[2] += off
        end[2] -= off
        probe = LineSampler(msh, np.round(start, 5) if off == 0 else start, end, 5,
                            faces=(tri, keys))
        hit = MPI.COMM_WORLD.allreduce(bool(np.any(probe._face >= 0)), op=MPI.LOR)
        assert hit == found, off
