"""Linear solvers of 3D mechanics: MUMPS against CG + GAMG on Sneddon's pressurized penny crack.

The penny scene (``configs/penny.yaml``: a disc crack of radius 1 m under 1 MPa in a clamped box
of half-width 5 m, P2 displacements) is meshed at a family of sizes, every mesh size scaled by
one factor ``s`` (``mesh.size = 2 s``, ``mesh.fracture_size = 0.2 s``, ``mesh.tip_size =
0.05 s``, ``mesh.transition = 3`` m), and solved with ``solver.linear_solver`` direct (MUMPS) and
iterative (CG + GAMG with the rigid-body modes), on 1 and 2 ranks. Each case is its own process
(``mpirun -n R`` for R ranks), so that its peak memory is the max RSS of that process (summed
over its ranks), gmsh included. Recorded per case: sizes, Newton and Krylov iterations, wall
time per phase (max over ranks: mesh = gmsh and distribution, setup = spaces, forms and
matrices, assembly, solve = the linear solve, of which the preconditioner set-up is the GAMG
hierarchy or the MUMPS factorization), the CPU seconds of the linear solve (the machine is
shared: wall times include waiting for a core), peak memory, the pre-mesh estimates of
:mod:`poromech.scene.resources`, the opening's relative L² error against Sneddon's infinite-body
solution, and the largest difference of the displacement to the direct solution and to the
1-rank solution (relative to its largest value; displacements compared per input cell, so
independent of the partition).

Run (the levels up to 1.0M took about 20 CPU minutes on the 2-core development machine)::

    python scripts/mechanics3d_solvers.py
    python scripts/mechanics3d_solvers.py --levels 33k 80k --ranks 1 --work /tmp/solvers
    python scripts/mechanics3d_solvers.py --options 190k     # GAMG options on one Jacobian

``--report`` runs no case and rewrites the Markdown and the figure from the CSV, with the
estimates of the current :mod:`poromech.scene.resources`. Cases with the same ``--work``
directory are compared with each other (solutions are kept there); rows of the levels not run
are kept from the existing CSV. Writes
``docs/mechanics3d/solvers.csv``, ``solvers.md`` and ``solvers.png`` (``--options``:
``gamg_options.csv`` and ``gamg_options.md``).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import resource
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics3d"
SCENE = ROOT / "configs" / "penny.yaml"
#: Level name (about the number of P2 unknowns) -> the factor ``s`` of every mesh size.
LEVELS = {"15k": 1.4, "33k": 1.0, "80k": 0.7, "190k": 0.5, "510k": 0.35, "1.0M": 0.275,
          "1.6M": 0.23}
#: Largest level run with MUMPS by default: 190k needs ~8 GB, the next one ~3 times more.
DIRECT_LEVELS = ("15k", "33k", "80k", "190k")
KEYS = ["level", "solver", "ranks", "cells", "dofs", "fracture_faces", "newton_iterations",
        "krylov_iterations", "time_mesh", "time_setup", "time_assembly", "time_pc_setup",
        "time_solve", "time_total", "cpu_solve", "peak_gb", "estimated_cells", "estimated_gb",
        "opening_error", "diff_direct", "diff_1rank", "load", "status"]
COMMAND = "python scripts/mechanics3d_solvers.py"


def overrides(level: str, solver: str) -> list[str]:
    """Scene overrides of a case: the mesh sizes of the level, the solver, no output files."""
    s = LEVELS[level]
    return [f"mesh.size={2.0 * s:g}", f"mesh.fracture_size={0.2 * s:g}",
            f"mesh.tip_size={0.05 * s:g}", f"solver.linear_solver={solver}",
            "output.xdmf=false", "output.fractures_csv=false"]


# -- one case (its own process) -------------------------------------------------------------
def _gather_sorted(comm: MPI.Comm, keys: np.ndarray, values: np.ndarray) -> np.ndarray | None:
    """Rows of every rank sorted by key on rank 0 (benchmark output, not the solver path)."""
    parts = comm.gather((keys, values), root=0)
    if comm.rank != 0:
        return None
    k = np.concatenate([p[0] for p in parts])
    return np.concatenate([p[1] for p in parts])[np.argsort(k, kind="stable")]


def sneddon_error(scene, fm, jump_n: np.ndarray) -> float:
    """Relative L² error of the face-mean opening against Sneddon's ``w(r)`` (collective).

    ``w = 8 (1 - ν²) p / (π E) √(a² - r²)`` for a disc of radius ``a`` in an infinite body
    (Sneddon 1946), at the face midpoints; the opening is ``-jump_n``.
    """
    prm = scene.parameters
    a, p, E, nu = (float(prm[k]) for k in ("a", "p", "E", "nu"))
    faces = fm.fractures
    r2 = (faces.midpoint[:, :2] ** 2).sum(axis=1)
    exact = 8 * (1 - nu**2) * p / (np.pi * E) * np.sqrt(np.maximum(a * a - r2, 0.0))
    num = fm.comm.allreduce(float(np.sum(faces.measure * (-jump_n - exact) ** 2)))
    den = fm.comm.allreduce(float(np.sum(faces.measure * exact**2)))
    return float(np.sqrt(num / den))


def estimate_columns(level: str, solver: str, ranks: int) -> dict:
    """The pre-mesh estimates of a case (:func:`poromech.scene.resources.estimate_run`)."""
    from poromech.scene.geometry import scene_geometry
    from poromech.scene.loading import load_scene
    from poromech.scene.resources import estimate_run

    scene = load_scene(SCENE, overrides(level, solver))
    estimate = estimate_run(scene, scene_geometry(scene), ranks)
    return {"estimated_cells": estimate.cells, "estimated_gb": estimate.memory / 1e9}


def run_case(level: str, solver: str, work: Path) -> None:
    """Solve one case; rank 0 writes ``<work>/<case>.json`` and the solution ``.npz``."""
    from poromech.io.checkpoint import cell_dof_rows
    from poromech.run import Run
    from poromech.scene.loading import load_scene

    comm = MPI.COMM_WORLD
    load0 = os.getloadavg()[0]
    scene = load_scene(SCENE, overrides(level, solver))
    cpu = [0.0]

    def measure_cpu(physics) -> None:
        """CPU seconds of this rank in the linear solves (the Newton's strategy, wrapped)."""
        linear = physics.solver.linear
        solve = linear.solve

        def timed(*args):
            c0 = time.process_time()
            try:
                return solve(*args)
            finally:
                cpu[0] += time.process_time() - c0

        linear.solve = timed

    with Run(scene, comm=comm, prepare=measure_cpu) as run:
        summary = run.execute()
        model, fm = run.physics.model, run.mesh
        keys, rows = cell_dof_rows(fm, model.V, model.u.x.array)
        jump_n = model.face_fields()["jump_n"]
        error = sneddon_error(scene, fm, jump_n)
        u = _gather_sorted(comm, keys, rows)
        w = _gather_sorted(comm, fm.fractures.index, -jump_n)
    peak = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0)
    cpu_solve = comm.allreduce(cpu[0], op=MPI.MAX)
    if comm.rank != 0:
        return
    wall, records = summary["wall_time"], summary["solves"]
    row = {
        "level": level, "solver": solver, "ranks": comm.size, "cells": summary["mesh"]["cells"],
        "dofs": summary["dofs"], "fracture_faces": summary["mesh"]["fracture_faces"],
        "newton_iterations": sum(r["iterations"] for r in records),
        "krylov_iterations": summary["linear_solver"]["krylov_iterations"],
        "time_mesh": wall.get("mesh", 0.0), "time_setup": wall.get("setup", 0.0),
        "time_assembly": wall.get("assembly", 0.0),
        "time_pc_setup": sum(r["time_preconditioner"] for r in records),
        "time_solve": wall.get("linear_solve", 0.0), "time_total": wall["total"],
        "cpu_solve": cpu_solve, "peak_gb": peak / 1e9,
        "opening_error": error, "load": 0.5 * (load0 + os.getloadavg()[0]),
        "status": summary["status"],
    }
    name = f"{level}-{solver}-{comm.size}"
    np.savez(work / f"{name}.npz", u=u, w=w)
    (work / f"{name}.json").write_text(json.dumps(row))


