"""One rank and two ranks give the same contact solution, also when a process boundary lies on a
fracture (faces whose + and - cells belong to different ranks)."""

import json

import numpy as np
import pytest
from conftest import mechanics_scene, run_parallel
from mpi4py import MPI

from poromech.run import Run
from poromech.scene.loading import scene_from_dict

CODE = """
import json, sys, numpy as np
import dolfinx_solver
from mpi4py import MPI
sys.path.insert(0, "tests")
from conftest import mechanics_scene
from poromech.scene.loading import scene_from_dict
from poromech.scene.geometry import scene_geometry
from poromech.mesh.generate import generate_mesh
from poromech.mesh.fractured import create_fractured_mesh
from poromech.run import Run
from poromech.scene.geometry import mesh_sizes
comm = MPI.COMM_WORLD
scene = scene_from_dict(json.loads('''SCENE'''))
geo = scene_geometry(scene)
arrays = generate_mesh(geo, mesh_sizes(scene)) if comm.rank == 0 else None
owner = None
if comm.rank == 0:
    c = arrays.x[arrays.cells].mean(axis=1)
    owner = (c[:, 1] < 0.5).astype(np.int32)
fm = create_fractured_mesh(comm, geo, arrays, owner=owner)
with Run(scene, mesh=fm) as run:
    records = run.execute()["solves"]
    model = run.physics.model
vals = model.face_fields()
rows = np.column_stack([fm.fractures.index] + [vals[k] for k in
                       ("jump_n", "jump_t", "traction_n", "traction_t")])
imap = fm.msh.topology.index_map(2)
cut = int(np.count_nonzero((fm.fractures.plus[:, 0] >= imap.size_local) |
                           (fm.fractures.minus[:, 0] >= imap.size_local)))
rows = comm.gather(rows, root=0)
cut = comm.allreduce(cut)
if comm.rank == 0:
    rows = np.concatenate(rows)
    rows = rows[np.argsort(rows[:, 0])]
    print(json.dumps({"values": rows[:, 1:].tolist(), "cut": cut,
                      "iterations": [r["iterations"] for r in records],
                      "dofs": model.dof_count()}))
"""


@pytest.mark.mpi
@pytest.mark.parametrize(("formulation", "degree"), [("nitsche", 1), ("mixed", 2)])
def test_two_ranks_equal_one_rank(formulation, degree):
    raw = mechanics_scene(degree=degree)
    raw["contact"]["formulation"] = formulation
    result = run_parallel(CODE.replace("SCENE", json.dumps(raw)))
    with Run(scene_from_dict(raw), comm=MPI.COMM_WORLD) as run:
        records = run.execute()["solves"]
        model, fm = run.physics.model, run.mesh
    faces = model.face_fields()
    vals = np.column_stack([faces[k] for k in ("jump_n", "jump_t", "traction_n", "traction_t")])
    vals = vals[np.argsort(fm.fractures.index)]
    par = np.array(result["values"])
    assert result["cut"] > 5  # the process boundary runs along fracture 'bar'
    assert result["dofs"] == model.dof_count()
    assert result["iterations"] == [r["iterations"] for r in records]
    scale = np.abs(vals).max(axis=0)
    assert np.all(np.abs(par - vals).max(axis=0) <= 1e-8 * scale)


def test_a_library_that_exits_on_rank_0_raises_on_every_rank():
    """A library calling sys.exit (meshio does) becomes an error, not a rank that left."""
    import sys

    from poromech.parallel import on_root
    with pytest.raises(RuntimeError, match=r"exit exited \(status 3\)"):
        on_root(MPI.COMM_WORLD, sys.exit, 3)


CHECKPOINT_CODE = """
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import poromech
from mpi4py import MPI

from poromech.io.checkpoint import load_checkpoint, save_checkpoint

comm = MPI.COMM_WORLD
n = 1000
# rank r writes the rows r, r + p, r + 2p, ... and asks for the others, scattered over all rows
mine = np.arange(comm.rank, n, comm.size)
values = np.column_stack([mine, -mine]).astype(np.float64)
out = Path(comm.bcast(tempfile.mkdtemp() if comm.rank == 0 else None))
save_checkpoint(comm, out, {"step": 1}, {"rows": (mine, values)})
meta, arrays = load_checkpoint(comm, out)
want = np.arange((comm.rank + 1) % comm.size, n, comm.size)[::-1].reshape(-1, 2)
got = arrays["rows"][want]
ok = bool(np.array_equal(got[..., 0], want) and np.array_equal(got[..., 1], -want))
result = {"ok": comm.allreduce(ok, op=MPI.LAND), "meta": meta,
          "read": comm.gather(arrays["rows"].rows_read)}
comm.barrier()
if comm.rank == 0:
    shutil.rmtree(out)
    print(json.dumps(result))
"""


def test_a_checkpoint_is_read_by_blocks_of_rows():
    """Each of 2 ranks reads half the rows of a checkpoint array and gets the rows it asks for,
    scattered over the whole array, from the other rank: before, each read the span of its
    rows, all of them."""
    result = run_parallel(CHECKPOINT_CODE)
    assert result["ok"] and result["meta"] == {"step": 1}
    assert result["read"] == [500, 500]



NODE_ROWS_CODE = """
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import poromech
from dolfinx import fem
from mpi4py import MPI

from poromech.io.checkpoint import NodeRows, load_checkpoint, save_checkpoint
from poromech.mesh.fractured import cracked_space
from poromech.run import build_mesh
from poromech.scene.loading import scene_from_dict

comm = MPI.COMM_WORLD
fm = build_mesh(scene_from_dict(SCENE), comm)
V = cracked_space(fm, 2)
numbering = NodeRows(fm, V)
f = fem.Function(V)
f.x.array[:] = (np.repeat(numbering.positions, 2) + np.tile([0.0, 0.5], len(numbering.positions)))
out = Path(comm.bcast(tempfile.mkdtemp() if comm.rank == 0 else None))
save_checkpoint(comm, out, {}, {"u": numbering.rows(f.x.array)})
_, arrays = load_checkpoint(comm, out)
g = fem.Function(V)
NodeRows(fm, V).set(g, arrays["u"])
same = bool(np.array_equal(g.x.array, f.x.array))
result = {"same": comm.allreduce(same, op=MPI.LAND), "rows": arrays["u"].shape[0],
          "blocks": V.dofmap.index_map.size_global}
comm.barrier()
if comm.rank == 0:
    shutil.rmtree(out)
    print(json.dumps(result))
"""


def test_displacements_are_checkpointed_once_per_dof_block():
    """A P2 displacement on a cracked mesh is written as one row per dof block (a row per
    cell repeated each block about 7 times in 3D) and read back on owned and ghost blocks to
    the bit, on 2 ranks."""
    raw = mechanics_scene(time={"final": 1.0, "steps": 1})
    result = run_parallel(NODE_ROWS_CODE.replace("SCENE", json.dumps(raw)))
    assert result["same"] and result["rows"] == result["blocks"] > 100
