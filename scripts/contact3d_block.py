"""A block held on a fault by friction alone: equilibrium and Newton iterations towards the limit.

Scene: ``configs/sliding_block3d.yaml`` — a 1 m box cut through by a plane fault of slope
s = 0.2, the lower block fixed, the upper one held by nothing but Coulomb friction (F = 0.6)
under a top traction (a, 0, -σ), σ = 1 MPa. The resultant on the fault leaves the friction cone
at a* = σ (F + s)/(1 - F s) = 9.09e5 Pa: below a* the fault holds the block (partly sticking,
partly slipping), beyond it no equilibrium exists, for the continuous problem and for every
formulation alike (the projection bounds each contact point's or face's traction by the cone,
and the written tractions are the ones the residual integrates).

Each case loads the block in one step from rest to ``a = load · a*`` (no step cuts) with one
formulation and degree. ``block.csv`` has a row per case: ``newton`` the Newton iterations,
``converged``, ``balance`` the largest component of the sum of the written face tractions times
the face areas minus the applied load (a, 0, -σ), over σ (the face tractions carry the whole
load: rounding), ``stick``, ``slip``, ``open`` the fractions of the faces in each state,
``seconds`` the solve's wall time. Beyond a* (``load`` 1.05) every case must fail. Rows with
a ``line_search`` other than ``contact`` (``solver.line_search``) repeat ``nitsche`` P2 at
0.8 a* with PETSc's searches and with full steps (``basic``). Rows with ``dim`` 2 load the same
block in 2D (the (x, z) section, plane strain: a fault of the same slope across a 1 m square,
the mesh sizes halved) with P2 at 0.8 a*: the limit is the same.

Run (about 7 minutes on one core)::

    python scripts/contact3d_block.py        # -> docs/mechanics3d/block.{csv,md}
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from report_common import generated, write_report

from poromech.errors import SolverError
from poromech.mechanics.physics import MechanicsPhysics
from poromech.run import Run
from poromech.scene.loading import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "sliding_block3d.yaml"
OUT = ROOT / "docs" / "mechanics3d"
SCRIPT = "contact3d_block.py"
FORMULATIONS = ("nitsche", "mean_nitsche", "stabilized_mixed", "mixed")
SIGMA, SLOPE, FRICTION = 1.0e6, 0.2, 0.6
LIMIT = SIGMA * (FRICTION + SLOPE) / (1.0 - FRICTION * SLOPE)
LOADS = (0.5, 0.8, 0.95, 1.05)
#: The searches compared on ``nitsche`` P2 at 0.8 a* (the first is the default).
LINE_SEARCHES = ("contact", "basic", "bt", "l2")
FIELDS = ("dim", "formulation", "degree", "load", "line_search", "a", "newton", "converged",
          "balance", "stick", "slip", "open", "seconds")


#: The block in 2D: the (x, z) section of the 3D scene, a fault of the same slope.
SCENE_2D = """name: sliding_block2d
description: the section of configs/sliding_block3d.yaml
parameters: {sigma: 1.0e6, a: 1.0e6}
geometry:
  domain: {rectangle: [0.0, 0.0, 1.0, 1.0]}
  fractures:
    - {name: fault, points: [[0.0, 0.4], [1.0, 0.6]]}
mesh: {size: 0.125, fracture_size: 0.06}
degree: 2
material: {young: 1.0e10, poisson: 0.25}
contact: {formulation: nitsche, friction: coulomb, friction_coefficient: 0.6}
boundary_conditions:
  - {boundary: bottom, displacement: [0.0, 0.0]}
  - {boundary: top, traction: ["a * t", "-sigma"]}
