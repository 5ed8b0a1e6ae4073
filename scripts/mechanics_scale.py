"""Scale run: a P2 contact problem with ≥ 500k dofs on 2 ranks.

Also measures the cost of a Newton iteration relative to one linear elastic solve of the same
size in the same run.

Run::

    mpirun -n 2 python scripts/mechanics_scale.py [--refinement 3]

Writes ``docs/mechanics/scale.csv`` and ``docs/mechanics/scale.md``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import itertools
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

from mpi4py import MPI

from poromech.run import Run, build_mesh
from poromech.scene.loading import load_scene

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics"
#: The mechanics-only six-fracture scene (the embedded default may be a coupled one).
SCENE = ROOT / "configs" / "six_fractures_mechanics.yaml"


def timed_run(scene, fm, extrapolate: bool = True) -> dict:
    """Set up and solve in memory: records, sizes and the set-up and solve wall times.

    The set-up builds forms and matrices, and for the condensed ``mixed`` solve factorizes
    twice (the ``setup`` phase of the run's timer); the solve time is the sum of the steps'.

    ``extrapolate=False`` turns the step predictor off: on a linear problem under a load linear
    in time it would give the second step exactly, without a solve.
    """
    def configure(physics) -> None:
        physics.predictor.extrapolate = extrapolate

    with Run(scene, mesh=fm, prepare=configure) as run:
        summary = run.execute()
        condensed = run.physics.solver.condensed
        records = summary["solves"]
        return {"records": records, "dofs": summary["dofs"],
                "condensed_factorizations": condensed.factorizations if condensed else 0,
                "setup": summary["wall_time"]["setup"],
                "solve": sum(r["wall_time"] for r in records)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--refinement", type=int, default=3)
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    base = load_scene(SCENE, [f"mesh.refinement={args.refinement}", "output.xdmf=false"])
    t0 = time.perf_counter()
    fm = build_mesh(base, comm)
    t_mesh = time.perf_counter() - t0
    rows = []
    # the linear elastic reference: same space and loads, traction-free fractures; the first
    # solve includes MUMPS's symbolic analysis, the second refactorizes numerically only, as
    # every Newton iteration does (without the predictor, which would make it exact)
    elastic = load_scene(SCENE, [f"mesh.refinement={args.refinement}", "contact.formulation=none",
                                "time={final: 500.0, steps: 2}", "solver.reuse_jacobian=false"])
    ref = timed_run(elastic, fm, extrapolate=False)
    t_first, t_elastic = ref["records"][0]["wall_time"], ref["records"][1]["wall_time"]
    dofs_elastic = ref["dofs"]
    variants = [(f, stale, "false") for f, stale in itertools.product(("nitsche", "mixed"),
                                                                      ("true", "false"))]
    variants.append(("mixed", "true", "true"))
    for formulation, stale, condensed in variants:
        scene = load_scene(SCENE, [f"mesh.refinement={args.refinement}",
                                  f"contact.formulation={formulation}",
                                  f"solver.stale_factorization={stale}",
                                  f"solver.condensation={condensed}"])
        out = timed_run(scene, fm)
        records, t_setup, t_solve = out["records"], out["setup"], out["solve"]
        its = sum(r["iterations"] for r in records)
        facts = sum(r["factorizations"] for r in records) + out["condensed_factorizations"]
        rows.append({
            "formulation": formulation, "condensed": condensed, "stale_factorization": stale,
            "ranks": comm.size,
            "dofs": out["dofs"],
            "cells": fm.msh.topology.index_map(2).size_global,
            "fracture_faces": fm.num_fracture_faces, "steps": len(records),
            "newton_iterations": its,
            "face_iterations": sum(r["face_iterations"] for r in records),
            "factorizations": facts,
            "stale_solves": sum(r["stale_solves"] for r in records),
            "gmres_iterations": sum(r["linear_iterations"] for r in records),
            "time_setup": t_setup, "time_solve": t_solve,
            "time_per_iteration": t_solve / its if its else float("nan"),
            "time_linear_elastic": t_elastic, "time_first_elastic": t_first,
            "ratio": t_solve / its / t_elastic if its else float("nan"),
            "ratio_run": (t_setup + t_solve) / t_elastic,
        })
    if comm.rank != 0:
        return
    OUT.mkdir(parents=True, exist_ok=True)
    with open(OUT / "scale.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, list(rows[0]))
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.4g}" if isinstance(v, float) else v) for k, v in r.items()})
    lines = [
        "# Scale run", "",
        f"Generated {datetime.date.today()} by `mpirun -n {comm.size} python "
        f"scripts/mechanics_scale.py --refinement {args.refinement}`: the default six-fracture "
        f"scene (5 quasi-static steps to T/4) at refinement {args.refinement}, P2, MUMPS LU. "
        f"Mesh generation and distribution: {t_mesh:.1f} s. The reference is one linear elastic "
        f"solve of the same size ({dofs_elastic} dofs, traction-free fractures) in the same run: "
        f"{t_elastic:.2f} s (assembly, numeric factorization, solve, residual check); the very "
        f"first solve, which also runs MUMPS's symbolic analysis (reused by every later "
        f"factorization with the same pattern), took {t_first:.2f} s.", "",
        "Newton directions come from a fresh factorization, from a reused one (Jacobian "
        "unchanged), or, with `solver.stale_factorization` (default on), from GMRES "
        "preconditioned by the last factorization when few contact states switched. With "
        "`solver.condensation` (default on, `mixed` P2 only) each solve is the condensed one "
        "(docs/poromechanics.md): two factorizations at set-up, then back-substitutions and a "
        "dense face Newton, checked by the regular Newton (0 iterations when the candidate "
        "passes). *set-up*: building the simulation (forms, matrices, the condensed "
        "factorizations); *run / elastic*: (set-up + solve) / one elastic solve.", "",
        "| formulation | condensed | stale factorization | ranks | dofs | steps | Newton it | "
        "face Newton it | factorizations | stale GMRES solves (GMRES it) | set-up (s) | "
        "solve (s) | s / Newton it | ratio to one elastic solve | run / elastic |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['formulation']} | {r['condensed']} | {r['stale_factorization']} | "
                     f"{r['ranks']} | {r['dofs']} | {r['steps']} | {r['newton_iterations']} | "
                     f"{r['face_iterations']} | "
                     f"{r['factorizations']} | {r['stale_solves']} ({r['gmres_iterations']}) | "
                     f"{r['time_setup']:.1f} | {r['time_solve']:.1f} | "
                     f"{r['time_per_iteration']:.2f} | {r['ratio']:.2f} | "
                     f"{r['ratio_run']:.1f} |")
    (OUT / "scale.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