# -- the study --------------------------------------------------------------------------------
def launch(level: str, solver: str, ranks: int, work: Path) -> dict:
    """Run one case in its own process(es); its row (status ``error: ...`` when it failed)."""
    cmd = [sys.executable, __file__, "--case", level, solver, "--work", str(work)]
    if ranks > 1:
        cmd = [str(Path(sys.executable).with_name("mpirun")), "-n", str(ranks), *cmd]
    print(f"{level} {solver} {ranks} rank(s) ...", flush=True)
    proc = subprocess.run(cmd, capture_output=True, text=True)
    path = work / f"{level}-{solver}-{ranks}.json"
    if proc.returncode != 0 or not path.exists():
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
        return {"level": level, "solver": solver, "ranks": ranks,
                "status": f"error: {tail[0][:150]}"}
    row = json.loads(path.read_text())
    print(f"  {row['dofs']} dofs, {row['krylov_iterations']} Krylov iterations, solve "
          f"{row['time_solve']:.1f} s, peak {row['peak_gb']:.2f} GB", flush=True)
    return row


def difference(work: Path, a: str, b: str) -> float:
    """``max |u_a - u_b| / max |u_b|`` of two saved solutions; NaN if one is missing."""
    pa, pb = work / f"{a}.npz", work / f"{b}.npz"
    if not (pa.exists() and pb.exists()):
        return float("nan")
    ua, ub = np.load(pa)["u"], np.load(pb)["u"]
    if ua.shape != ub.shape:
        return float("nan")
    return float(np.abs(ua - ub).max() / np.abs(ub).max())


