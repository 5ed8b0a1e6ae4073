"""Scale run of the 3D HFV flow solver: the fracture network of ``configs/flow3d_network.yaml``.

Level ``l`` scales the scene's ``mesh.size`` and ``mesh.fracture_size`` by ``2^(-l/2)`` (level 0
is the shipped mesh, about 67k unknowns; each level adds about 2.3 times the unknowns). Every
case runs in its own process(es), ``mpirun -n R`` for R ranks, and its row is appended to
``docs/flow/flow3d_scale.csv`` as soon as it finishes, so that a killed run keeps the finished
rows. A case meshes once and solves the steady problem with one or more solver *variants*:
``gamg`` (the 3D defaults of ``poromech/flow/solver.py``: CG + GAMG with two levels of
aggressive coarsening; ``aggressive_1`` has one, as in 2D), ``mumps`` (LU) and the GAMG option
changes of :data:`VARIANTS`, each in its own process or, with ``--together``, one after the
other on one mesh (the option study).

Columns: ``unknowns``; ``shifted`` fracture faces solved in shifted variables
(``poromech/flow/shift.py``); ``iterations`` CG iterations to rtol 1e-12 (relative to the
initial natural-norm residual); ``gmsh_s`` the mesh generation on rank 0 (gmsh and the mesh
arrays); ``mesh_s`` all of the meshing: ``gmsh_s``, then the distribution and the fracture
faces;
``setup_s`` the flow set-up (geometry, numbering, COO pattern, PETSc objects); ``pc_setup_s``
the GAMG set-up or the factorization; ``solve_s`` the solve including ``pc_setup_s``; wall
seconds, rank maximum; ``peak_gb`` the summed peak RSS of the ranks at the end of the case
(for the later variants of a case, the peak of the whole process so far); ``peak_mesh_gb`` the
same after meshing; ``mass_balance_rel`` the relative global mass-balance residual; ``outflow``
the flux through the right face (m³/s); ``load`` the 1-minute load average (2 shared cores:
times are upper bounds).

Run::

    python scripts/flow3d_scale.py --levels 0 1 2 3 4 5 --ranks 1 2
    python scripts/flow3d_scale.py --levels 0 1 2 3 --ranks 1 --variants mumps --append
    python scripts/flow3d_scale.py --levels 0 2 --ranks 1 --append --together --variants gamg mis2
    python scripts/flow3d_scale.py --report     # redraw the Markdown and the figure from the CSV
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from report_common import fmt, read_csv, write_csv

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "flow"
SCENE = ROOT / "configs" / "flow3d_network.yaml"
SIZE, FRACTURE_SIZE = 0.1, 0.05  # the scene's mesh sizes (m)
FIELDS = ["level", "ranks", "variant", "case", "cells", "fracture_faces", "unknowns", "shifted",
          "iterations", "gmsh_s", "mesh_s", "setup_s", "pc_setup_s", "solve_s", "peak_mesh_gb",
          "peak_gb", "mass_balance_rel", "outflow", "status", "load"]

#: Solver variants: (flow.linear_solver, options merged over its defaults, shift ratio or None
#: for the default). A ``null`` option removes a default.
VARIANTS: dict[str, tuple[str, dict, float | None]] = {
    "gamg": ("iterative", {}, None),
    "mumps": ("direct", {}, None),
    "threshold_0": ("iterative", {"pc_gamg_threshold": 0.0}, None),
    "threshold_0.01": ("iterative", {"pc_gamg_threshold": 0.01}, None),
    "threshold_0.05": ("iterative", {"pc_gamg_threshold": 0.05}, None),
    "threshold_0.1": ("iterative", {"pc_gamg_threshold": 0.1}, None),
    "nsmooths_0": ("iterative", {"pc_gamg_agg_nsmooths": 0}, None),
    "aggressive_0": ("iterative", {"pc_gamg_aggressive_coarsening": 0}, None),
    "aggressive_1": ("iterative", {"pc_gamg_aggressive_coarsening": 1}, None),  # 2D default
    "aggressive_3": ("iterative", {"pc_gamg_aggressive_coarsening": 3}, None),
    "mis2": ("iterative", {"pc_gamg_aggressive_square_graph": False}, None),
    "sor": ("iterative", {"mg_levels_ksp_type": "richardson", "mg_levels_pc_type": "sor"}, None),
    "smooth_3": ("iterative", {"mg_levels_ksp_max_it": 3}, None),
    "no_shift": ("iterative", {}, float("inf")),
    "shift_all": ("iterative", {}, 0.0),
}
STUDY = [v for v in VARIANTS if v not in ("gamg", "mumps")]


def overrides(level: float) -> list[str]:
    """``--set`` overrides of a level: mesh sizes scaled by ``2^(-level/2)``, no output."""
    s = 2.0 ** (-level / 2)
    return [f"mesh.size={SIZE * s:.6g}", f"mesh.fracture_size={FRACTURE_SIZE * s:.6g}",
            "output.xdmf=false"]


def peak_gb(comm) -> float:
    """Summed peak resident memory of the ranks (GB, collective)."""
    return comm.allreduce(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0) / 1e9


def timed(comm, fn):
    """``fn()`` and its wall time, rank maximum (collective)."""
    from mpi4py import MPI

    comm.barrier()
    t0 = time.perf_counter()
    out = fn()
    return out, comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)


def solve_variant(scene, fm, name: str, base: dict) -> dict:
    """Build the flow problem with a variant's solver, solve, and the row (collective)."""
    from dataclasses import replace

    from poromech.flow.balance import boundary_fluxes, compute_fluxes, mass_balance
    from poromech.flow.setup import problem_from_scene

    kind, options, ratio = VARIANTS[name]
    comm = fm.comm
    flow = replace(scene.flow, linear_solver=kind, petsc={**scene.flow.petsc, **options})
    pb, t_setup = timed(comm, lambda: problem_from_scene(replace(scene, flow=flow), fm))
    if ratio is not None:
        pb.shift.ratio = ratio
        pb.set_properties(pb.properties)
    row = base | {"variant": name, "unknowns": pb.dofs.num_global,
                  "shifted": pb.shift.num_shifted, "setup_s": t_setup}
    try:
        rec = pb.solve()
        fluxes = compute_fluxes(pb)
        row |= {"iterations": rec.iterations, "pc_setup_s": rec.setup_seconds,
                "solve_s": rec.seconds, "status": rec.reason,
                "mass_balance_rel": mass_balance(pb, fluxes)["relative_residual"],
                "outflow": boundary_fluxes(pb, fluxes)["right"]["total"]}
    except Exception as err:  # a failed solve is a row too
        row["status"] = f"error: {str(err).splitlines()[0][:120]}"
    pb.destroy()
    row["peak_gb"] = peak_gb(comm)
    return row


