"""Contact towards incompressibility: every formulation at Poisson's ratios up to 0.49999.

The friction bound of pointwise ``nitsche``, ``F [σ_n(u) - β_n [[u]]_n]_-``, takes the normal
stress at each point, in which ``λ div u`` weighs ``λ/μ = 2ν/(1 - 2ν)`` times the shear terms
(49 at ν = 0.49, 4,999 at 0.4999). The study runs every variant of
``scripts/mechanics_robustness.py`` (mixed, stabilized mixed, mean-Nitsche, Nitsche θ = -1, 0,
+1) on:

* the inclined crack with slip (``configs/inclined_crack_slip.yaml``, exact jump), P1 and P2:
  Newton iterations and the relative L² error of the jump (P1 locks volumetrically);
* the six-fracture mechanics scene (``configs/six_fractures_mechanics.yaml``, P2, Coulomb
  F = 0.5, five load steps, step cuts as configured);
* the seven-fracture 3D network (``configs/network3d.yaml``, P2, Coulomb F = 0.5, four load
  steps) on a coarse mesh (``mesh.size = 0.5``, ``mesh.fracture_size = 0.2``: 2,891 cells), the
  linear solver as ``solver.linear_solver: auto`` picks it (MUMPS at this size), no step cuts
  (a failed step is the run's failure).

Cells: total Newton iterations (per load step in brackets for the multi-step scenes) / relative
L² error of the jump where it is known; ✗ = not converged, with PETSc's reason.

Run (about 25 minutes on one core)::

    python scripts/mechanics_incompressible.py   # -> docs/mechanics/incompressible.{csv,md}
"""

from __future__ import annotations

import argparse
import datetime

import dolfinx_solver  # noqa: F401

from mechanics_robustness import OUT, VARIANTS, Case, cell, label, run, write_csv
from mpi4py import MPI

POISSON = (0.25, 0.49, 0.499, 0.4995, 0.4999, 0.49999)
NETWORK3D = ["mesh.size=0.5", "mesh.fracture_size=0.2", "time.max_cuts=0"]


def cases(poisson: tuple[float, ...]) -> list[tuple[str, Case, tuple[int, ...]]]:
    """(scene label, case, degrees) for every Poisson's ratio."""
    out = []
    for nu in poisson:
        out.append(("inclined crack", Case(f"{nu:g}", "inclined_crack_slip",
                                           [f"parameters.nu={nu}"]), (1, 2)))
        out.append(("six fractures", Case(f"{nu:g}", "six_fractures_mechanics",
                                          [f"material.poisson={nu}"], exact=False), (2,)))
        out.append(("network3d", Case(f"{nu:g}", "network3d",
                                      NETWORK3D + [f"material.poisson={nu}"], exact=False), (2,)))
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--poisson", type=float, nargs="+", default=POISSON)
    parser.add_argument("--scenes", nargs="+", default=["inclined crack", "six fractures",
                                                        "network3d"])
    args = parser.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for scene, case, degrees in cases(tuple(args.poisson)):
        if scene not in args.scenes:
            continue
        for degree in degrees:
            for formulation, theta in VARIANTS:
                r = run(case, formulation, theta, degree)
                r.update(scene=scene, poisson=float(case.name))
                rows.append(r)
                if comm.rank == 0:
                    print(f"{scene:15s} ν={case.name:8s} P{degree} "
                          f"{label(formulation, theta):18s} {entry(r)} {r['time']:.1f} s",
                          flush=True)
    if comm.rank == 0:
        write(rows)


def entry(r: dict) -> str:
    """A table cell: :func:`cell` with the iterations per step of a multi-step run."""
    steps = r.get("per_step", [])
    if r["converged"] and len(steps) > 1:  # the multi-step scenes have no exact jump
        return f"{cell(r)} ({'/'.join(map(str, steps))})"
    return cell(r)


def write(rows: list[dict]) -> None:
    """``incompressible.csv`` and ``incompressible.md``."""
    OUT.mkdir(parents=True, exist_ok=True)
    keys = ["scene", "poisson", "formulation", "theta", "degree", "converged", "reason",
            "iterations", "per_step", "face_iterations", "l2", "time"]
    write_csv(OUT / "incompressible.csv", [{"per_step": [], **r} for r in rows], keys)
    heads = [label(*v) for v in VARIANTS]
    lines = ["# Contact towards incompressibility", "",
             f"Generated {datetime.date.today()} by `python scripts/mechanics_incompressible.py`"
             " (1 MPI rank). Cell: total Newton iterations (per load step in brackets) / "
             "relative L² error of the jump against the exact solution (inclined crack); "
             "`+Nf`: face Newton iterations of the condensed `mixed` solve; ✗ = not converged, "
             "with PETSc's reason. λ/μ = 2ν/(1 − 2ν). The 3D network runs without step cuts "
             "(`time.max_cuts = 0`); the six-fracture scene cuts a failed step up to four "
             "times.", ""]
    for scene in dict.fromkeys(r["scene"] for r in rows):
        for degree in sorted({r["degree"] for r in rows if r["scene"] == scene}):
            lines += [f"## {scene}, P{degree}", "",
                      "| ν | λ/μ | " + " | ".join(heads) + " |", "|---" * (len(heads) + 2) + "|"]
            sel = [r for r in rows if r["scene"] == scene and r["degree"] == degree]
            for nu in dict.fromkeys(r["poisson"] for r in sel):
                cells = [entry(next(r for r in sel if r["poisson"] == nu
                                    and (r["formulation"], r["theta"]) == v)) for v in VARIANTS]
                lines.append(f"| {nu:g} | {2 * nu / (1 - 2 * nu):,.0f} | "
                             + " | ".join(cells) + " |")
            lines.append("")
    (OUT / "incompressible.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