def read_rows(path: Path) -> tuple[list[str], list[dict]]:
    """Provenance comment lines and rows of an existing CSV."""
    if not path.exists():
        return [], []
    lines = path.read_text().splitlines()
    comments = [ln[2:] for ln in lines if ln.startswith("# ")]
    return comments, list(csv.DictReader(ln for ln in lines if not ln.startswith("#")))


def _number(v):
    try:
        return float(v)
    except (TypeError, ValueError):
        return float("nan")


def study(args) -> None:
    """Run the cases, compare solutions, write CSV, Markdown and figure (rank 0 only)."""
    work = Path(args.work or tempfile.mkdtemp(prefix="mechanics3d_solvers_"))
    work.mkdir(parents=True, exist_ok=True)
    rows = []
    for level in [] if args.report else args.levels:
        for solver in args.solvers:
            if solver == "direct" and level not in args.direct_levels:
                continue
            for ranks in (args.ranks if solver == "iterative" else [1]):
                rows.append(launch(level, solver, ranks, work))
    for r in rows:
        case = f"{r['level']}-{r['solver']}-{r['ranks']}"
        r["diff_direct"] = difference(work, case, f"{r['level']}-direct-1") \
            if r["solver"] == "iterative" else float("nan")
        r["diff_1rank"] = difference(work, case, f"{r['level']}-{r['solver']}-1") \
            if int(r["ranks"]) > 1 else float("nan")
    csv_path = OUT / "solvers.csv"
    comments, old = read_rows(csv_path)
    done = {(r["level"], r["solver"], str(r["ranks"])) for r in rows}
    kept = [r for r in old if (r["level"], r["solver"], r["ranks"]) not in done]
    order = {name: i for i, name in enumerate(LEVELS)}
    allrows = sorted(kept + rows, key=lambda r: (order[r["level"]], r["solver"] != "direct",
                                                 int(r["ranks"])))
    for r in allrows:  # the estimates of the current resources module, for every row
        r.update(estimate_columns(r["level"], r["solver"], int(r["ranks"])))
    command = " ".join([COMMAND, *map(shlex.quote, sys.argv[1:])])
    stamp = f"Generated by `{command}` ({datetime.date.today()})"
    if args.report:  # the estimates of the rows are rewritten: say so once
        stamp = f"Estimates and report rewritten by `{command}`"
        comments = [c for c in comments if not c.startswith("Estimates and report")]
    comments.append(stamp)
    OUT.mkdir(parents=True, exist_ok=True)
    with open(csv_path, "w", newline="") as fh:
        fh.writelines(f"# {c}\n" for c in comments)
        w = csv.DictWriter(fh, KEYS, extrasaction="ignore")
        w.writeheader()
        for r in allrows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v)
                        for k, v in r.items()})
    _, allrows = read_rows(csv_path)
    write_markdown(allrows, comments)
    figure(allrows)


# -- report ------------------------------------------------------------------------------------
def _fmt(v, spec: str) -> str:
    x = _number(v)
    return "–" if np.isnan(x) else format(x, spec)


