"""Error against run time of every contact formulation × displacement degree.

Scenes: ``configs/sneddon.yaml`` (open pressurized crack, contact switched on) and
``configs/inclined_crack_slip.yaml`` (closed crack slipping with Coulomb friction), both with
their exact solutions imposed on the box. For each variant and each uniform refinement level the
script records the relative L² and max errors of the jump, the Newton iterations and the wall time
(mesh + setup + solve, with forms already compiled).

Run (about 10 minutes on 2 cores)::

    python scripts/mechanics_convergence.py

Writes ``docs/mechanics/convergence.csv``, ``convergence.md`` and ``convergence.png``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import shlex
import sys
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from mpi4py import MPI

from poromech.run import Run, build_mesh
from poromech.scene.loading import load_scene
from poromech.verification.jumps import exact_jump, jump_errors

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics"
VARIANTS = [
    ("mixed", -1),
    ("stabilized_mixed", -1),
    ("mean_nitsche", -1),
    ("nitsche", -1),
    ("nitsche", 0),
    ("nitsche", 1),
]
SCENES = ["sneddon", "inclined_crack_slip"]
FIELDS = ["scene", "formulation", "theta", "degree", "level", "cells", "fracture_faces", "dofs",
          "newton_iterations", "face_iterations", "l2", "max", "l2_n", "l2_t", "time_mesh",
          "time_setup", "time_solve", "time_total"]


def label(formulation: str, theta: int) -> str:
    """Short name of a variant."""
    if formulation in ("nitsche",):
        return f"nitsche θ={theta:+d}"
    return formulation.replace("_", "-")


def run_case(name: str, formulation: str, theta: int, degree: int, level: int) -> dict:
    """Solve one case and measure errors and times (collective)."""
    comm = MPI.COMM_WORLD
    scene = load_scene(ROOT / "configs" / f"{name}.yaml", [
        f"contact.formulation={formulation}", f"contact.theta={theta}", f"degree={degree}",
        f"mesh.refinement={level}"])
    t0 = time.perf_counter()
    fm = build_mesh(scene, comm)
    t1 = time.perf_counter()
    with Run(scene, mesh=fm) as run:
        summary = run.execute()
        model = run.physics.model
    t3 = time.perf_counter()
    records = summary["solves"]
    t2 = t1 + summary["wall_time"]["setup"]  # physics set-up: forms, matrices, factorizations
    err = jump_errors(model.u, fm, exact_jump(scene))
    row = {
        "scene": name, "formulation": formulation, "theta": theta, "degree": degree,
        "level": level, "cells": fm.msh.topology.index_map(2).size_global,
        "fracture_faces": fm.num_fracture_faces, "dofs": summary["dofs"],
        "newton_iterations": sum(r["iterations"] for r in records),
        "face_iterations": sum(r.get("face_iterations", 0) for r in records),
        **{k: err[k] for k in ("l2", "max", "l2_n", "l2_t")},
        "time_mesh": t1 - t0, "time_setup": t2 - t1, "time_solve": t3 - t2, "time_total": t3 - t0,
    }
    return row


def fastest_at(rows: list[dict], target: float) -> tuple[str, float] | None:
    """Variant reaching a relative L² error ``target`` in the least (log-interpolated) time."""
    best = None
    keys = sorted({(r["formulation"], r["theta"], r["degree"]) for r in rows})
    for key in keys:
        rs = sorted([r for r in rows if (r["formulation"], r["theta"], r["degree"]) == key],
                    key=lambda r: r["level"])
        for a, b in zip(rs, rs[1:], strict=False):
            if a["l2"] >= target >= b["l2"]:
                w = np.log(a["l2"] / target) / np.log(a["l2"] / b["l2"])
                t = np.exp((1 - w) * np.log(a["time_total"]) + w * np.log(b["time_total"]))
                name = f"{label(key[0], key[1])} P{key[2]}"
                if best is None or t < best[1]:
                    best = (name, float(t))
                break
    return best


def write_markdown(rows: list[dict], path: Path, command: str) -> None:
    """Tables per scene with observed rates, and the fastest variant per accuracy."""
    lines = ["# Error against run time of the contact formulations",
             "", f"Generated {datetime.date.today()} by `{command}` "
             f"({MPI.COMM_WORLD.size} MPI rank(s)). Errors: relative L² and max norm of the "
             "jump on Γ against the exact solution; time: mesh + setup + Newton solve (s), "
             "forms already compiled. `+Nf`: face Newton iterations of the condensed `mixed` "
             "solve (P2; its set-up is in the time).", ""]
    for name in SCENES:
        lines += [f"## {name}", "",
                  "| variant | P | level | dofs | Newton it | L² error | rate | max error "
                  "| time (s) |",
                  "|---|---|---|---|---|---|---|---|---|"]
        sub = [r for r in rows if r["scene"] == name]
        for formulation, theta in VARIANTS:
            for degree in (1, 2):
                rs = sorted([r for r in sub if r["formulation"] == formulation
                             and r["theta"] == theta and r["degree"] == degree],
                            key=lambda r: r["level"])
                prev = None
                for r in rs:
                    rate = "" if prev is None else f"{np.log2(prev / r['l2']):.2f}"
                    face = f"+{r['face_iterations']}f" if r.get("face_iterations") else ""
                    lines.append(
                        f"| {label(formulation, theta)} | {degree} | {r['level']} | {r['dofs']} | "
                        f"{r['newton_iterations']}{face} | {r['l2']:.3e} | {rate} | "
                        f"{r['max']:.3e} | "
                        f"{r['time_total']:.2f} |")
                    prev = r["l2"]
        lines += ["", "Fastest variant to reach a given relative L² error (log-interpolated "
                  "between levels):", "", "| L² error | fastest | time (s) |", "|---|---|---|"]
        for target in (2e-2, 1e-2, 5e-3, 2e-3, 1e-3):
            best = fastest_at(sub, target)
            if best:
                lines.append(f"| {target:.0e} | {best[0]} | {best[1]:.2f} |")
        lines.append("")
    path.write_text("\n".join(lines) + "\n")


def plot(rows: list[dict], path: Path) -> None:
    """Log-log error against run time, one panel per scene."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(SCENES), figsize=(11, 4.2))
    labels = [label(*v) for v in VARIANTS]
    markers = dict(zip(labels, "osD^v<", strict=True))
    colors = dict(zip(labels, ["C0", "C1", "C2", "C3", "C4", "C5"], strict=True))
    for ax, name in zip(axes, SCENES, strict=False):
        for formulation, theta in VARIANTS:
            for degree, ls in ((1, "--"), (2, "-")):
                rs = sorted([r for r in rows if r["scene"] == name and r["formulation"] ==
                             formulation and r["theta"] == theta and r["degree"] == degree],
                            key=lambda r: r["level"])
                if rs:
                    lab = label(formulation, theta)
                    ax.loglog([r["time_total"] for r in rs], [r["l2"] for r in rs], ls,
                              color=colors[lab], marker=markers[lab], ms=4,
                              label=f"{lab} P{degree}")
        ax.set_xlabel("wall time (s)")
        ax.set_ylabel("relative L² error of the jump")
        ax.set_title(name)
        ax.grid(True, which="both", alpha=0.3)
    axes[-1].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def read_rows(path: Path) -> list[dict]:
    """Rows of a previous run, with numbers parsed."""
    ints = {"theta", "degree", "level", "cells", "fracture_faces", "dofs", "newton_iterations",
            "face_iterations"}
    rows = []
    for r in csv.DictReader(open(path)):
        rows.append({k: (v if k in ("scene", "formulation") else int(v) if k in ints
                         else float(v)) for k, v in r.items()})
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels-p1", type=int, default=5, help="refinement levels for P1")
    parser.add_argument("--levels-p2", type=int, default=4, help="refinement levels for P2")
    parser.add_argument("--from-csv", action="store_true",
                        help="only rewrite the table and the plot from convergence.csv")
    args = parser.parse_args()
    if args.from_csv:
        rows = read_rows(OUT / "convergence.csv")
        write_markdown(rows, OUT / "convergence.md", "python scripts/mechanics_convergence.py")
        plot(rows, OUT / "convergence.png")
        return
    comm = MPI.COMM_WORLD
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in SCENES:
        for formulation, theta in VARIANTS:
            for degree, levels in ((1, args.levels_p1), (2, args.levels_p2)):
                run_case(name, formulation, theta, degree, 0)  # compile the forms first
                for level in range(levels):
                    row = run_case(name, formulation, theta, degree, level)
                    rows.append(row)
                    if comm.rank == 0:
                        print(f"{name} {label(formulation, theta)} P{degree} m={level}: "
                              f"L2 {row['l2']:.3e} it {row['newton_iterations']} "
                              f"{row['time_total']:.2f} s", flush=True)
    if comm.rank == 0:
        with open(OUT / "convergence.csv", "w", newline="") as fh:
            w = csv.DictWriter(fh, FIELDS)
            w.writeheader()
            for r in rows:
                w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
        # the options the rows were made with (fewer levels: a partial table)
        command = " ".join(["python scripts/mechanics_convergence.py",
                            *map(shlex.quote, sys.argv[1:])])
        write_markdown(rows, OUT / "convergence.md", command)
        plot(rows, OUT / "convergence.png")


if __name__ == "__main__":
    main()
