"""A penny crack in frictional contact under remote shear (Segedin): slip error, Newton, time.

Scene: ``configs/penny_shear.yaml`` (a disc of radius a = 1 m in the plane z = 0, remote shear
τ = 1 MPa along (cos 30°, sin 30°, 0) and compression σ = 2 MPa across it, the uniform far field
imposed on a box of half-width 5a, E = 10 GPa, ν = 0.25), meshed with one size family scaled
by ``s`` (``mesh.size = 2 s``, ``mesh.fracture_size = 0.2 s``, ``mesh.tip_size = 0.05 s``, the
family of ``scripts/penny_convergence.py``). The crack is closed and, frictionless, slips
parallel to τ by ``16 (1 - ν²) τ / (π (2 - ν) E) √(a² - r²)`` in an infinite solid
(``poromech.analytic.penny_shear_slip``). Columns:

* ``l2``: relative L² error of the jump vector over the disc (against the exact slip's norm);
  ``l2_n``: of its normal component (the exact opening is 0); ``transverse``: L² norm of the
  computed slip across τ (in the crack plane, perpendicular to τ), relative to the exact slip;
  ``centre``: computed/exact slip at the face point nearest the centre, minus 1.
* ``newton``: Newton iterations; ``krylov``: Krylov iterations summed over them (0 for MUMPS);
  ``time_total``: wall seconds of the whole case in its process (mesh, set-up, solve);
  ``load``: the 1-minute load average when the case started (2 shared cores: wall times are
  upper bounds); ``states``: the active-set codes found at the contact points (1 closed,
  0 open, 3 closed and slipping).

Cases: the four formulations (``nitsche``, ``mean_nitsche``, ``stabilized_mixed`` with θ = -1,
``mixed``), frictionless, P1 and P2 on every level (the scene's ``auto`` linear solver: MUMPS
below 20k unknowns and for ``mixed``, GMRES + GAMG above); ``nitsche``
θ = 0 and θ = 1 on the P2 levels; Coulomb with F = 0.25 (the crack slips under τ - Fσ = 0.5
MPa: half the frictionless slip) with ``nitsche`` θ = -1, P2; the box effect (half-width 10a
instead of 5a) on one P2 mesh.

Run (about 25 minutes on 2 cores; every case in its own process)::

    python scripts/penny_shear.py            # -> docs/mechanics3d/penny_shear.{csv,md,png}
    python scripts/penny_shear.py --quick    # the two coarsest levels only
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
SCENE = ROOT / "configs" / "penny_shear.yaml"
#: Mesh scale factors, coarse to fine, per degree.
SCALES = {1: (1.4, 1.0, 0.7, 0.5), 2: (1.4, 1.0, 0.7, 0.5)}
#: The four formulations (θ = -1 where there is one), each on every level of both degrees.
FORMULATIONS = ("nitsche", "mean_nitsche", "stabilized_mixed", "mixed")
FIELDS = ["case", "formulation", "theta", "friction", "degree", "scale", "box", "cells",
          "fracture_faces", "dofs", "l2", "l2_n", "transverse", "centre", "newton", "krylov",
          "solver", "states", "time_total", "load"]


def overrides(case: dict) -> list[str]:
    """The ``--set`` overrides of one case."""
    s, box = case["scale"], case["box"]
    sets = [f"degree={case['degree']}", f"mesh.size={2 * s:g}", f"mesh.fracture_size={0.2 * s:g}",
            f"mesh.tip_size={0.05 * s:g}", "mesh.transition=3",
            f"geometry.domain.box=[{-box}, {-box}, {-box}, {box}, {box}, {box}]",
            f"contact.formulation={case['formulation']}", f"contact.friction={case['friction']}",
            "output.xdmf=false", "output.fractures_csv=false"]
    if case["formulation"] != "mixed":  # mixed has no θ
        sets.append(f"contact.theta={case['theta']}")
    if case["friction"] == "coulomb":
        sets.append("contact.friction_coefficient=0.25")
    return sets


def run_case(sets: list[str]) -> dict:
    """Solve one case in this process; errors, iterations and time."""
    import dolfinx_solver  # noqa: F401

    from poromech.run import Run
    from poromech.scene.loading import load_scene
    from poromech.verification.jumps import exact_jump, face_quadrature, jump_values

    t0 = time.perf_counter()
    scene = load_scene(SCENE, sets)
    with Run(scene) as run:
        summary = run.execute()
        fm, model = run.physics.fm, run.physics.model
        record = run.physics.solver.record
        codes = np.unique(model.active_set()).tolist()
        q = face_quadrature(fm, 6)
        uh, ue = jump_values(model.u, q), exact_jump(scene)(q.points, q.normal)
    total = time.perf_counter() - t0
    prm = scene.parameters
    shear = np.array([np.cos(prm["phi"]), np.sin(prm["phi"]), 0.0])
    across = np.cross(q.normal, shear)  # in the crack plane, perpendicular to τ
    ref = np.sum(q.weights * np.sum(ue**2, axis=1))

    def rel(v):
        return float(np.sqrt(np.sum(q.weights * v**2) / ref))

    r = np.hypot(q.points[:, 0], q.points[:, 1])
    c = np.argmin(r)
    return {"cells": summary["mesh"]["cells"], "fracture_faces": summary["mesh"]["fracture_faces"],
            "dofs": summary["dofs"], "l2": rel(np.linalg.norm(uh - ue, axis=1)),
            "l2_n": rel(np.einsum("ij,ij->i", uh, q.normal)),
            "transverse": rel(np.einsum("ij,ij->i", uh, across)),
            "centre": float(np.linalg.norm(uh[c]) / np.linalg.norm(ue[c]) - 1.0),
            "newton": record.iterations, "krylov": summary["linear_solver"]["krylov_iterations"],
            "solver": summary["linear_solver"]["kind"], "states": " ".join(map(str, codes)),
            "time_total": total}


def cases(quick: bool) -> list[dict]:
    """Every case of the study, in run order."""
    def cut(levels):
        return levels[:2] if quick else levels

    out = []
    base = {"friction": "frictionless", "theta": -1, "box": 5.0}
    for d in (1, 2):
        for f in FORMULATIONS:
            out += [{**base, "case": f, "formulation": f, "degree": d, "scale": s}
                    for s in cut(SCALES[d])]
    for theta in (0, 1):
        out += [{**base, "case": f"nitsche theta {theta}", "formulation": "nitsche",
                 "theta": theta, "degree": 2, "scale": s} for s in cut(SCALES[2])]
    out += [{**base, "case": "nitsche coulomb", "formulation": "nitsche", "friction": "coulomb",
             "degree": 2, "scale": s} for s in cut(SCALES[2])]
    if not quick:
        out.append({**base, "case": "nitsche box 10a", "formulation": "nitsche", "degree": 2,
                    "scale": 0.7, "box": 10.0})
    return out


def study(quick: bool) -> list[dict]:
    rows = []
    for case in cases(quick):
        load = os.getloadavg()[0]
        try:
            row = {**case, **child_case(__file__, overrides(case)), "load": load}
        except RuntimeError as err:  # a case that fails is a row: no error, its reason
            reason = str(err).strip().splitlines()[-1][:120]
            row = {**case, **dict.fromkeys(("l2", "l2_n", "transverse", "centre",
                                            "time_total"), float("nan")),
                   "newton": -1, "krylov": -1, "solver": "", "states": f"failed: {reason}",
                   "cells": -1, "fracture_faces": -1, "dofs": -1, "load": load}
            print(f"{case['case']} P{case['degree']} s = {case['scale']}: {reason}", flush=True)
            rows.append(row)
            continue
        print({k: row[k] for k in ("case", "degree", "scale", "dofs", "l2", "newton",
                                   "time_total")}, flush=True)
        rows.append(row)
    return rows


def _order(seq: list[dict]) -> str:
    a, b = seq[-2], seq[-1]
    order = np.log(a["l2"] / b["l2"]) / np.log((b["dofs"] / a["dofs"]) ** (1 / 3))
    return f"{order:.2f} ({a['l2']:.3g} → {b['l2']:.3g})"


def report(rows: list[dict], command: str) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    stamp = f"Generated by `{command}` ({datetime.date.today()})"
    write_csv(OUT / "penny_shear.csv", [stamp], FIELDS, rows)
    keys = ("case", "degree", "scale", "box", "dofs", "l2", "l2_n", "transverse", "centre",
            "newton", "krylov", "solver", "time_total")
    lines = [f"# A penny crack in contact under remote shear (Segedin): slip error, Newton, "
             f"time\n\n{stamp}. See the docstring of `scripts/penny_shear.py` for the scene, "
             "the cases and the columns.\n\n| " + " | ".join(keys) + " |\n|"
             + "---|" * len(keys) + "\n"]
    for r in rows:
        lines.append("| " + " | ".join(fmt(r[k]) for k in keys) + " |\n")
    lines.append("\nObserved orders of the L² slip error in h (h ∝ unknowns^(-1/3)) between the "
                 "last two levels (box 5a):\n\n")
    for name in dict.fromkeys(r["case"] for r in rows):
        for d in (1, 2):
            seq = [r for r in rows if r["case"] == name and r["degree"] == d and r["box"] == 5.0
                   and np.isfinite(r["l2"])]
            if len(seq) >= 2:
                lines.append(f"* {name}, P{d}: {_order(seq)}\n")
    box = [r for r in rows if r["box"] == 10.0]
    if box:
        ref = next(r for r in rows if r["case"] == "nitsche" and r["degree"] == 2
                   and r["scale"] == box[0]["scale"] and r["box"] == 5.0)
        lines.append(f"\nBox of half-width 10a instead of 5a (nitsche, P2, scale {ref['scale']}): "
                     f"L² error {box[0]['l2']:.3g} against {ref['l2']:.3g}, centre "
                     f"{box[0]['centre']:.3g} against {ref['centre']:.3g}.\n")
    (OUT / "penny_shear.md").write_text("".join(lines))
    _figure(rows)


def _figure(rows: list[dict]) -> None:
    import matplotlib.pyplot as plt

    names = list(dict.fromkeys(r["case"] for r in rows if r["box"] == 5.0))
    colors = dict(zip(names, plt.rcParams["axes.prop_cycle"].by_key()["color"], strict=False))
    curves = []
    for name in names:
        for d, style in ((1, "s--"), (2, "o-")):
            seq = [r for r in rows if r["case"] == name and r["degree"] == d and r["box"] == 5.0
                   and np.isfinite(r["l2"])]
            if seq:
                curves.append((f"{name}, P{d}", style, colors[name], seq))
    error_figure(curves, "relative L² error of the slip",
                 "Penny crack under remote shear, in contact (configs/penny_shear.yaml)",
                 OUT / "penny_shear.png", dpi=90, legend_size=7)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="the two coarsest levels only")
    p.add_argument("--case", help=argparse.SUPPRESS)
    p.add_argument("--report-only", action="store_true",
                   help="redraw from docs/mechanics3d/penny_shear.csv")
    args = p.parse_args()
    if args.case:
        print(json.dumps(run_case(json.loads(args.case))))
        return
    command = "python scripts/penny_shear.py" + (" --quick" if args.quick else "")
    if args.report_only:
        rows = read_csv(OUT / "penny_shear.csv", text=("states",))[1]
    else:
        rows = study(args.quick)
    report(rows, command)


if __name__ == "__main__":
    main()