def targets(rows: list[dict]) -> list[str]:
    """The study's targets, each checked against the rows and said plainly."""
    out = []
    it1 = [r for r in rows if r["solver"] == "iterative" and r["ranks"] == "1"
           and r["status"] == "converged"]
    its = np.array([_number(r["krylov_iterations"]) for r in it1])
    if len(its):
        mean = 0.5 * (its.max() + its.min())
        spread = (its.max() - its.min()) / 2 / mean
        out.append(f"* **Krylov iterations flat (±25 %)**: {int(its.min())}-{int(its.max())} "
                   f"from {it1[0]['dofs']} to {it1[-1]['dofs']} unknowns, ±{100 * spread:.0f} % "
                   f"about {mean:.0f}: {'met' if spread <= 0.25 else 'missed'}.")
    for r in it1 + [r for r in rows if r["solver"] == "iterative" and r["ranks"] == "2"]:
        if r["level"] == "1.0M":
            t, m = _number(r["time_solve"]), _number(r["peak_gb"])
            ok = t < 120 and m < 8
            setup, cpu = _number(r["time_pc_setup"]), _number(r["cpu_solve"])
            out.append(f"* **1 million P2 unknowns in < 2 min of solve time and < 8 GB** "
                       f"({r['ranks']} rank(s), {r['dofs']} unknowns): solve {t:.0f} s "
                       f"(GAMG set-up {setup:.0f} s; {cpu:.0f} CPU s), peak {m:.1f} GB: "
                       f"{'met' if ok else 'missed'}.")
    both = [r for r in it1 if not np.isnan(_number(r["diff_direct"]))]
    if both:
        worst = max(_number(r["diff_direct"]) for r in both)
        out.append(f"* **Iterative = direct to 1e-8**: largest difference {worst:.1e} "
                   f"(levels {', '.join(r['level'] for r in both)}): "
                   f"{'met' if worst < 1e-8 else 'missed'}.")
    direct = [r for r in rows if r["solver"] == "direct" and r["status"] == "converged"]
    if direct:
        big = direct[-1]
        gb, t = _number(big["peak_gb"]), _number(big["time_solve"])
        out.append(f"* **MUMPS fits** up to {big['dofs']} unknowns here ({gb:.1f} GB, solve "
                   f"{t:.0f} s); larger levels were not run with it (the estimate grows as "
                   "n^(4/3)).")
    par = [r for r in rows if r["ranks"] == "2" and not np.isnan(_number(r["diff_1rank"]))]
    if par:
        worst = max(_number(r["diff_1rank"]) for r in par)
        out.append(f"* **1 rank = 2 ranks to the solver tolerance**: largest difference "
                   f"{worst:.1e} (levels {', '.join(r['level'] for r in par)}): "
                   f"{'met' if worst < 1e-8 else 'missed'}.")
    ok = [r for r in rows if str(r["status"]).startswith("converged")]
    if ok:
        ratio = np.array([_number(r["estimated_gb"]) / _number(r["peak_gb"]) for r in ok])
        out.append(f"* **Pre-mesh memory estimate within a factor 1.5 of the measured peak**: "
                   f"estimate / peak {ratio.min():.2f}-{ratio.max():.2f} over {len(ok)} cases: "
                   f"{'met' if ratio.min() >= 1 / 1.5 and ratio.max() <= 1.5 else 'missed'}.")
    return out


