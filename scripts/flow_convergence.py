"""Manufactured solution with pressure jumps (DESIGN §5): L² errors and observed orders.

Uniform refinements of an unstructured mesh of ``(-1, 1) × (0, 1)`` cut by ``{x = 0}``;
errors of cell, trace, fracture and node pressures; CG + GAMG iterations and solve time.
Writes ``docs/flow/convergence.csv``, ``convergence.md`` and ``convergence.png``.

With ``--dim 3``: ``(-1, 1) × (0, 1)²`` cut by the square ``{x = 0}``, meshed at the sizes
``--sizes`` (nodes on the fracture edges); writes ``docs/flow/convergence3d.*``.

    python scripts/flow_convergence.py [--levels 0 1 2 3 4 5 6]
    python scripts/flow_convergence.py --dim 3 [--sizes 0.2 0.1 0.05 0.035 0.025]
"""

from __future__ import annotations

import argparse

import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

import numpy as np
from flow_common import DOCS, generated, markdown_table, order_figure, write_csv
from mpi4py import MPI

from poromech.flow.balance import compute_fluxes, mass_balance
from poromech.verification.flow import JumpSolution, observed_orders, uniform_mesh

KEYS = ("cell", "trace", "fracture", "node")
COMMAND = "python scripts/flow_convergence.py"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3, 4, 5, 6])
    p.add_argument("--dim", type=int, choices=(2, 3), default=2)
    p.add_argument("--sizes", type=float, nargs="+", default=[0.2, 0.1, 0.05, 0.035, 0.025])
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    sol = JumpSolution(dim=args.dim)
    rows = []
    meshes = ([(m, 0.2, m) for m in args.levels] if args.dim == 2
              else [(i, h, 0) for i, h in enumerate(args.sizes)])
    for m, size, refinement in meshes:
        fm = uniform_mesh(comm, sol.geometry(), size, refinement=refinement)
        h = size / 2**refinement
        pb = sol.problem(fm, options={"ksp_rtol": 1e-12})
        rec = pb.solve()
        err = sol.errors(pb)
        balance = mass_balance(pb, compute_fluxes(pb))["relative_residual"]
        rows.append([m, h, pb.dofs.num_global, rec.iterations, rec.seconds, balance]
                    + [err[k] for k in KEYS])
        pb.destroy()
        if comm.rank == 0:
            print(rows[-1], flush=True)
    if comm.rank != 0:
        return
    data = np.array(rows, dtype=float)
    orders = np.vstack([np.full(len(KEYS), np.nan),
                        np.column_stack([observed_orders(data[:, 1], data[:, 6 + i])
                                         for i in range(len(KEYS))])])
    header = ["refinement" if args.dim == 2 else "level", "h", "unknowns", "iterations",
              "solve_s", "mass_balance_rel"]
    header += [f"err_{k}" for k in KEYS] + [f"order_{k}" for k in KEYS]
    table = [r + [float(o) for o in orders[i]] for i, r in enumerate(rows)]
    DOCS.mkdir(parents=True, exist_ok=True)
    stem = "convergence" if args.dim == 2 else "convergence3d"
    command = COMMAND if args.dim == 2 else f"{COMMAND} --dim 3"
    write_csv(DOCS / f"{stem}.csv", header, table)
    text = (generated(command, comm.size) + f"; a = {sol.a}, c = {sol.c}, "
            f"T_f = {sol.T_f}, C_f = {sol.C_f}.\n\n")
    (DOCS / f"{stem}.md").write_text(text + markdown_table(header, table))
    order_figure(DOCS / f"{stem}.png", data[:, 1],
                 {f"{k} pressure": data[:, 6 + i] for i, k in enumerate(KEYS)}, 2, "h²",
                 "mesh size h (m)", "discrete L² error",
                 f"Manufactured solution with pressure jumps ({args.dim}D)" if args.dim == 3
                 else "Manufactured solution with pressure jumps")


if __name__ == "__main__":
    main()
