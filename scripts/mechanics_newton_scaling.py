"""Semi-smooth Newton iterations against the mesh: every formulation × degree, 4 mesh levels.

The default mechanics scene (``configs/six_fractures_mechanics.yaml``: six fractures, top
displacement ramped over 5 quasi-static steps) is run through ``poromech.run.run_scene`` at four
mesh levels (a coarse ``mesh.size`` for ~0.7k cells, then ``mesh.refinement`` 0, 1, 2: ~3k, 12k,
47k cells), and the Newton iterations of every step are recorded with the converged reason,
active-set changes, factorizations and wall time.

Run (about 15 minutes on 2 cores for the whole matrix)::

    python scripts/mechanics_newton_scaling.py
    python scripts/mechanics_newton_scaling.py --levels 0.7k 3k --formulations nitsche --degrees 2
    python scripts/mechanics_newton_scaling.py --label "no predictor" --no-predictor --append

``--append`` adds the rows to the existing CSV (another label, e.g. a variant or an earlier
version of poromech run with ``PYTHONPATH``) instead of replacing it; the Markdown table and the
figure are always made from the whole CSV. Writes ``docs/mechanics/newton_scaling.csv``,
``newton_scaling.md`` and ``newton_scaling.png``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import datetime
import shlex
import sys
from pathlib import Path

import dolfinx_solver  # noqa: F401

from mpi4py import MPI

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics"
SCENE = ROOT / "configs" / "six_fractures_mechanics.yaml"
LEVELS = {
    "0.7k": ["mesh.size=0.095", "mesh.fracture_size=0.085"],
    "3k": ["mesh.refinement=0"],
    "12k": ["mesh.refinement=1"],
    "47k": ["mesh.refinement=2"],
}
FORMULATIONS = ["mixed", "stabilized_mixed", "mean_nitsche", "nitsche"]
KEYS = ["label", "level", "cells", "fracture_faces", "formulation", "theta", "degree", "step",
        "time", "iterations", "converged", "reason", "cuts", "active_set_changes",
        "factorizations", "residual_evaluations", "time_linear", "time_assembly"]
TARGET = 12


def quiet_output(scene_path: Path) -> list[str]:
    """Overrides switching off every writer the scene schema has (only summary.json stays)."""
    from poromech.scene.schema import Output

    names = {f.name for f in dataclasses.fields(Output)}
    return [f"output.{k}=false" for k in ("xdmf", "vtx", "fractures_csv", "checkpoint")
            if k in names]


def run_case(level: str, formulation: str, theta: int, degree: int, label: str,
             predictor: bool = True) -> list[dict]:
    """One scene run in memory; one row per step (collective)."""
    from poromech.errors import SolverError
    from poromech.run import Run
    from poromech.scene.loading import load_scene

    comm = MPI.COMM_WORLD
    # the regular Newton: the condensed solve of mixed P2 (solver.condensation) needs none of
    # its iterations, which this study counts
    overrides = LEVELS[level] + [f"contact.formulation={formulation}", f"contact.theta={theta}",
                                 f"degree={degree}", "solver.condensation=false"] \
        + quiet_output(SCENE)
    scene = load_scene(SCENE, overrides)

    def no_predictor(physics) -> None:
        physics.predictor.extrapolate = False

    with Run(scene, comm=comm, prepare=None if predictor else no_predictor) as run:
        try:
            run.execute()
        except SolverError:
            pass  # the summary holds the failed solve too
        summary = run.summary
    rows = []
    for k, rec in enumerate(summary.get("solves", [])):
        rows.append({
            "label": label, "level": level, "cells": summary["mesh"].get("cells", ""),
            "fracture_faces": summary["mesh"].get("fracture_faces", ""),
            "formulation": formulation, "theta": theta, "degree": degree,
            "step": rec.get("step", k + 1), "time": rec.get("time", ""),
            "iterations": rec["iterations"],  # a cut step: of every attempt and sub-step
            "converged": rec["converged"], "reason": rec["reason"],
            "cuts": rec.get("cuts", 0),
            "active_set_changes": " ".join(str(c) for c in rec["active_set_changes"]),
            "factorizations": rec.get("factorizations", ""),
            "residual_evaluations": rec.get("residual_evaluations", ""),
            "time_linear": f"{rec.get('time_linear', float('nan')):.3f}",
            "time_assembly": f"{rec.get('time_assembly', float('nan')):.3f}",
        })
    if not str(summary.get("status", "converged")).startswith("converged"):
        rows.append({**{k: "" for k in KEYS}, "label": label, "level": level,
                     "formulation": formulation, "theta": theta, "degree": degree,
                     "step": len(rows) + 1, "iterations": 0, "converged": False,
                     "reason": str(summary.get("status", ""))[:120]})
    return rows


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    """Comment lines (provenance) and rows of an earlier CSV."""
    if not path.exists():
        return [], []
    lines = path.read_text().splitlines()
    comments = [ln for ln in lines if ln.startswith("#")]
    rows = list(csv.DictReader(ln for ln in lines if not ln.startswith("#")))
    return comments, rows


def variant(r: dict) -> str:
    """Column label of a formulation × degree."""
    f = r["formulation"].replace("_", "-")
    if r["formulation"] == "nitsche" and int(r["theta"]) != -1:
        f += f" θ={int(r['theta']):+d}"
    return f"{f} P{r['degree']}"


def summarize(rows: list[dict]) -> dict:
    """(label, variant, level) → (iterations per step, cells, all converged)."""
    out: dict = {}
    cells = {r["level"]: r["cells"] for r in rows if r["cells"]}
    for r in rows:
        key = (r["label"], variant(r), r["level"])
        its, _, ok = out.get(key, ([], None, True))
        converged = str(r["converged"]) == "True"
        out[key] = (its + ([int(r["iterations"])] if converged else []), cells[r["level"]],
                    ok and converged)
    return out


def cell(rows: list[dict], label: str, v: str, level: str) -> str:
    """Iterations of every step, ``ᶜ`` for a cut step, ✗ for a run that stopped."""
    out = []
    for r in rows:
        if (r["label"], variant(r), r["level"]) != (label, v, level):
            continue
        if str(r["converged"]) != "True":
            out.append("✗")
        else:
            out.append(str(r["iterations"]) + ("ᶜ" if int(r.get("cuts") or 0) else ""))
    return "/".join(out)


def markdown(comments: list[str], rows: list[dict]) -> str:
    """Tables: per label, Newton iterations per step for every variant and level."""
    levels = [lv for lv in LEVELS if any(r["level"] == lv for r in rows)]
    summary = summarize(rows)
    cells = {lv: next(r["cells"] for r in rows if r["level"] == lv and r["cells"])
             for lv in levels}
    lines = ["# Semi-smooth Newton iterations against the mesh", ""]
    lines += [f"Generated by `{c.lstrip('# ').strip()}`." for c in comments] + [""]
    lines += [
        "Default mechanics scene (`configs/six_fractures_mechanics.yaml`: six fractures, top "
        "displacement ramped over 5 steps to T/4). Each cell lists the Newton iterations of the "
        "5 steps; ᶜ marks a step that was cut (retried as halves, ...; its count includes every "
        "attempt), ✗ a step that failed after every cut (the run stops). Levels: "
        + ", ".join(f"{lv} = {cells[lv]} cells" for lv in levels) + ".", ""]
    for label in dict.fromkeys(r["label"] for r in rows):
        variants = list(dict.fromkeys(variant(r) for r in rows if r["label"] == label))
        lines += [f"## {label}", "", "| variant | " + " | ".join(levels) + " | max |",
                  "|---|" + "---|" * (len(levels) + 1)]
        for v in variants:
            worst = max([i for lv in levels for i in summary.get((label, v, lv), ([],))[0]],
                        default=0)
            cols = [cell(rows, label, v, lv) for lv in levels]
            lines.append(f"| {v} | " + " | ".join(cols) + f" | {worst} |")
        lines.append("")
    return "\n".join(lines)


def plot(rows: list[dict], path: Path) -> None:
    """First-step and largest later-step iterations against cells.

    Colour = variant, line style = label; a cross marks a run that did not converge (at the top).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = summarize(rows)
    labels = list(dict.fromkeys(r["label"] for r in rows))
    variants = list(dict.fromkeys(variant(r) for r in rows))
    colors = plt.get_cmap("tab10")
    styles = ["-", "--", ":", "-."]
    top = 50
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2), sharey=True)
    for (label, v) in dict.fromkeys((k[0], k[1]) for k in summary):
        pts = sorted((int(c), its, ok) for (lb, vv, _), (its, c, ok) in summary.items()
                     if lb == label and vv == v and its)
        kw = {"color": colors(variants.index(v) % 10),
              "ls": styles[labels.index(label) % len(styles)]}
        x = [p[0] for p in pts]
        first = [min(p[1][0], top) for p in pts]
        later = [min(max(p[1][1:], default=0), top) for p in pts]
        name = v if len(labels) == 1 else f"{v} ({label})"
        axes[0].plot(x, first, marker="o", ms=3, label=name, **kw)
        axes[1].plot(x, later, marker="o", ms=3, **kw)
        bad = [p[0] for p in pts if not p[2]]
        for ax in axes:
            ax.plot(bad, [top] * len(bad), "x", color=kw["color"], ms=7)
    for ax, title in zip(axes, ("step 1 (from rest)", "steps 2-5 (largest)"), strict=True):
        ax.axhline(TARGET, color="k", lw=0.8, ls="--")
        ax.set_xscale("log")
        ax.set_ylim(0, top + 2)
        ax.set_xlabel("cells")
        ax.set_title(title)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("Newton iterations (x: not converged)")
    axes[0].legend(fontsize=6, ncol=2, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=90)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--levels", nargs="+", default=list(LEVELS), choices=list(LEVELS))
    parser.add_argument("--formulations", nargs="+", default=FORMULATIONS,
                        help="formulations; nitsche:0 and nitsche:1 select θ")
    parser.add_argument("--degrees", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--label", default="poromech", help="label of the rows of this run")
    parser.add_argument("--no-predictor", action="store_true",
                        help="start each step from the accepted state (no extrapolation)")
    parser.add_argument("--append", action="store_true", help="add rows to the existing CSV")
    parser.add_argument("--csv", type=Path, default=OUT / "newton_scaling.csv")
    parser.add_argument("--report-only", action="store_true",
                        help="only remake the Markdown and the figure from the CSV")
    args = parser.parse_args()
    if args.report_only:
        comments, rows = read_csv(args.csv)
        args.csv.with_suffix(".md").write_text(markdown(comments, rows))
        plot(rows, args.csv.with_suffix(".png"))
        return
    comm = MPI.COMM_WORLD
    rows = []
    for level in args.levels:
        for degree in args.degrees:
            for spec in args.formulations:
                formulation, _, theta = spec.partition(":")
                new = run_case(level, formulation, int(theta or -1), degree, args.label,
                               predictor=not args.no_predictor)
                rows += new
                if comm.rank == 0 and new:
                    print(f"{args.label:12s} {level:5s} {variant(new[0]):22s} "
                          + " ".join(r["iterations"].__str__() for r in new), flush=True)
    if comm.rank != 0:
        return
    command = "python scripts/mechanics_newton_scaling.py " + shlex.join(sys.argv[1:])
    stamp = f"# {command.strip()} ({datetime.date.today().isoformat()})"
    comments, old = read_csv(args.csv) if args.append else ([], [])
    comments.append(stamp)
    rows = old + rows
    args.csv.parent.mkdir(parents=True, exist_ok=True)
    with open(args.csv, "w", newline="") as fh:
        fh.write("\n".join(comments) + "\n")
        w = csv.DictWriter(fh, KEYS)
        w.writeheader()
        w.writerows(rows)
    args.csv.with_suffix(".md").write_text(markdown(comments, rows))
    plot(rows, args.csv.with_suffix(".png"))


if __name__ == "__main__":
    main()