def write_markdown(rows: list[dict], comments: list[str]) -> None:
    header = ["level", "solver", "ranks", "cells", "unknowns", "Krylov its", "mesh s",
              "setup s", "assembly s", "PC set-up s", "solve s", "solve CPU s", "total s",
              "peak GB", "est. GB", "est./gmsh cells", "opening error", "vs direct",
              "vs 1 rank", "load"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        if not str(r["status"]).startswith("converged"):
            lines.append(f"| {r['level']} | {r['solver']} | {r['ranks']} | "
                         + " | ".join(["–"] * (len(header) - 4)) + f" | {r['status']} |")
            continue
        ratio = _number(r["estimated_cells"]) / _number(r["cells"])
        lines.append("| " + " | ".join([
            r["level"], r["solver"], r["ranks"], r["cells"], r["dofs"], r["krylov_iterations"],
            _fmt(r["time_mesh"], ".1f"), _fmt(r["time_setup"], ".1f"),
            _fmt(r["time_assembly"], ".1f"), _fmt(r["time_pc_setup"], ".1f"),
            _fmt(r["time_solve"], ".1f"), _fmt(r["cpu_solve"], ".1f"),
            _fmt(r["time_total"], ".1f"), _fmt(r["peak_gb"], ".2f"),
            _fmt(r["estimated_gb"], ".2f"), f"{ratio:.2f}", _fmt(r["opening_error"], ".4f"),
            _fmt(r["diff_direct"], ".1e"), _fmt(r["diff_1rank"], ".1e"),
            _fmt(r["load"], ".1f")]) + " |")
    text = ["# Linear solvers of 3D mechanics: MUMPS and CG + GAMG", ""]
    text += [f"{c}." for c in comments] + [""]
    text += [
        "Sneddon's penny crack (`configs/penny.yaml`: radius 1 m, 1 MPa, E = 10 GPa, ν = 0.25, "
        "clamped box of half-width 5 m, P2) at mesh sizes scaled by one factor "
        f"(levels: {', '.join(f'{k} s = {v}' for k, v in LEVELS.items())}; `mesh.size = 2 s`, "
        "`mesh.fracture_size = 0.2 s`, `mesh.tip_size = 0.05 s`). Direct: MUMPS LU. Iterative: "
        "CG + GAMG (smoothed aggregation, the 6 rigid-body modes of the cracked space as "
        "near-nullspace, Chebyshev/Jacobi), `ksp_rtol` 1e-11 on the unpreconditioned residual. "
        "One process per case; wall seconds are the maximum over ranks: *mesh* (gmsh on rank 0 "
        "and distribution), *setup* (cracked space, forms, matrices), *assembly*, *solve* (the "
        "linear solve, including the *PC set-up*: GAMG hierarchy or MUMPS factorization). "
        "*Solve CPU s*: CPU seconds of the linear solve (the largest rank): the 2 cores are "
        "shared with other jobs, whose load (*load*, 1-minute load average during the case) "
        "stretches wall times. *Peak GB*: max RSS of the whole process, summed over ranks. "
        "*Est.*: the pre-mesh estimates of `poromech.scene.resources` (memory, and cells "
        "against gmsh's). *Opening error*: relative L² error of the opening against Sneddon's "
        "infinite-body solution (the box and the O(h) tip singularity). *vs direct* / *vs 1 "
        "rank*: largest displacement difference relative to the largest displacement.", ""]
    text += targets(rows) + [""] + lines
    (OUT / "solvers.md").write_text("\n".join(text) + "\n")


def figure(rows: list[dict]) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    styles = {("direct", "1"): ("s-", "MUMPS, 1 rank"),
              ("iterative", "1"): ("o-", "CG + GAMG, 1 rank"),
              ("iterative", "2"): ("^--", "CG + GAMG, 2 ranks")}
    for (solver, ranks), (style, label) in styles.items():
        sel = [r for r in rows if r["solver"] == solver and r["ranks"] == ranks
               and str(r["status"]).startswith("converged")]
        if not sel:
            continue
        n = np.array([_number(r["dofs"]) for r in sel])
        axes[0].loglog(n, [_number(r["time_solve"]) for r in sel], style, label=label)
        axes[1].loglog(n, [_number(r["peak_gb"]) for r in sel], style, label=label)
        if solver == "iterative":
            axes[2].semilogx(n, [_number(r["krylov_iterations"]) for r in sel], style,
                             label=label)
    axes[0].set_ylabel("linear solve (wall s)")
    axes[1].set_ylabel("peak memory (GB, max RSS)")
    axes[2].set_ylabel("CG iterations")
    axes[2].set_ylim(bottom=0)
    for ax in axes:
        ax.set_xlabel("P2 unknowns")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=8)
    fig.suptitle("Penny crack: MUMPS vs CG + GAMG")
    fig.subplots_adjust(wspace=0.32)
    path = OUT / "solvers.png"
    fig.savefig(path, dpi=90, bbox_inches="tight")
    assert path.stat().st_size < 300 * 1024


# -- GAMG options on one Jacobian -------------------------------------------------------------
#: Variants of the iterative defaults (``mech_`` options) compared by ``--options``.
VARIANTS = {
    "defaults": {},
    "threshold 0.01": {"pc_gamg_threshold": 0.01},
    "threshold 0.05": {"pc_gamg_threshold": 0.05},
    "unsmoothed aggregation": {"pc_gamg_agg_nsmooths": 0},
    "Chebyshev degree 3": {"mg_levels_ksp_max_it": 3},
    "coarse_eq_limit 100": {"pc_gamg_coarse_eq_limit": 100},
    "no aggressive coarsening": {"pc_gamg_aggressive_coarsening": 0},
}