def run_case(level: float, variants: list[str], out: Path) -> None:
    """Mesh a level once and solve it with each variant (all ranks); rank 0 writes the rows."""
    import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

    from mpi4py import MPI

    from poromech.mesh.fractured import distribute_mesh
    from poromech.mesh.generate3d import generate_mesh_3d
    from poromech.scene.geometry import mesh_sizes, scene_geometry
    from poromech.scene.loading import load_scene

    comm = MPI.COMM_WORLD
    load0 = os.getloadavg()[0]
    scene = load_scene(SCENE, overrides(level))
    geo, gmsh_s = scene_geometry(scene), [0.0]

    def arrays():  # on rank 0 (poromech.run.build_mesh, timed)
        t0 = time.perf_counter()
        out = generate_mesh_3d(geo, mesh_sizes(scene))
        gmsh_s[0] = time.perf_counter() - t0
        return out

    fm, t_mesh = timed(comm, lambda: distribute_mesh(comm, geo, arrays))
    top = fm.msh.topology
    base = {"level": level, "ranks": comm.size, "mesh_s": t_mesh, "gmsh_s": comm.bcast(gmsh_s[0]),
            "cells": top.index_map(3).size_global, "peak_mesh_gb": peak_gb(comm),
            "fracture_faces": comm.allreduce(len(fm.fractures.facets))}
    for name in variants:
        row = solve_variant(scene, fm, name, base | {"case": "+".join(variants)})
        row["load"] = 0.5 * (load0 + os.getloadavg()[0])
        if comm.rank == 0:
            with open(out, "a") as fh:
                fh.write(json.dumps(row) + "\n")


