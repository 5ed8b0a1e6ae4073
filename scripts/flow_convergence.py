"""Manufactured solution with pressure jumps (DESIGN §5): L² errors and observed orders.

Uniform refinements of an unstructured mesh of ``(-1, 1) × (0, 1)`` cut by ``{x = 0}``;
errors of cell, trace, fracture and node pressures; CG + GAMG iterations and solve time.
Writes ``docs/flow/convergence.csv``, ``convergence.md`` and ``convergence.png``.

    python scripts/flow_convergence.py [--levels 0 1 2 3 4 5 6]
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
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    sol = JumpSolution()
    rows = []
    for m in args.levels:
        fm = uniform_mesh(comm, sol.geometry(), 0.2, refinement=m)
        pb = sol.problem(fm, options={"ksp_rtol": 1e-12})
        rec = pb.solve()
        err = sol.errors(pb)
        balance = mass_balance(pb, compute_fluxes(pb))["relative_residual"]
        rows.append([m, 0.2 / 2**m, pb.dofs.num_global, rec.iterations, rec.seconds, balance]
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
    header = ["refinement", "h", "unknowns", "iterations", "solve_s", "mass_balance_rel"]
    header += [f"err_{k}" for k in KEYS] + [f"order_{k}" for k in KEYS]
    table = [r + [float(o) for o in orders[i]] for i, r in enumerate(rows)]
    DOCS.mkdir(parents=True, exist_ok=True)
    write_csv(DOCS / "convergence.csv", header, table)
    text = (generated(COMMAND, comm.size) + f"; a = {sol.a}, c = {sol.c}, "
            f"T_f = {sol.T_f}, C_f = {sol.C_f}.\n\n")
    (DOCS / "convergence.md").write_text(text + markdown_table(header, table))
    order_figure(DOCS / "convergence.png", data[:, 1],
                 {f"{k} pressure": data[:, 6 + i] for i, k in enumerate(KEYS)}, 2, "h²",
                 "mesh size h (m)", "discrete L² error",
                 "Manufactured solution with pressure jumps")


if __name__ == "__main__":
    main()
