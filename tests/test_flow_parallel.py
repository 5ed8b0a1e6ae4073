"""1 rank vs 2 ranks: same HFV solution, also with a process boundary lying on fractures."""

import json
import sys
from pathlib import Path

import numpy as np
import pytest
from conftest import ROOT, network_geometry, run_parallel
from mpi4py import MPI
from test_flow_driver import flow_scene

from poromech.flow.balance import boundary_fluxes, compute_fluxes
from poromech.flow.boundary import FlowBoundary
from poromech.flow.problem import DarcyProblem, FlowProperties
from poromech.run import run_scene
from poromech.scene.loading import scene_from_dict
from poromech.verification.flow import (
    barrier_metrics,
    barrier_scene,
    rectangle,
    solve_scene,
    uniform_mesh,
)

TOL = 1e-8


def network():
    raw = network_geometry()
    return rectangle(*raw["domain"]["rectangle"], [f["points"] for f in raw["fractures"]])


def checkerboard(centroids):
    """Ranks split at x = 0.5 and y = 0.5: the process boundary runs along the fractures
    'stem' (x = 0.5) and 'bar' (y = 0.5) and through their T junction."""
    return ((centroids[:, 0] > 0.5) ^ (centroids[:, 1] > 0.5)).astype(np.int32)


def solve_network(comm, owner=None) -> dict:
    """Conductive network with sources, anisotropic matrix; gathered on rank 0 (collective)."""
    fm = uniform_mesh(comm, network(), 0.08, owner=owner)
    nc = fm.msh.topology.index_map(2).size_local
    nf = len(fm.fractures.facets)
    perm = np.broadcast_to(np.array([[1.0, 0.3], [0.3, 0.5]]) * 1e-12, (nc, 2, 2)).copy()
    # 'bar' blocks (pair coupling |σ| T_f/η ≈ 1.5e-11 against matrix conductances ≈ 1e-9), the
    # others conduct. The stem's end at the T junction crosses the bar, so the bar is cut off
    # from the stem (docs/flow.md "Intersections"): with Λ_n = 1e-20 it would be an island
    # held by 1e-15 couplings, whose level CG resolves only to round-off (≈ 0.02 Pa).
    kn = np.where(fm.fractures.fracture == 1, 1e-16, 1e-9)
    props = FlowProperties(perm, 1e-3, np.full(nf, 1e-3), np.full(nf, np.nan), kn,
                           np.full(nf, np.nan), np.zeros(nc))
    bcs = [FlowBoundary("left", (3,), "pressure", lambda x, t: 1e5 + 0 * x[:, 0]),
           FlowBoundary("right", (1,), "flux", lambda x, t: 1e-6 * x[:, 1])]
    pb = DarcyProblem(fm, props, bcs, source=lambda x, t: 1e-5 * np.sin(3 * x[:, 0]),
                      options={"ksp_rtol": 1e-13})
    rec = pb.solve()
    flux = boundary_fluxes(pb, compute_fluxes(pb))
    orig = np.asarray(fm.msh.topology.original_cell_index[:nc])
    parts = comm.gather((orig, pb.cell_pressure, fm.fractures.index,
                         np.column_stack([pb.fracture_pressure, pb.trace_pressure,
                                          pb.node_pressure])), root=0)
    shifted = pb.shift.num_shifted
    pb.destroy()
    if comm.rank != 0:
        return {}
    cells = np.concatenate([p[0] for p in parts])
    faces = np.concatenate([p[2] for p in parts])
    p_cell = np.concatenate([p[1] for p in parts])[np.argsort(cells)]
    p_face = np.concatenate([p[3] for p in parts])[np.argsort(faces)]
    return {"p_cell": p_cell.tolist(), "p_face": p_face.tolist(), "flux": flux,
            "iterations": rec.iterations, "shifted": shifted,
            "owned_faces": [int(len(p[2])) for p in parts]}


def solve_barrier(comm, owner=None) -> dict:
    """Issue 7 X junction of a barrier and a conduit (collective); with :func:`checkerboard` the
    process boundary runs along both fractures and through their intersection."""
    pb = solve_scene(barrier_scene("crossing"), comm, owner)
    out = barrier_metrics(pb) | {"crossing": pb.crossings.num_crossing,
                                 "owned_faces": comm.allgather(len(pb.faces.measure))}
    pb.destroy()
    return out


