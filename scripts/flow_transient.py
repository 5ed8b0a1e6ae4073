"""Implicit Euler order in time: decay of a sine mode with storage (1D diffusion).

``s ∂p/∂t = (k/η) ∂²p/∂x²`` on a strip ``(0, 1) × (0, 0.1)``, ``p = 0`` at both ends,
``p(x, 0) = sin(π x)``; relative L² error of the cell pressures at ``T = 0.1`` against
``exp(-π² t) sin(π x)`` on a fine mesh (its spatial error, ~1e-4, stays below the time error)
for halved steps. Writes ``docs/flow/transient.csv``, ``transient.md`` and ``transient.png``.

    python scripts/flow_transient.py
"""

from __future__ import annotations

import argparse

import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

import numpy as np
from flow_common import DOCS, generated, markdown_table, order_figure, write_csv
from mpi4py import MPI

from poromech.verification.flow import Diffusion1D, observed_orders, uniform_mesh

COMMAND = "python scripts/flow_transient.py"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--steps", type=int, nargs="+", default=[4, 8, 16, 32, 64, 128, 256])
    p.add_argument("--size", type=float, default=0.005, help="mesh size (m)")
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    sol = Diffusion1D()
    final = 0.1
    fm = uniform_mesh(comm, sol.geometry(), args.size)
    rows = []
    for n in args.steps:
        pb = sol.problem(fm)
        err = sol.run(pb, final, n)
        its = [r.iterations for r in pb.records]
        rows.append([n, final / n, pb.dofs.num_global, err, float(np.mean(its))])
        pb.destroy()
    if comm.rank != 0:
        return
    data = np.array(rows, dtype=float)
    orders = np.concatenate([[np.nan], observed_orders(data[:, 1], data[:, 3])])
    header = ["steps", "dt", "unknowns", "rel_l2_error", "cg_iterations_per_step", "order"]
    table = [r + [float(o)] for r, o in zip(rows, orders, strict=True)]
    DOCS.mkdir(parents=True, exist_ok=True)
    write_csv(DOCS / "transient.csv", header, table)
    text = (generated(COMMAND, comm.size) + f"; mesh size {args.size} m, "
            f"T = {final} s, λT = {sol.rate * final:.3f}.\n\n")
    (DOCS / "transient.md").write_text(text + markdown_table(header, table))
    order_figure(DOCS / "transient.png", data[:, 1], {"HFV + implicit Euler": data[:, 3]}, 1,
                 "Δt", "time step Δt (s)", "relative L² error at T", "1D diffusion with storage")


if __name__ == "__main__":
    main()
