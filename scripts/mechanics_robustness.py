"""Robustness of every contact formulation on stiff and extreme cases.

For each case and each variant (mixed, stabilized mixed, mean-Nitsche, Nitsche θ = -1, 0, 1;
P1 and P2) the script records whether the semi-smooth Newton converged, its iterations, and the
relative L² error of the jump where an exact solution exists. Cases: β⁰ over seven decades
relative to E, friction F ∈ {0, 0.1, 1, 10}, ν = 0.49 and 0.499, E from 1 kPa to 100 GPa in one
scene, fractures one and two faces long, a network with a corner, a T, an X and a fracture on the
boundary, a fully open and a fully closed crack. A second table compares poromech's ``contact``
line search with PETSc's ``basic`` and ``bt`` on the hardest cases.

Run (about 10 minutes on 2 cores)::

    python scripts/mechanics_robustness.py

Writes ``docs/mechanics/robustness.csv`` and ``docs/mechanics/robustness.md``.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from mpi4py import MPI

from poromech.errors import SolverError
from poromech.run import Run, build_mesh
from poromech.scene.loading import load_scene, scene_from_dict
from poromech.verification.jumps import exact_jump, jump_errors

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics"
VARIANTS = [("mixed", -1), ("stabilized_mixed", -1), ("mean_nitsche", -1), ("nitsche", -1),
            ("nitsche", 0), ("nitsche", 1)]
E = 1.0e10  # Young's modulus of the verification scenes


@dataclass
class Case:
    """A scene with overrides; ``exact`` when the scene has an analytic jump."""

    name: str
    source: str | dict
    overrides: list[str] = field(default_factory=list)
    exact: bool = True
    note: str = ""


def network(young="1e9") -> dict:
    """Corner, T, X and a fracture ending on the boundary, under compression and shear."""
    return {
        "name": "network",
        "geometry": {"domain": {"rectangle": [0, 0, 2, 1]}, "fractures": [
            {"points": [[0.2, 0.8], [0.5, 0.88], [0.8, 0.8]]},
            {"points": [[0.2, 0.5], [0.8, 0.5]]}, {"points": [[0.5, 0.2], [0.5, 0.5]]},
            {"points": [[1.2, 0.2], [1.6, 0.6]]}, {"points": [[1.2, 0.6], [1.6, 0.2]]},
            {"points": [[1.7, 0.8], [2.0, 0.8]]}]},
        "mesh": {"size": 0.08, "fracture_size": 0.04},
        "material": {"young": young, "poisson": 0.25},
        "contact": {"beta_n": 1e11, "beta_t": 1e11, "friction_coefficient": 0.3},
        "boundary_conditions": [{"boundary": "bottom", "displacement": [0, 0]},
                                {"boundary": "top", "displacement": [0.002, -0.001]}],
    }


def short_fracture(faces: int) -> dict:
    """A fracture exactly ``faces`` mesh faces long in a compressed and sheared box."""
    h = 0.05
    scene = network()
    scene["name"] = f"short{faces}"
    scene["geometry"]["fractures"] = [{"points": [[1.0 - faces * h / 2, 0.45],
                                                  [1.0 + faces * h / 2, 0.55]]}]
    length = math.hypot(faces * h, 0.1)
    scene["mesh"] = {"size": 0.1, "fracture_size": length / faces * 1.01}
    return scene


def cases() -> list[Case]:
    """The case list of the study."""
    out = []
    for ratio in (1e-1, 1, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6):
        b = ratio * E
        out.append(Case(f"β⁰ = {ratio:g} E", "inclined_crack_slip",
                        [f"contact.beta_n={b}", f"contact.beta_t={b}",
                         f"contact.beta_sm_n={b}", f"contact.beta_sm_t={b}"],
                        note="θ=+1 is not coercive" if ratio <= 1 else ""))
    for F in (0.0, 0.1, 1.0, 10.0):
        ov = [f"parameters.F={F}", f"contact.friction_coefficient={F}"]
        if F == 0:
            ov.append("contact.friction=frictionless")
        out.append(Case(f"F = {F:g}", "inclined_crack_slip", ov,
                        note="sticks (cos ψ < F sin ψ)" if F == 10 else ""))
    for nu in (0.49, 0.499):
        out.append(Case(f"ν = {nu}", "inclined_crack_slip", [f"parameters.nu={nu}"]))
    out.append(Case("E = 1 kPa / 100 GPa", "six_fractures_mechanics",
                    ["material.young=where(x < 1, 1e3, 1e11)", "time.steps=1"], exact=False,
                    note="θ=+1 needs β⁰ ≫ E_max"))
    out.append(Case("fracture 1 face long", short_fracture(1), exact=False))
    out.append(Case("fracture 2 faces long", short_fracture(2), exact=False))
    out.append(Case("corner, T, X, boundary", network(), exact=False))
    xjunction = network()
    xjunction["geometry"]["fractures"] = xjunction["geometry"]["fractures"][3:5]
    out.append(Case("X at critical friction", xjunction, ["contact.friction_coefficient=0.2"],
                    exact=False, note="|τ| ≈ F|σ_n| on both fractures: degenerate"))
    out.append(Case("six fractures, 5 steps", "six_fractures_mechanics", exact=False))
    out.append(Case("fully open (Sneddon)", "sneddon"))
    out.append(Case("fully closed (stick)", "inclined_crack_stick"))
    return out


def load(case: Case, extra: list[str]):
    """The scene of a case with extra overrides."""
    if isinstance(case.source, str):
        return load_scene(ROOT / "configs" / f"{case.source}.yaml", case.overrides + extra)
    from poromech.scene.loading import apply_overrides

    return scene_from_dict(apply_overrides(case.source, case.overrides + extra))


def run(case: Case, formulation: str, theta: int, degree: int, line_search="contact",
        condensation: bool = True) -> dict:
    """One solve: converged?, iterations, error, time (collective)."""
    comm = MPI.COMM_WORLD
    scene = load(case, [f"contact.formulation={formulation}", f"contact.theta={theta}",
                        f"degree={degree}", f"solver.line_search={line_search}",
                        f"solver.condensation={str(condensation).lower()}"])
    fm = build_mesh(scene, comm)
    row = {"case": case.name, "formulation": formulation, "theta": theta, "degree": degree,
           "line_search": line_search, "converged": True, "reason": "", "iterations": 0,
           "face_iterations": 0, "l2": float("nan"), "nan": False}
    t0 = time.perf_counter()
    with Run(scene, mesh=fm) as run:
        try:
            run.execute()
        except SolverError as err:
            row["converged"] = False
            row["reason"] = err.reason
        except Exception as err:  # a linear solver error is a failure of the case, not the study
            row["converged"] = False
            row["reason"] = f"{type(err).__name__}: {str(err).splitlines()[0][:60]}"
        row["time"] = time.perf_counter() - t0
        records = run.records
        row["per_step"] = [r["iterations"] for r in records]
        row["iterations"] = sum(row["per_step"])
        row["face_iterations"] = sum(r.get("face_iterations", 0) for r in records)
        row["reason"] = row["reason"] or (records[-1]["reason"] if records else "")
        if run.physics is None:  # failed while setting up
            row["converged"] = False
            return row
        u = run.physics.model.u
    row["nan"] = bool(comm.allreduce(not np.all(np.isfinite(u.x.array)), op=MPI.LOR))
    if case.exact and row["converged"]:
        err = jump_errors(u, fm, exact_jump(scene))
        row["l2"] = err["l2"] if err["norm"] > 1e-12 else err["max"]
    return row


def cell(r: dict) -> str:
    """Table cell: iterations and error, or the failure reason."""
    if not r["converged"]:
        return f"✗ {r['reason'].replace('DIVERGED_', '').lower()}"
    err = "" if math.isnan(r["l2"]) else f" / {r['l2']:.1e}"
    face = f"+{r['face_iterations']}f" if r["face_iterations"] else ""
    return f"{r['iterations']}{face}{err}"


def label(formulation: str, theta: int) -> str:
    """Column label of a variant."""
    return f"nitsche θ={theta:+d}" if formulation == "nitsche" else formulation.replace("_", "-")


def main(argv: list[str] | None = None) -> None:
    # no options: --help says what the script runs and writes, and runs nothing
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    comm = MPI.COMM_WORLD
    OUT.mkdir(parents=True, exist_ok=True)
    rows = []
    for case in cases():
        for degree in (1, 2):
            for formulation, theta in VARIANTS:
                r = run(case, formulation, theta, degree)
                rows.append(r)
                if comm.rank == 0:
                    print(f"{case.name:26s} P{degree} {label(formulation, theta):18s} {cell(r)}",
                          flush=True)
    ls_cases = [c for c in cases() if c.name in (
        "six fractures, 5 steps", "E = 1 kPa / 100 GPa", "corner, T, X, boundary",
        "X at critical friction", "ν = 0.499")]
    ls_rows = []
    for case in ls_cases:
        for formulation, theta in VARIANTS:
            for ls in ("contact", "basic", "bt"):
                # the regular Newton's line search (the condensed mixed solve has its own)
                r = run(case, formulation, theta, 2, ls, condensation=False)
                ls_rows.append(r)
                if comm.rank == 0:
                    print(f"LS {ls:8s} {case.name:26s} {label(formulation, theta):18s} {cell(r)}",
                          flush=True)
    if comm.rank != 0:
        return
    keys = ["case", "formulation", "theta", "degree", "line_search", "converged", "reason",
            "iterations", "face_iterations", "l2", "nan", "time"]
    write_csv(OUT / "robustness.csv", rows + ls_rows, keys)
    write_markdown(rows, ls_rows)


def write_csv(path: Path, rows: list[dict], keys: list[str]) -> None:
    """The ``keys`` of each row: floats to 4 significant digits, lists joined by ``/``."""
    def text(v):
        if isinstance(v, float):
            return f"{v:.4g}"
        return "/".join(map(str, v)) if isinstance(v, list) else v

    with open(path, "w", newline="") as fh:
        w = csv.DictWriter(fh, keys)
        w.writeheader()
        for r in rows:
            w.writerow({k: text(r[k]) for k in keys})


def write_markdown(rows: list[dict], ls_rows: list[dict]) -> None:
    """The two tables, with notes."""
    heads = [label(*v) for v in VARIANTS]
    lines = ["# Robustness on stiff and extreme cases", "",
             f"Generated {datetime.date.today()} by `python scripts/mechanics_robustness.py`. "
             "Cell: total Newton iterations / relative L² error of the jump against the exact "
             "solution (absolute max error in m for the stuck crack, whose exact jump is 0); "
             "`+Nf`: iterations of the face Newton of the condensed `mixed` solve (P2, "
             "`solver.condensation`), whose result the regular Newton then checks; "
             "✗ = not converged, with PETSc's reason. E = 10 GPa in the verification scenes; "
             "level-0 meshes. No run produced a NaN without reporting it: "
             f"{sum(r['nan'] and r['converged'] for r in rows + ls_rows)} converged runs "
             "contain non-finite values.", ""]
    notes = {c.name: c.note for c in cases() if c.note}
    for degree in (1, 2):
        lines += [f"## P{degree}", "", "| case | " + " | ".join(heads) + " |",
                  "|---" * (len(heads) + 1) + "|"]
        for case in dict.fromkeys(r["case"] for r in rows):
            cells = [cell(next(r for r in rows if r["case"] == case and r["degree"] == degree
                               and (r["formulation"], r["theta"]) == v)) for v in VARIANTS]
            note = f" ({notes[case]})" if case in notes else ""
            lines.append(f"| {case}{note} | " + " | ".join(cells) + " |")
        lines.append("")
    lines += ["## Line searches (P2)", "",
              "Total Newton iterations (✗ = failure) with poromech's `contact` line search and "
              "PETSc's `basic` (full steps) and `bt` (backtracking) on the cases where they "
              "differ (on all other cases of the tables above the three agree); the regular "
              "Newton for `mixed` too (`solver.condensation: false`).", "",
              "| case | variant | contact | basic | bt |", "|---|---|---|---|---|"]
    for case in dict.fromkeys(r["case"] for r in ls_rows):
        for v in VARIANTS:
            cells = [cell(next(r for r in ls_rows if r["case"] == case and r["line_search"] == ls
                               and (r["formulation"], r["theta"]) == v))
                     for ls in ("contact", "basic", "bt")]
            lines.append(f"| {case} | {label(*v)} | " + " | ".join(cells) + " |")
    (OUT / "robustness.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