"""


def run_case(formulation: str, degree: int, load: float, line_search: str = "contact",
             dim: int = 3) -> dict:
    """One load step from rest to ``load · a*``; the written face values before acceptance."""
    a = load * LIMIT
    path = SCENE
    if dim == 2:
        path = Path(tempfile.mkdtemp()) / "sliding_block2d.yaml"
        path.write_text(SCENE_2D)
    applied = [a, 0.0, -SIGMA] if dim == 3 else [a, -SIGMA]
    scene = load_scene(path, [f"parameters.a={a!r}", f"contact.formulation={formulation}",
                               f"degree={degree}", "time.final=1.0", "time.steps=1",
                               "time.max_cuts=0", "output.xdmf=false",
                               f"solver.line_search={line_search}"])
    seen: dict = {}
    accept = MechanicsPhysics.accept

    def record(physics, t):
        v, faces = physics.model.face_fields(), physics.fm.fractures
        if dim == 3:
            tangential = np.column_stack([v[f"traction_t{c}"] for c in "xyz"])
        else:  # 2D: along τ = (n_y, -n_x)
            tangential = v["traction_t"][:, None] * faces.tangents[:, 0, :]
        traction = v["traction_n"][:, None] * faces.normal + tangential
        force = (traction * faces.measure[:, None]).sum(axis=0)
        seen["balance"] = float(np.max(np.abs(force - applied)) / SIGMA)
        states = physics.model.states(v)
        for code, name in enumerate(("open", "stick", "slip")):
            seen[name] = float(np.mean(states == code))
        accept(physics, t)

    MechanicsPhysics.accept = record
    t0 = time.perf_counter()
    try:
        with Run(scene) as run:
            try:
                run.execute()
                converged = True
            except SolverError:
                converged = False
            rec = run.physics.solver.record
    finally:
        MechanicsPhysics.accept = accept
    return {"dim": dim, "formulation": formulation, "degree": degree, "load": load,
            "line_search": line_search, "a": a,
            "newton": rec.iterations, "converged": converged,
            "balance": seen.get("balance", float("nan")), "stick": seen.get("stick", ""),
            "slip": seen.get("slip", ""), "open": seen.get("open", ""),
            "seconds": round(time.perf_counter() - t0, 2)}


def table(rows: list[dict]) -> str:
    """Markdown: Newton iterations per load fraction and the largest balance error per case."""
    lines = [
        "# A block held on a fault by friction alone",
        "",
        f"{generated(SCRIPT)}. "
        "See the docstring of `scripts/contact3d_block.py` for the scene and the columns. "
        f"One load step from rest to a = load · a*, a* = {LIMIT:.4g} Pa (the limit of the "
        "friction cone); MUMPS LU; ✗: not converged (100 Newton iterations, or the line search "
        "gave up).",
        "",
        "| formulation | degree | " + " | ".join(f"Newton, load {x}" for x in LOADS)
        + " | largest balance error / σ |",
        "|---|---|" + "---|" * len(LOADS) + "---|",
    ]
    for f in FORMULATIONS:
        for k in (1, 2):
            case = [r for r in rows if r["formulation"] == f and r["degree"] == k
                    and r["line_search"] == "contact" and r["dim"] == 3]
            if not case:
                continue
            cells = [f"{r['newton']}{'' if r['converged'] else ' ✗'}" for r in case]
            balance = max((r["balance"] for r in case if r["converged"]), default=float("nan"))
            lines.append(f"| `{f}` | {k} | " + " | ".join(cells) + f" | {balance:.1e} |")
    searches = [r for r in rows if r["line_search"] != "contact" and r["dim"] == 3]
    if searches:
        lines += ["", "`nitsche` P2 at 0.8 a* with other line searches (`solver.line_search`; "
                  "`basic`: full steps):", "", "| line search | Newton | s |", "|---|---|---|"]
        default = [r for r in rows if r["formulation"] == "nitsche" and r["degree"] == 2
                   and r["load"] == 0.8 and r["line_search"] == "contact" and r["dim"] == 3]
        for r in default + searches:
            lines.append(f"| `{r['line_search']}` | {r['newton']}"
                         f"{'' if r['converged'] else ' ✗'} | {r['seconds']} |")
    flat = [r for r in rows if r["dim"] == 2]
    if flat:
        lines += ["", "The same block in 2D (plane strain), P2 at 0.8 a*:", "",
                  "| formulation | Newton | largest balance error / σ |", "|---|---|---|"]
        for r in flat:
            lines.append(f"| `{r['formulation']}` | {r['newton']}"
                         f"{'' if r['converged'] else ' ✗'} | {r['balance']:.1e} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT)
    parser.add_argument("--formulations", nargs="+", default=list(FORMULATIONS))
    parser.add_argument("--degrees", nargs="+", type=int, default=[1, 2])
    args = parser.parse_args()
    cases = [(f, k, load, "contact") for f in args.formulations for k in args.degrees
             for load in LOADS]
    if "nitsche" in args.formulations and 2 in args.degrees:
        cases += [("nitsche", 2, 0.8, search) for search in LINE_SEARCHES[1:]]
        cases += [(f, 2, 0.8, "contact", 2) for f in FORMULATIONS]
    rows = []
    for case in cases:
        rows.append(run_case(*case))
        print({key: rows[-1][key] for key in ("dim", "formulation", "degree", "load", "line_search",
                                              "newton", "converged", "balance", "seconds")},
              flush=True)
    write_report(args.out, "block", SCRIPT, FIELDS, rows, table(rows))


if __name__ == "__main__":
    main()
