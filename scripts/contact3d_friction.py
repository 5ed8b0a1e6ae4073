"""High Coulomb friction on the seven-fracture network: where Newton stops and what it says.

Scene: ``configs/network3d.yaml`` (compression, then shear in three steps) with P1
displacements on its own mesh, for friction coefficients F from 0.5 (the scene's) to 10 and the
formulations ``nitsche`` (θ = -1), ``mean_nitsche`` and ``stabilized_mixed``; and, for contrast,
``configs/six_fractures_mechanics.yaml`` in 2D (P2, ``nitsche``) with the same coefficients.
A failed step is not cut (``time.max_cuts`` 0; with the default four cuts, down to 1/16 of the
step, ``nitsche`` failed alike at F = 2 and 10).

Above F = 1 a quasi-static Coulomb problem is not known to have a solution, nor a unique one
(Klarbring 1990 gives small spring examples with several solutions, and with none): a Newton
that fails there may have nothing to converge to, or may miss a solution that exists. A
failure message names the fractures on which contact points switched state twice or more in
the last ``poromech.mechanics.newton.RECENT_ITERATIONS`` iterations (the Newton cycles between
branches there); ``cycling`` quotes it.

``friction.csv`` has a row per case: ``dim``, ``formulation``, ``friction``, ``newton`` the
Newton iterations of each step (``✗`` after the failed step's), ``converged``, ``failed_at`` the
time of the failed step, ``cycling`` the fractures and face counts of the message,
``seconds`` the run's wall time.

Run (about 7 minutes on one core)::

    python scripts/contact3d_friction.py        # -> docs/mechanics3d/friction.{csv,md}
"""

from __future__ import annotations

import argparse
import re
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

from report_common import generated, write_report

from poromech.errors import SolverError
from poromech.mechanics.physics import MechanicsPhysics
from poromech.run import Run
from poromech.scene.loading import load_scene

ROOT = Path(__file__).resolve().parents[1]
NETWORK = ROOT / "configs" / "network3d.yaml"
SCENE_2D = ROOT / "configs" / "six_fractures_mechanics.yaml"
OUT = ROOT / "docs" / "mechanics3d"
SCRIPT = "contact3d_friction.py"
FORMULATIONS = ("nitsche", "mean_nitsche", "stabilized_mixed")
FRICTIONS = (0.5, 1.0, 1.5, 2.0, 3.0, 10.0)
FIELDS = ("dim", "formulation", "friction", "newton", "converged", "failed_at", "cycling",
          "seconds")
CYCLING = re.compile(r"contact states cycle \(.*?\) on \d+ faces?: ([^;]+)")


def run_case(dim: int, formulation: str, friction: float) -> dict:
    """One run; the Newton iterations of every step and, on failure, what the message says."""
    path, sets = (NETWORK, ["degree=1"]) if dim == 3 else (SCENE_2D, [])
    scene = load_scene(path, sets + [f"contact.formulation={formulation}",
                                     f"contact.friction_coefficient={friction!r}",
                                     "time.max_cuts=0", "output.xdmf=false"])
    newton: list[str] = []
    accept = MechanicsPhysics.accept

    def record(physics, t):
        newton.append(str(physics.solver.record.iterations))
        accept(physics, t)

    MechanicsPhysics.accept = record
    failed_at, cycling = "", ""
    t0 = time.perf_counter()
    try:
        with Run(scene) as run:
            try:
                run.execute()
            except SolverError as err:
                newton.append(f"{run.physics.solver.record.iterations} ✗")
                failed_at = re.search(r"at t = (\S+) s", str(err)).group(1)
                found = CYCLING.search(str(err))
                cycling = found.group(1) if found else ""
    finally:
        MechanicsPhysics.accept = accept
    return {"dim": dim, "formulation": formulation, "friction": friction,
            "newton": "/".join(newton), "converged": not failed_at, "failed_at": failed_at,
            "cycling": cycling, "seconds": round(time.perf_counter() - t0, 1)}


def table(rows: list[dict]) -> str:
    """The Markdown page."""
    lines = [
        "# High Coulomb friction: where Newton stops", "",
        f"{generated(SCRIPT)}. See the docstring of "
        "`scripts/contact3d_friction.py` for the scenes and the columns. No step cuts; "
        "✗: the step's Newton failed (100 iterations, or the line search gave up).", "",
        "| scene | formulation | F | Newton per step | failed at t | faces whose states cycle "
        "(the message) | s |",
        "|---|---|---|---|---|---|---|"]
    for r in rows:
        scene = "network3d.yaml, P1" if r["dim"] == 3 else "six_fractures_mechanics.yaml (2D), P2"
        lines.append(f"| {scene} | `{r['formulation']}` | {r['friction']:g} | {r['newton']} | "
                     f"{r['failed_at'] or '-'} | {r['cycling'] or '-'} | {r['seconds']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    cases = [(3, f, mu) for f in FORMULATIONS for mu in FRICTIONS]
    cases += [(2, "nitsche", mu) for mu in FRICTIONS]
    rows = []
    for case in cases:
        rows.append(run_case(*case))
        print(rows[-1], flush=True)
    write_report(args.out, "friction", SCRIPT, FIELDS, rows, table(rows))


if __name__ == "__main__":
    main()
