"""A network of eleven intersecting fractures in contact, about a million P2 unknowns.

Scene: ``configs/network3d_large.yaml`` (a 2 m box, four X pairs of discs, a T and a polygon
reaching the front face; bottom fixed, top pushed down in step 1 and sheared along x in steps
2-5; Coulomb friction F = 0.5, P2). Each formulation runs in its own process(es) (``mpirun -n R``
for R ranks) with the scene's linear solver ``auto``: GMRES + GAMG with the rigid-body modes for
``nitsche``; the same on the displacement Schur complement for ``mean_nitsche`` and
``stabilized_mixed`` (face unknowns eliminated face by face); MUMPS for ``mixed``, whose face
block is singular in contact (it is run only where MUMPS fits: ``--levels`` gives the mesh
scale, 1 = the scene's mesh).

Columns: ``dofs`` unknowns; ``newton`` Newton iterations per load step; ``krylov`` Krylov
iterations in total; ``pc_setups`` GAMG set-ups (or factorizations); ``time_*`` wall seconds
(rank maximum) of meshing, set-up, assembly, linear solves (with the ``pc`` set-ups) and the
whole run; ``peak_gb`` the summed max RSS of the ranks; ``load`` the 1-minute load average (2
shared cores: wall times are upper bounds).

Run::

    python scripts/contact3d_large_network.py --ranks 2 --formulations nitsche
    python scripts/contact3d_large_network.py --ranks 2 --formulations mixed --levels 2 --append
    python scripts/contact3d_large_network.py --report    # redraw docs/mechanics3d/large_network.md
"""

from __future__ import annotations

import argparse
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

from report_common import fmt, read_csv, write_csv

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics3d"
SCENE = ROOT / "configs" / "network3d_large.yaml"
FORMULATIONS = ("nitsche", "mean_nitsche", "stabilized_mixed", "mixed")
FIELDS = ["formulation", "level", "ranks", "solver", "cells", "fracture_faces", "dofs", "status",
          "newton", "newton_total", "krylov", "pc_setups", "time_mesh", "time_setup",
          "time_assembly", "time_linear", "time_pc", "time_total", "peak_gb", "load"]


def overrides(formulation: str, level: float, steps: int = 5) -> list[str]:
    """``--set`` overrides: formulation, mesh scaled by ``level``, first ``steps`` steps."""
    sets = [f"contact.formulation={formulation}", "output.xdmf=false",
            f"time.final={steps:g}", f"time.steps={steps}"]
    if level != 1:
        sets += [f"mesh.size={0.08 * level:g}", f"mesh.fracture_size={0.0265 * level:g}"]
    return sets


def run_case(formulation: str, level: float, steps: int, out: Path) -> None:
    """Solve one case (all ranks); rank 0 writes ``out`` (a JSON row)."""
    import dolfinx_solver  # noqa: F401

    from mpi4py import MPI

    from poromech.run import run_scene
    from poromech.scene.loading import load_scene

    comm = MPI.COMM_WORLD
    load0 = os.getloadavg()[0]
    scene = load_scene(SCENE, overrides(formulation, level, steps))
    with tempfile.TemporaryDirectory() as tmp:
        work = comm.bcast(tmp if comm.rank == 0 else None)
        try:
            summary = run_scene(scene, Path(work) / "run", comm)
            status = summary["status"]
        except Exception as err:  # a failed case is a row too
            summary, status = None, f"error: {str(err).splitlines()[0][:200]}"
        comm.barrier()
    peak = comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0)
    if comm.rank != 0:
        return
    row = {"formulation": formulation, "level": level, "ranks": comm.size, "status": status,
           "peak_gb": peak / 1e9, "load": 0.5 * (load0 + os.getloadavg()[0])}
    out.write_text(json.dumps(summary_row(row, summary)))


def summary_row(row: dict, summary: dict | None) -> dict:
    """``row`` completed with the numbers of a run's ``summary.json``."""
    if summary is not None:
        wall, records = summary["wall_time"], summary["solves"]
        row.update({
            "solver": summary["linear_solver"]["kind"], "cells": summary["mesh"]["cells"],
            "fracture_faces": summary["mesh"]["fracture_faces"], "dofs": summary["dofs"],
            "newton": "/".join(str(r["iterations"]) for r in records),
            "newton_total": sum(r["iterations"] for r in records),
            "krylov": sum(r["linear_iterations"] for r in records),
            "pc_setups": sum(r["factorizations"] for r in records),
            "time_mesh": wall.get("mesh", 0.0), "time_setup": wall.get("setup", 0.0),
            "time_assembly": wall.get("assembly", 0.0),
            "time_linear": wall.get("linear_solve", 0.0),
            "time_pc": sum(r["time_preconditioner"] for r in records),
            "time_total": wall["total"]})
    return row


