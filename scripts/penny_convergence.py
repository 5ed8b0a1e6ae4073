"""Sneddon's penny crack in 3D: opening error against unknowns and run time, P1 and P2.

Scene: ``configs/penny.yaml`` (a disc of radius a = 1 m under p = 1 MPa in a clamped box of
half-width 5a, E = 10 GPa, ν = 0.25), meshed by gmsh with one size family scaled by ``s``
(``mesh.size = 2 s``, ``mesh.fracture_size = 0.2 s``, ``mesh.tip_size = 0.05 s``) and, for
comparison, the same family without tip grading (``mesh.tip_size = mesh.fracture_size``).
Errors are relative L² errors of the jump over the disc against Sneddon's infinite-body
opening (``poromech.analytic.penny_opening``), split into the disc's interior (r < 0.9a) and
its rim, and the error of the opening at the centre. The clamped box itself makes the crack
stiffer than in an infinite solid (measured as the difference between boxes of half-width 5a
and 10a on the finest P2 mesh: about 0.5 % of the opening at the centre).

Run (about 15 minutes on 2 cores; every case in its own process, forms compiled beforehand)::

    python scripts/penny_convergence.py            # -> docs/mechanics3d/penny.{csv,md,png}
    python scripts/penny_convergence.py --quick    # the two coarsest levels only
    python scripts/penny_convergence.py --accurate # only (re)run the accurate case, keep the rest

Times are wall seconds of the whole run inside the process (mesh, set-up, solve, no output).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import time
from pathlib import Path

import numpy as np
from penny_common import child_case, error_figure, fmt
from report_common import read_csv, write_csv

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics3d"
PENNY = ROOT / "configs" / "penny.yaml"
#: Scale factors of the mesh family (mesh.size = 2 s, ...), coarse to fine, per degree (P1
#: further, to compare at equal cost).
SCALES = {1: (1.4, 1.0, 0.7, 0.5, 0.35, 0.25), 2: (1.4, 1.0, 0.7, 0.5, 0.35)}
FIELDS = ["degree", "grading", "scale", "box", "cells", "fracture_faces", "dofs", "l2",
          "l2_interior", "l2_rim", "centre", "solver", "krylov_iterations", "time_mesh",
          "time_total", "load"]


def overrides(scale: float, graded: bool, degree: int, box: float = 5.0) -> list[str]:
    """The ``--set`` overrides of one case."""
    tip = 0.05 * scale if graded else 0.2 * scale
    return [f"degree={degree}", f"mesh.size={2 * scale:g}", f"mesh.fracture_size={0.2 * scale:g}",
            f"mesh.tip_size={tip:g}", "mesh.transition=3",
            f"geometry.domain.box=[{-box}, {-box}, {-box}, {box}, {box}, {box}]",
            "output.xdmf=false", "output.fractures_csv=false"]


#: A mesh for accuracy rather than for the convergence family: a box of half-width 10a, 0.1 m
#: faces on the crack, 0.01 m at its rim, a slower transition (P2).
ACCURATE = ["degree=2", "mesh.size=2", "mesh.fracture_size=0.1", "mesh.tip_size=0.01",
            "mesh.transition=6", "geometry.domain.box=[-10.0, -10.0, -10.0, 10.0, 10.0, 10.0]",
            "output.xdmf=false", "output.fractures_csv=false"]


def accurate_row() -> dict:
    """The case of :data:`ACCURATE` (grading ``accurate``)."""
    return {"degree": 2, "grading": "accurate", "scale": 0.0, "box": 10.0,
            **child_case(__file__, ACCURATE), "load": os.getloadavg()[0]}


def run_case(sets: list[str]) -> dict:
    """Solve one case in this process; errors and times."""
    import dolfinx_solver  # noqa: F401

    from poromech.run import Run
    from poromech.scene.loading import load_scene
    from poromech.verification.jumps import exact_jump, face_quadrature, jump_values

    t0 = time.perf_counter()
    scene = load_scene(PENNY, sets)
    with Run(scene) as run:
        summary = run.execute()
        fm, u = run.physics.fm, run.physics.model.u
        q = face_quadrature(fm, 6)
        uh, ue = jump_values(u, q), exact_jump(scene)(q.points, q.normal)
    total = time.perf_counter() - t0
    r = np.hypot(q.points[:, 0], q.points[:, 1])
    e2, n2 = np.sum((uh - ue) ** 2, axis=1), np.sum(ue**2, axis=1)
    ref = np.sum(q.weights * n2)

    def part(mask):
        return float(np.sqrt(np.sum(q.weights[mask] * e2[mask]) / ref))

    c = np.argmin(r)
    centre = float((uh[c] @ q.normal[c]) / (ue[c] @ q.normal[c]) - 1.0)
    return {"cells": summary["mesh"]["cells"], "fracture_faces": summary["mesh"]["fracture_faces"],
            "dofs": summary["dofs"], "l2": part(r >= 0), "l2_interior": part(r < 0.9),
            "l2_rim": part(r >= 0.9), "centre": centre,
            "solver": summary["linear_solver"]["kind"],
            "krylov_iterations": summary["linear_solver"]["krylov_iterations"],
            "time_mesh": summary["wall_time"].get("mesh", float("nan")), "time_total": total}


def study(scales: dict[int, tuple], boxes: bool) -> list[dict]:
    rows = []
    for degree in (1, 2):
        # compile the forms of this degree
        child_case(__file__, overrides(scales[degree][0], True, degree))
        for graded in (True, False):
            for s in scales[degree]:
                load = os.getloadavg()[0]
                row = {"degree": degree, "grading": "tip" if graded else "none", "scale": s,
                       "box": 5.0, **child_case(__file__, overrides(s, graded, degree)),
                       "load": load}
                print({k: row[k] for k in ("degree", "grading", "scale", "dofs", "l2",
                                           "time_total")}, flush=True)
                rows.append(row)
    if boxes:
        s = scales[2][-1]
        row = {"degree": 2, "grading": "tip", "scale": s, "box": 10.0,
               **child_case(__file__, overrides(s, True, 2, 10.0)), "load": os.getloadavg()[0]}
        rows.append(row)
        rows.append(accurate_row())
    return rows


def report(rows: list[dict], stamp: str) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    write_csv(OUT / "penny.csv", [stamp], FIELDS, rows)
    main = [r for r in rows if r["box"] == 5.0]
    lines = [f"# Sneddon's penny crack: opening error against unknowns and time\n\n{stamp}. "
             "See the docstring of `scripts/penny_convergence.py` for the scene and the "
             "errors.\n"]
    # observed orders in h ~ dofs^(-1/3)
    lines.append("\n| degree | tip grading | scale | cells | unknowns | L² error | interior r<0.9a "
                 "| rim | centre | run s |\n|---|---|---|---|---|---|---|---|---|---|\n")
    for r in main:
        lines.append("| " + " | ".join(fmt(r[k]) for k in (
            "degree", "grading", "scale", "cells", "dofs", "l2", "l2_interior", "l2_rim",
            "centre", "time_total")) + " |\n")
    lines.append("\nObserved orders of the L² error in h (h ∝ unknowns^(-1/3)) between the last "
                 "two levels:\n\n")
    for d in (1, 2):
        for g in ("tip", "none"):
            seq = [r for r in main if r["degree"] == d and r["grading"] == g]
            if len(seq) >= 2:
                a, b = seq[-2], seq[-1]
                order = np.log(a["l2"] / b["l2"]) / np.log((b["dofs"] / a["dofs"]) ** (1 / 3))
                lines.append(f"* P{d}, grading {g}: {order:.2f} ({a['l2']:.3g} → "
                             f"{b['l2']:.3g})\n")
    box = [r for r in rows if r["box"] == 10.0 and r["grading"] == "tip"]
    if box:
        ref = next(r for r in main if r["degree"] == 2 and r["grading"] == "tip"
                   and r["scale"] == box[0]["scale"])
        lines.append(f"\nBox of half-width 10a instead of 5a (P2, scale {ref['scale']}): L² error "
                     f"{box[0]['l2']:.3g} against {ref['l2']:.3g}, centre {box[0]['centre']:.3g} "
                     f"against {ref['centre']:.3g}.\n")
    for r in rows:
        if r["grading"] == "accurate":
            lines.append(f"\nA mesh for accuracy (P2, box of half-width 10a, 0.1 m faces on the "
                         f"crack, 0.01 m at its rim, `mesh.transition = 6`; `ACCURATE` in the "
                         f"script): {r['dofs']} unknowns, {r['cells']} cells, L² error "
                         f"{r['l2']:.3g}, centre {r['centre']:.3g}, {r['time_total']:.0f} s "
                         f"({r['solver']}, {r['krylov_iterations']} Krylov iterations).\n")
    (OUT / "penny.md").write_text("".join(lines))
    _figure(main)


def _figure(rows: list[dict]) -> None:
    curves = []
    for d, color in ((1, "tab:orange"), (2, "tab:blue")):
        for g, style in (("tip", "o-"), ("none", "s--")):
            seq = [r for r in rows if r["degree"] == d and r["grading"] == g]
            if seq:
                label = f"P{d}, {'tip grading' if g == 'tip' else 'no grading'}"
                curves.append((label, style, color, seq))
    error_figure(curves, "relative L² error of the jump",
                 "Sneddon's penny crack (configs/penny.yaml)", OUT / "penny.png")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="the two coarsest levels only")
    p.add_argument("--case", help=argparse.SUPPRESS)
    p.add_argument("--accurate", action="store_true",
                   help="run only the accurate case; the other rows from penny.csv")
    p.add_argument("--report-only", action="store_true",
                   help="redraw from docs/mechanics3d/penny.csv")
    args = p.parse_args()
    if args.case:
        print(json.dumps(run_case(json.loads(args.case))))
        return
    command = "python scripts/penny_convergence.py" + (" --quick" if args.quick else "")
    stamp = None
    if args.report_only or args.accurate:
        comments, rows = read_csv(OUT / "penny.csv", text=("grading", "solver"))
        if args.accurate:
            rows = [r for r in rows if r["grading"] != "accurate"] + [accurate_row()]
            command = "python scripts/penny_convergence.py, then --accurate"
        else:  # the rows' own provenance: the commands and the day that made them
            stamp = next((c for c in comments if c.startswith("Generated by")), None)
    else:
        scales = {d: v[:2] for d, v in SCALES.items()} if args.quick else SCALES
        rows = study(scales, boxes=not args.quick)
    report(rows, stamp or f"Generated by `{command}` ({datetime.date.today()})")


if __name__ == "__main__":
    main()