def options_study(level: str, skip: list[str]) -> None:
    """Set up and solve one assembled Jacobian with each of :data:`VARIANTS` (1 rank)."""
    from petsc4py import PETSc

    from poromech.mechanics.linear import ITERATIVE_OPTIONS
    from poromech.run import Run
    from poromech.scene.loading import load_scene

    comm = MPI.COMM_WORLD
    scene = load_scene(SCENE, overrides(level, "iterative"))
    rows = []
    with Run(scene, comm=comm) as run:
        summary = run.execute()
        newton = run.physics.solver
        A = newton.A
        x0, F = A.createVecRight(), A.createVecLeft()
        x0.set(0.0)
        newton.snes.computeFunction(x0, F)  # the residual at rest: the first right side
        reference = newton.x.copy()  # the run's solution u = -J⁻¹F, to the defaults' tolerance
        db = PETSc.Options()
        for name, variant in VARIANTS.items():
            if name in skip:
                continue
            opts = {k: v for k, v in {**ITERATIVE_OPTIONS, **variant}.items() if v is not None}
            for k, v in opts.items():
                db[f"study_{k}"] = v
            ksp = PETSc.KSP().create(comm)
            ksp.setOptionsPrefix("study_")
            ksp.setOperators(A, A)
            ksp.setFromOptions()
            y = A.createVecRight()
            t0, c0 = time.perf_counter(), time.process_time()
            ksp.setUp()
            t1, c1 = time.perf_counter(), time.process_time()
            ksp.solve(F, y)
            t2, c2 = time.perf_counter(), time.process_time()
            y.axpy(1.0, reference)
            rows.append([name, ksp.getIterationNumber(), t1 - t0, c1 - c0, t2 - t1, c2 - c1,
                         c2 - c0, ksp.getPC().getMGLevels(),
                         y.norm(PETSc.NormType.INFINITY)
                         / reference.norm(PETSc.NormType.INFINITY)])
            print(rows[-1], flush=True)
            for k in opts:
                db.delValue(f"study_{k}")
            ksp.destroy()
            y.destroy()
    header = ["variant", "CG iterations", "set-up s", "set-up CPU s", "solve s", "solve CPU s",
              "total CPU s", "levels", "vs run"]
    command = " ".join([COMMAND, *map(shlex.quote, sys.argv[1:])])
    stamp = f"Generated by `{command}` ({datetime.date.today()}), {summary['dofs']} unknowns"
    OUT.mkdir(parents=True, exist_ok=True)
    with open(OUT / "gamg_options.csv", "w", newline="") as fh:
        fh.write(f"# {stamp}\n")
        w = csv.writer(fh)
        w.writerow(header)
        for r in rows:
            w.writerow([f"{v:.4g}" if isinstance(v, float) else v for v in r])
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(f"{v:.3g}" if isinstance(v, float) else str(v) for v in r)
              + " |" for r in rows]
    text = [
        "# GAMG options for the penny crack", "", f"{stamp}.", "",
        "One assembled Jacobian of the penny crack (level " + level + ", 1 rank), set up and "
        "solved from the same right-hand side with the iterative defaults "
        "(`poromech.mechanics.linear.ITERATIVE_OPTIONS`: CG, `ksp_rtol` 1e-11 unpreconditioned, "
        "GAMG smoothed aggregation, threshold 0, aggressive coarsening of the first level, "
        "Chebyshev(2)/Jacobi, `coarse_eq_limit` 1000) and one change at a time. CPU seconds "
        "are this process's (the machine is shared; wall seconds include waiting). *vs run*: "
        "largest difference to the run's solution relative to its largest value.", "", *lines]
    (OUT / "gamg_options.md").write_text("\n".join(text) + "\n")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", nargs="+", default=list(LEVELS), choices=list(LEVELS))
    parser.add_argument("--solvers", nargs="+", default=["direct", "iterative"],
                        choices=["direct", "iterative"])
    parser.add_argument("--ranks", nargs="+", type=int, default=[1, 2])
    parser.add_argument("--direct-levels", nargs="+", default=list(DIRECT_LEVELS),
                        choices=list(LEVELS), help="levels also solved with MUMPS")
    parser.add_argument("--work", help="directory of the cases' results (kept; compared)")
    parser.add_argument("--options", metavar="LEVEL", choices=list(LEVELS),
                        help="compare GAMG options on one Jacobian of this level instead")
    parser.add_argument("--skip", nargs="*", default=[], help="--options variants left out")
    parser.add_argument("--report", action="store_true",
                        help="run nothing: rewrite the report from the CSV (estimates anew)")
    parser.add_argument("--case", nargs=2, metavar=("LEVEL", "SOLVER"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.case:
        run_case(*args.case, Path(args.work))
    elif args.options:
        options_study(args.options, args.skip)
    else:
        study(args)


if __name__ == "__main__":
    main()