def launch(level: float, ranks: int, variants: list[str]) -> list[dict]:
    """One case in its own process(es); its rows (a failed process gives one error row)."""
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "rows.jsonl"
        cmd = [sys.executable, __file__, "--case", str(level), ",".join(variants), str(out)]
        if ranks > 1:
            cmd = [str(Path(sys.executable).with_name("mpirun")), "-n", str(ranks), *cmd]
        print(f"level {level:g} on {ranks} rank(s): {', '.join(variants)} ...", flush=True)
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT)
        rows = [json.loads(ln) for ln in out.read_text().splitlines()] if out.exists() else []
    for r in rows:
        print(f"  {r['variant']}: {r['unknowns']} unknowns, {r.get('iterations')} it., solve "
              f"{r.get('solve_s', float('nan')):.2f} s, {r['peak_gb']:.2f} GB, {r['status']}",
              flush=True)
    done = {r["variant"] for r in rows}
    if proc.returncode != 0 or len(done) < len(variants):
        tail = (proc.stderr or proc.stdout).strip().splitlines()[-1:] or ["?"]
        rows += [{"level": level, "ranks": ranks, "variant": v, "case": "+".join(variants),
                  "status": f"error: {tail[0][:160]}"} for v in variants if v not in done]
    print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    return rows


def replaced(rows: list[dict], new: list[dict]) -> list[dict]:
    """The rows with each new row in place of an earlier one of its case, else added.

    A case is its level, ranks, variant and the variants it was run with: running one again
    with ``--append`` replaces its row instead of adding a second one.
    """
    def key(r: dict) -> tuple:
        return float(r["level"]), int(r["ranks"]), str(r["variant"]), str(r["case"])

    fresh = {key(r): r for r in new}
    kept = [fresh.pop(key(r), r) for r in rows]
    return kept + [r for r in new if key(r) in fresh]


MAIN = ["level", "ranks", "variant", "unknowns", "shifted", "iterations", "gmsh_s", "mesh_s",
        "setup_s", "pc_setup_s", "solve_s", "peak_mesh_gb", "peak_gb", "mass_balance_rel",
        "outflow", "load"]


def cell(row: dict, key: str) -> str:
    """A table cell: five digits for the outflow, three otherwise, blank when missing."""
    v = row.get(key, "")
    if v == "" or v is None:
        return ""
    return f"{v:.5g}" if key == "outflow" and isinstance(v, float) else fmt(v)


def table(rows: list[dict], keys: list[str]) -> list[str]:
    """Markdown table lines."""
    out = ["| " + " | ".join(keys) + " |", "|" + "---|" * len(keys)]
    return out + ["| " + " | ".join(cell(r, k) for k in keys) + " |" for r in rows]