def run_driver(comm, outdir) -> dict:
    """A transient network scene with probes, run; probe CSVs read on rank 0."""
    raw = flow_scene(biot_modulus=1e9, porosity=0.1, initial_pressure=1e5)
    raw["time"] = {"final": 50.0, "steps": 2}
    summary = run_scene(scene_from_dict(raw), Path(outdir), comm)
    if comm.rank != 0:
        return {}
    probes = {n: (Path(outdir) / f"probe_{n}.csv").read_text() for n in ("bar", "vertical")}
    return {"summary": summary["flow"]["conservation"], "probes": probes}


CODE = f"""
import json, sys, tempfile
sys.path.insert(0, {str(ROOT / "tests")!r})
import dolfinx_solver
from mpi4py import MPI
from test_flow_parallel import checkerboard, run_driver, solve_barrier, solve_network
comm = MPI.COMM_WORLD
out = {{"default": solve_network(comm), "fracture": solve_network(comm, checkerboard)}}
out["barrier"] = solve_barrier(comm, checkerboard)
outdir = comm.bcast(tempfile.mkdtemp() if comm.rank == 0 else None)
out["driver"] = run_driver(comm, outdir)
if comm.rank == 0:
    print(json.dumps(out))
"""


@pytest.fixture(scope="module")
def results(tmp_path_factory):
    serial = solve_network(MPI.COMM_SELF)
    serial["barrier"] = solve_barrier(MPI.COMM_SELF)
    serial["driver"] = run_driver(MPI.COMM_SELF, tmp_path_factory.mktemp("serial"))
    return serial, run_parallel(CODE, nprocs=2)


@pytest.mark.mpi
@pytest.mark.parametrize("partition", ["default", "fracture"])
def test_two_ranks_same_solution(results, partition):
    serial, parallel = results
    par = parallel[partition]
    assert min(par["owned_faces"]) > 0  # both ranks own fracture faces
    for key in ("p_cell", "p_face"):
        a, b = np.array(serial[key]), np.array(par[key])
        assert a.shape == b.shape
        assert np.abs(a - b).max() <= TOL * np.abs(a).max(), key
    for name, v in serial["flux"].items():
        for part in ("matrix", "fracture"):
            assert par["flux"][name][part] == pytest.approx(v[part], rel=1e-6, abs=1e-12)
    assert par["shifted"] == serial["shifted"] > 0
    assert abs(par["iterations"] - serial["iterations"]) <= 5


@pytest.mark.mpi
def test_two_ranks_blocking_intersection(results):
    """The intersection resistances gathered across ranks: same outflow and barrier jump."""
    serial, parallel = results
    a, b = serial["barrier"], parallel["barrier"]
    assert min(b["owned_faces"]) > 0 and a["crossing"] == b["crossing"] == 4
    for key in ("outflow", "jump"):
        assert b[key] == pytest.approx(a[key], rel=TOL), key
    assert b["relative_residual"] < 1e-10


@pytest.mark.mpi
def test_two_ranks_driver_probes_and_report(results):
    """Transient flow run: identical probes (to solver tolerance) and conservation report."""
    serial, parallel = results
    a, b = serial["driver"], parallel["driver"]
    for name in ("bar", "vertical"):
        ra = [line.split(",") for line in a["probes"][name].splitlines()]
        rb = [line.split(",") for line in b["probes"][name].splitlines()]
        assert ra[0] == rb[0] and len(ra) == len(rb)
        for x, y in zip(ra[1:], rb[1:], strict=True):
            assert [v == "" for v in x] == [v == "" for v in y]
            vals = [(float(u), float(v)) for u, v in zip(x, y, strict=True) if u != ""]
            assert all(abs(u - v) <= 1e-6 * max(abs(u), 1.0) for u, v in vals)
    for name, v in a["summary"]["boundary_fluxes"].items():
        assert b["summary"]["boundary_fluxes"][name]["total"] == pytest.approx(
            v["total"], rel=1e-6, abs=1e-15)
    assert b["summary"]["relative_residual"] < 1e-8


def test_solution_is_nontrivial(results):
    serial, _ = results
    p_face = np.array(serial["p_face"])
    jump = np.abs(p_face[:, 1] - p_face[:, 2])
    assert jump.max() > 1.0 and np.ptp(serial["p_cell"]) > 10.0
    assert json.dumps(serial["flux"])  # JSON-ready
    assert Path(sys.executable).exists()