def launch(formulation: str, level: float, ranks: int, steps: int) -> dict:
    """One case in its own process(es); its row."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "row.json"
        cmd = [sys.executable, __file__, "--case", formulation, str(level), str(steps),
               str(out)]
        if ranks > 1:
            cmd = [str(Path(sys.executable).with_name("mpirun")), "-n", str(ranks), *cmd]
        print(f"{formulation} level {level} on {ranks} rank(s) ...", flush=True)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        if not out.exists():
            tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
            return {"formulation": formulation, "level": level, "ranks": ranks,
                    "status": f"error: {tail[0][:200]}"}
        row = json.loads(out.read_text())
    print(f"  {row.get('dofs')} dofs, Newton {row.get('newton')}, {row.get('krylov')} Krylov, "
          f"{time.perf_counter() - t0:.0f} s, {row['peak_gb']:.1f} GB, {row['status']}",
          flush=True)
    return row


def latest(rows: list[dict]) -> list[dict]:
    """The last row of each formulation, level and ranks, by level and formulation."""
    def key(r: dict) -> tuple:
        return float(r["level"]), FORMULATIONS.index(r["formulation"]), int(r["ranks"])

    return sorted({key(r): r for r in rows}.values(), key=key)


def report(rows: list[dict], commands: list[str]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    rows = latest(rows)
    commands = contributing(commands, rows)
    stamp = "; ".join(f"`{c}`" for c in commands)
    write_csv(OUT / "large_network.csv", commands, FIELDS, rows)
    keys = [k for k in FIELDS if k not in ("fracture_faces",)]
    lines = [f"# Eleven intersecting fractures in contact, about a million P2 unknowns\n\n"
             f"Generated by {stamp} ({datetime.date.today()}). See the docstring of "
             "`scripts/contact3d_large_network.py` for the scene and the columns.\n\n"
             "| " + " | ".join(keys) + " |\n|" + "---|" * len(keys) + "\n"]
    for r in rows:
        lines.append("| " + " | ".join(fmt(r.get(k, "")) for k in keys) + " |\n")
    done = [r for r in rows if r.get("status") == "converged" and int(r.get("dofs") or 0) >= 1e6
            and len(str(r.get("newton", "")).split("/")) == 5]
    if done:
        best = min(done, key=lambda r: float(r["time_total"]))
        total = float(best["time_total"])
        lines.append(f"\nFastest at ≥ 1 million unknowns: {best['formulation']} on "
                     f"{best['ranks']} rank(s), {total:.0f} s for the 5 load steps (target "
                     f"600 s: {'met' if total <= 600 else 'not met'}), peak "
                     f"{float(best['peak_gb']):.1f} GB.\n")
    (OUT / "large_network.md").write_text("".join(lines))


def contributing(commands: list[str], rows: list[dict]) -> list[str]:
    """The commands that made the current rows, in their order.

    For each row the last command covering its formulation, level and ranks; earlier commands
    whose rows were all replaced are dropped.
    """
    def covers(command: str) -> set[tuple]:
        a = parser().parse_args(shlex.split(command)[2:])
        return {(f, float(lv), a.ranks) for f in a.formulations for lv in a.levels}

    cover = [covers(c) for c in commands]
    made = {max((i for i, c in enumerate(cover)
                 if (r["formulation"], float(r["level"]), int(r["ranks"])) in c), default=-1)
            for r in rows}
    return [c for i, c in enumerate(commands) if i in made]


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--formulations", nargs="+", default=list(FORMULATIONS),
                   choices=FORMULATIONS)
    p.add_argument("--levels", nargs="+", type=float, default=[1.0],
                   help="mesh scale factors (1: the scene's mesh, larger: coarser)")
    p.add_argument("--ranks", type=int, default=2)
    p.add_argument("--append", action="store_true",
                   help="add to the existing rows (replacing those of the same formulation, "
                   "level and ranks)")
    p.add_argument("--report", action="store_true", help="rewrite the Markdown from the CSV")
    p.add_argument("--steps", type=int, default=5, help="the first load steps only")
    p.add_argument("--summary", type=Path, help="add the row of the summary.json of a run of "
                   "this scene (e.g. one stopped after its first steps) for --formulations, "
                   "--levels and --ranks")
    p.add_argument("--case", nargs=4, help=argparse.SUPPRESS)
    return p


def main() -> None:
    args = parser().parse_args()
    if args.case:
        run_case(args.case[0], float(args.case[1]), int(args.case[2]), Path(args.case[3]))
        return
    commands, old = read_csv(OUT / "large_network.csv", text=("newton",))
    if args.report:
        report(old, commands)
        return
    rows = old if args.append else []
    commands = commands if args.append else []
    if args.summary:
        summary = json.loads(args.summary.read_text())
        status = summary["status"]
        if status == "running":  # a run stopped by hand
            status = f"stopped after {summary['completed_steps']} step(s)"
        rows.append(summary_row({"formulation": args.formulations[0], "level": args.levels[0],
                                 "ranks": args.ranks, "status": status,
                                 "peak_gb": float("nan"), "load": float("nan")}, summary))
    else:
        for f in args.formulations:
            for level in args.levels:
                rows.append(launch(f, level, args.ranks, args.steps))
    # the summary file of --summary is named by its run directory's role, not its place
    argv = ["RUN/summary.json" if args.summary and a == str(args.summary) else a
            for a in sys.argv[1:]]
    command = "python scripts/contact3d_large_network.py " + " ".join(argv)
    report(rows, [*commands, command])


if __name__ == "__main__":
    main()