def study_table(rows: list[dict]) -> list[str]:
    """Iterations and solve seconds (with the set-up) of the study, one column per level."""
    study = [r for r in rows if "+" in r["case"]]
    if not study:
        return []
    keys = sorted({(r["level"], r["ranks"]) for r in study})
    by = {(r["variant"], r["level"], r["ranks"]): r for r in study}
    unknowns = {k: by.get(("gamg", *k), {}).get("unknowns", "") for k in keys}
    head = ["variant", *(f"level {lv:g}, {n} unknowns, {rk} rank{'s' if rk > 1 else ''}"
                         for (lv, rk), n in unknowns.items())]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for v in ["gamg", *STUDY]:
        cells = []
        for k in keys:
            r = by.get((v, *k))
            if r is None:
                cells.append("")
            elif not str(r.get("status", "")).startswith("CONVERGED"):
                cells.append(str(r["status"]).partition("converge: ")[2].partition(",")[0]
                             or str(r["status"])[:40])
            else:
                cells.append(f"{r['iterations']} it., {r['solve_s']:.3g} s "
                             f"(set-up {r['pc_setup_s']:.2g})")
        lines.append(f"| {v} {describe(v)} | " + " | ".join(cells) + " |")
    return lines


def describe(name: str) -> str:
    """The options of a variant, for the study table."""
    _, options, ratio = VARIANTS[name]
    text = ", ".join(f"`{k}={v}`" for k, v in options.items())
    if ratio is not None:
        text = f"shift ratio {ratio:g}"
    return f"({text})" if text else "(defaults)"


def speedups(rows: list[dict]) -> list[str]:
    """Solve and total (set-up + solve) speed-up of 2 ranks over 1, GAMG, per level."""
    by = {(r["level"], r["ranks"]): r for r in rows if r["case"] == "gamg"
          and str(r.get("status", "")).startswith("CONVERGED")}
    lines = []
    for level in sorted({lv for lv, _ in by}):
        one, two = by.get((level, 1)), by.get((level, 2))
        if one and two:
            tot = [r["setup_s"] + r["solve_s"] for r in (one, two)]
            lines.append(f"| {level:g} | {one['unknowns']} | {one['solve_s'] / two['solve_s']:.2f}"
                         f" | {tot[0] / tot[1]:.2f} | {one['mesh_s'] / two['mesh_s']:.2f} |")
    if lines:
        lines = ["| level | unknowns | solve | set-up + solve | mesh |", "|---|---|---|---|---|",
                 *lines]
    return lines


#: Curves of the figure: (variant, ranks) → (label, matplotlib style).
CURVES = {
    ("gamg", 1): ("CG + GAMG, 3D defaults, 1 rank", "o-C0"),
    ("gamg", 2): ("CG + GAMG, 3D defaults, 2 ranks", "s-C1"),
    ("aggressive_1", 1): ("CG + GAMG, 2D coarsening, 1 rank", "o--C2"),
    ("aggressive_1", 2): ("CG + GAMG, 2D coarsening, 2 ranks", "s--C3"),
    ("mumps", 1): ("MUMPS, 1 rank", "^:C4"),
    ("mumps", 2): ("MUMPS, 2 ranks", "v:C5"),
}


