"""Scale run: HFV flow on the regular fracture network of Flemisch et al. (2018, case 2).

Uniform refinements of ``configs/flemisch_case2.yaml`` up to more than a million unknowns, on
the ranks of the communicator (run with ``mpirun -n 2``). For each size: mesh and setup times,
then a steady solve, a values-only update (new apertures) with its re-solve, and three implicit
Euler steps with storage from rest (the first rebuilds the preconditioner for the storage term,
the next two reuse it).
Writes ``docs/flow/scale.csv`` and ``scale.md``.

    mpirun -n 2 python scripts/flow_scale.py [--levels 2 3 4]
"""

from __future__ import annotations

import argparse
import time

import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

import numpy as np
from flow_common import DOCS, ROOT, generated, markdown_table, write_csv
from mpi4py import MPI

from poromech.flow.balance import compute_fluxes, mass_balance
from poromech.flow.problem import TimeStep
from poromech.flow.setup import problem_from_scene
from poromech.run import build_mesh
from poromech.scene.loading import load_scene

COMMAND = "mpirun -n 2 python scripts/flow_scale.py"
DT = 0.01


def timed(comm, fn):
    """Run ``fn()``; its result and the wall time (max over ranks)."""
    comm.barrier()
    t0 = time.perf_counter()
    out = fn()
    return out, comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)


def run_level(comm, level: int) -> list[list]:
    scene = load_scene(ROOT / "configs" / "flemisch_case2.yaml",
                       [f"mesh.refinement={level}", "time.final=0.03", "time.steps=3",
                        "flow.biot_modulus=1.0"])
    fm, t_mesh = timed(comm, lambda: build_mesh(scene, comm))
    pb, t_setup = timed(comm, lambda: problem_from_scene(scene, fm))
    base = [level, comm.size, pb.dofs.num_global, round(t_mesh, 2), round(t_setup, 2)]
    rows = []

    def record(name, update_s=float("nan"), step=None):
        rec = pb.records[-1]
        bal = mass_balance(pb, compute_fluxes(pb), 0.0, step)["relative_residual"]
        rows.append(base + [name, rec.iterations, round(rec.setup_seconds, 3),
                            round(rec.seconds, 3), update_s, bal])

    pb.solve()
    record("steady")
    _, t_update = timed(comm, lambda: (pb.set_aperture(1.5 * pb.properties.aperture),
                                       pb.assemble_matrix()))
    pb.solve()
    record("steady, new apertures", round(t_update, 3))
    pb.set_pressure(lambda x, t: np.zeros(len(x)))  # start from rest: p⁰ = 0, φ⁰ = 0
    phi = np.zeros(pb.geom.num_cells)
    for n in range(1, 4):
        step = TimeStep(DT, phi, np.zeros_like(phi), pb.properties.aperture.copy())
        pb.solve(n * DT, step)
        record(f"implicit Euler step {n}", step=step)
        phi = pb.porosity(step)
    pb.destroy()
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--levels", type=int, nargs="+", default=[2, 3, 4])
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for level in args.levels:
        rows += run_level(comm, level)
        if comm.rank == 0:
            print(*rows[-5:], sep="\n", flush=True)
    if comm.rank != 0:
        return
    header = ["refinement", "ranks", "unknowns", "mesh_s", "setup_s", "solve", "iterations",
              "pc_setup_s", "solve_s", "values_update_s", "mass_balance_rel"]
    DOCS.mkdir(parents=True, exist_ok=True)
    write_csv(DOCS / "scale.csv", header, rows)
    text = (generated(COMMAND, comm.size) + "; CG + GAMG, rtol 1e-12 "
            "relative to the initial (preconditioned) residual. solve_s includes pc_setup_s.\n\n")
    (DOCS / "scale.md").write_text(text + markdown_table(header, rows))


if __name__ == "__main__":
    main()