def figure(rows: list[dict]) -> None:
    """Iterations and wall times against unknowns (PNG, below 300 KB)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from flow_common import save_figure

    ok = [r for r in rows if r["case"] == r["variant"]
          and str(r.get("status", "")).startswith("CONVERGED")]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for (variant, ranks), (label, style) in CURVES.items():
        sel = sorted((r for r in ok if r["variant"] == variant and r["ranks"] == ranks),
                     key=lambda r: r["unknowns"])
        if not sel:
            continue
        n = [r["unknowns"] for r in sel]
        if variant != "mumps":
            a.semilogx(n, [r["iterations"] for r in sel], style, label=label)
        b.loglog(n, [r["solve_s"] for r in sel], style, label=label)
        if variant == "gamg":
            b.loglog(n, [r["mesh_s"] for r in sel], style[0] + "-.k", alpha=0.5, ms=4,
                     label=f"meshing, {ranks} rank{'s' if ranks > 1 else ''}")
    a.set_ylim(0, 60)
    a.set_xlabel("unknowns")
    a.set_ylabel("CG iterations (rtol 1e-12)")
    a.set_title("CG iterations")
    b.set_xlabel("unknowns")
    b.set_ylabel("wall time (s)")
    b.set_title("Solve (with the preconditioner set-up), meshing")
    for ax, where in ((a, "lower right"), (b, "upper left")):
        ax.grid(alpha=0.3, which="both")
        if ax.get_legend_handles_labels()[0]:
            ax.legend(fontsize=7, loc=where)
    save_figure(fig, OUT / "flow3d_scale.png")
    plt.close(fig)


def report(rows: list[dict], commands: list[str]) -> None:
    """``flow3d_scale.md`` and ``flow3d_scale.png`` from the rows."""
    main = [r for r in rows if r["case"] == r["variant"]]
    order = ["gamg", "aggressive_1", "mumps", *VARIANTS]
    main.sort(key=lambda r: (order.index(r["variant"]), r["level"], r["ranks"]))
    lines = ["# 3D flow: solver scaling on the fracture network of "
             "`configs/flow3d_network.yaml`", "",
             f"Generated {datetime.date.today()} by", "",
             *(f"    {c}" for c in commands), "",
             "Levels scale the scene's mesh sizes by 2^(-level/2); see the docstring of "
             "`scripts/flow3d_scale.py` for the columns. Times are wall-clock on a 2-core "
             "machine shared with other work (`load`: its 1-minute load average).", "",
             "## CG + GAMG and MUMPS", "",
             "`gamg`: the 3D defaults; `aggressive_1`: the same with one level of aggressive "
             "coarsening (the 2D default, and the 3D default before this study); `mumps`: LU.",
             "", *table(main, MAIN), ""]
    speed = speedups(rows)
    if speed:
        lines += ["## Speed-up of 2 ranks over 1 (CG + GAMG)", "", *speed, ""]
    study = study_table(rows)
    if study:
        lines += ["## GAMG options", "",
                  "Each variant merges its options over the 3D defaults (`flow.petsc`; "
                  "`pc_gamg_aggressive_coarsening=2`), on the same mesh; `shift ratio` "
                  "changes the trace-shift threshold (`poromech/flow/shift.py`, default 1e3: "
                  "inf = no face shifted, 0 = all). `mis2` is not run on 2 ranks: its set-up "
                  "did not finish in 17 minutes at level 4 (10 s on 1 rank), nor in 2 minutes "
                  "at level 0 (PETSc 3.25).",
                  "", *study, ""]
    lines += ["![iterations and times](flow3d_scale.png)", ""]
    (OUT / "flow3d_scale.md").write_text("\n".join(lines))
    figure(rows)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--levels", nargs="+", type=float, default=[0, 1, 2, 3, 4, 5])
    p.add_argument("--ranks", nargs="+", type=int, default=[1, 2])
    p.add_argument("--variants", nargs="+", default=["gamg"], choices=list(VARIANTS))
    p.add_argument("--together", action="store_true",
                   help="all variants in one process, on one mesh (else one process each)")
    p.add_argument("--append", action="store_true", help="add to the existing rows")
    p.add_argument("--report", action="store_true", help="redraw the Markdown and the figure")
    p.add_argument("--case", nargs=3, help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.case:
        run_case(float(args.case[0]), args.case[1].split(","), Path(args.case[2]))
        return
    commands, rows = read_csv(OUT / "flow3d_scale.csv", text=("variant", "case", "status"))
    if not args.report:
        if not args.append:
            commands, rows = [], []
        command = "python scripts/flow3d_scale.py " + " ".join(sys.argv[1:])
        commands = [c for c in commands if c != command] + [command]
        groups = [args.variants] if args.together else [[v] for v in args.variants]
        for level in args.levels:
            for ranks in args.ranks:
                for variants in groups:
                    rows = replaced(rows, launch(level, ranks, variants))
                    write_csv(OUT / "flow3d_scale.csv", commands, FIELDS, rows)
    report(rows, commands)


if __name__ == "__main__":
    main()
