"""Robustness of the coupled solver on stiff and extreme cases, per contact formulation.

    python scripts/poromechanics_robustness.py [--again] [--degree 1]
    python scripts/poromechanics_robustness.py --3d [--again]

Each case is the coupled six-fracture scene (m = 0, P2, Anderson) with a few keys changed, or
the injection scene; every formulation is run through the command line. A cell of the table is
converged / g evaluations / contact Newton iterations (of every attempt, cut ones included), or
the reason of the failure. Every written field of a converged run is checked for non-finite
values. Writes docs/poromechanics/robustness.{csv,md}, or robustness_p1.{csv,md} with
``--degree 1`` (P1 displacements).

``--3d``: the 3D fault scene (configs/fault_reactivation3d.yaml) on its coarse uniform mesh
(``mesh.size = 60``, ``mesh.fracture_size = 22``, no zones; 7k P1 displacement and 36k flow
unknowns, 20 steps), P1, with the three formulations that are stable with P1 in 3D
(``CASES_3D``; ``mixed`` needs P2 there). Writes docs/poromechanics/robustness3d.{csv,md}
(about 20 minutes, most of it in the tight-rock case, which fails).
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from fault_reactivation3d import mesh_overrides  # noqa: E402
from poromechanics_study import (  # noqa: E402
    DOCS,
    FORMULATIONS,
    RUNS,
    SCENE,
    markdown_table,
    run_cli,
    write_csv,
)

INJECTION = ROOT / "configs" / "injection.yaml"
STEPS_2000 = "{times: [" + ", ".join(str(float(k)) for k in range(1, 21)) + "]}"

#: name: (scene, overrides, what it probes)
CASES = {
    "K_m 1e-20": (SCENE, ["flow.permeability=[1.0e-20, 5.0e-21]"],
                  "nearly impervious matrix: undrained, pressure builds up"),
    "… without fallback": (SCENE, ["flow.permeability=[1.0e-20, 5.0e-21]",
                                   "coupling.fallback=none"],
                           "the same without solving a failed step again by NGMRES before "
                           "cutting it"),
    "… never fracture fixed-stress": (SCENE, ["flow.permeability=[1.0e-20, 5.0e-21]",
                                             "coupling.fracture_stabilization=0"],
                                      "the same without β_f, even when the Darcy solve in g is "
                                      "not to be trusted"),
    "… fracture fixed-stress": (SCENE, ["flow.permeability=[1.0e-20, 5.0e-21]",
                                       "coupling.fracture_stabilization=1"],
                                "the same with β_f (p_f - p_in) in the fracture balance of g "
                                "from the start"),
    "K_m 1e-10": (SCENE, ["flow.permeability=[1.0e-10, 5.0e-11]"],
                  "very permeable matrix: pressure stays at p⁰, stiff diffusion"),
    "Δt = T/2000": (SCENE, [f"time={STEPS_2000}"],
                    "first 20 steps of Δt = 1 s: storage-dominated (undrained) steps"),
    "Δt = T": (SCENE, ["time.steps=1"], "one step over the whole loading and drainage"),
    "b = 1, M = ∞": (SCENE, ["material.biot=1", "flow.biot_modulus=null"],
                     "incompressible constituents: no storage but b div u"),
    "b = 1, M = ∞, Δt = 1 s": (SCENE, ["material.biot=1", "flow.biot_modulus=null",
                                        f"time={STEPS_2000}"],
                               "incompressible constituents at small steps"),
    "… without fixed-stress": (SCENE, ["material.biot=1", "flow.biot_modulus=null",
                                       f"time={STEPS_2000}", "coupling.stabilization=0"],
                               "the same with the paper's g (coupling.stabilization = 0)"),
    "injection opens": (INJECTION, [],
                        "a fracture opens completely under injection, then closes"),
    "… with fracture fixed-stress": (INJECTION, ["coupling.fracture_stabilization=1"],
                                 "the same with β_f (p_f - p_in) in the fracture balance of g"),
    "frictionless": (SCENE, ["contact.friction=frictionless"], "zero friction"),
    "E 1 GPa / 100 GPa": (SCENE, ["material.young=where(x < 1.0, 1.0e9, 1.0e11)"],
                      "Young's modulus 1 GPa next to 100 GPa"),
    "K_f contrast 1e8": (SCENE, ["flow.fracture_permeability=where(x < 1.0, 1.0e-2, 1.0e-10)"],
                         "fracture permeability 1e-2 m² left of x = 1, 1e-10 m² right"),
    "… coupling.atol = 1 Pa": (SCENE, ["flow.fracture_permeability=where(x < 1.0, 1.0e-2, 1.0e-10)",
                                       "coupling.atol=1.0"],
                               "the same, stopping at an RMS residual of 1 Pa"),
}


FAULT = ROOT / "configs" / "fault_reactivation3d.yaml"
#: The coarse uniform mesh of scripts/fault_reactivation3d.py and P1.
FAULT_BASE = [*mesh_overrides("coarse"), "degree=1"]
FAULT_STEPS_1S = "{times: [" + ", ".join(str(float(k)) for k in range(1, 21)) + "]}"
FORMULATIONS_3D = ("stabilized_mixed", "mean_nitsche", "nitsche")

#: name: (overrides of the 3D fault scene, what it probes)
CASES_3D = {
    "the scene": ([], "10 mD rock, 10 L/s for 20000 s, F = 0.6 (89 % of the limit at t = 0)"),
    "K_m 1e-18": (["flow.permeability=[1.0e-18]"],
                  "tight rock (1 µD): the injected fluid stays in and next to the fault"),
    "K_m 1e-11": (["flow.permeability=[1.0e-11]"],
                  "very permeable rock (10 D): pressure stays near hydrostatic, stiff diffusion"),
    "Q × 10": (["parameters.Q=0.1"], "100 L/s: ten times the scene's rate"),
    "Δt = 1 s": ([f"time={FAULT_STEPS_1S}"],
                 "first 20 steps of 1 s: storage-dominated (undrained) steps"),
    "Δt = T/4": (["time.steps=4"], "4 steps of 10000 s over injection and leak-off"),
    "b = 1, M = ∞": (["material.biot=1", "flow.biot_modulus=null"],
                     "incompressible constituents: no storage but b div u"),
    "frictionless": (["contact.friction=frictionless"],
                     "zero friction: the in-situ shear slides the faults at t = 0"),
    "F = 0.45": (["contact.friction_coefficient=0.45"],
                 "beyond the Coulomb limit at t = 0: the initial equilibrium slips"),
    "E 2 GPa / 200 GPa": (["material.young=where(z < -2000, 2.0e9, 2.0e11)"],
                          "Young's modulus 2 GPa below the fault's centre, 200 GPa above"),
    "K_f 1e-8 m²": (["flow.fracture_permeability=1.0e-8"],
                    "fracture permeability 1e-8 m², 300 times d₀²/12 (3.3e-11 m²)"),
}


def finite(out: Path) -> bool:
    """Whether every field of every written step is finite."""
    from poromech.io.xdmf import read_series

    for stem in ("displacement", "fractures", "flow"):
        if not (out / f"{stem}.xdmf").exists():
            continue
        series = read_series(out, stem)
        for k in range(len(series.times)):
            if not all(np.all(np.isfinite(v)) for v in series.fields(k).values()):
                return False
    return True


def cell(summary: dict, out: Path) -> tuple[str, bool]:
    """Table cell and whether the run converged."""
    if summary["status"] == "converged":
        c = summary["coupling"]
        mark = "✓" if finite(out) else "✓ but NaN"
        notes = []
        if c.get("fracture_stabilization_from") is not None:
            notes.append(f"β_f from t = {c['fracture_stabilization_from']:g} s")
        noisy = sum(bool(r.get("converged_at_noise")) for r in summary["solves"])
        if noisy:
            notes.append(f"{noisy} steps at the noise of g")
        rescued = [r["method"] for r in summary["solves"] if r.get("fallback_from") is not None]
        if rescued:
            notes.append(f"{len(rescued)} step{'s' * (len(rescued) > 1)} by {rescued[0]}")
        extra = f" ({'; '.join(notes)})" if notes else ""
        face = f" + {c['face_iterations']} face" if c.get("face_iterations") else ""
        return f"{mark} {c['g_evaluations']} / {c['newton_iterations']}{face}{extra}", True
    status = summary["status"]
    reason = next((w for w in status.replace(",", " ").replace(":", " ").split()
                   if w.startswith(("DIVERGED", "CONVERGED"))), status[:40])
    return f"✗ {reason}", False


#: Columns of the CSV of every table.
CSV_HEADER = ["case", "formulation", "converged", "g evaluations", "Newton iterations",
              "face Newton iterations", "seconds", "status"]


def run_table(cases: dict, formulations: tuple[str, ...], sub: str, again: bool
              ) -> tuple[list[list], list[list]]:
    """Every case × formulation through the command line into ``RUNS/sub``.

    ``cases``: name → (scene, overrides, what it probes). Returns the Markdown rows (a cell per
    formulation, :func:`cell`) and the CSV rows (:data:`CSV_HEADER`).
    """
    rows, csv_rows = [], []
    for name, (scene, sets, what) in cases.items():
        row = [name]
        slug = "".join(c if c.isalnum() else "_" for c in name)
        for f in formulations:
            out = RUNS / sub / f"{slug}_{f}"
            summary = run_cli(out, scene, [*sets, f"contact.formulation={f}"], again=again,
                              timeout=1800, warm=False)
            text, ok = cell(summary, out)
            row.append(text)
            c = summary.get("coupling", {})
            csv_rows.append([name, f, ok, c.get("g_evaluations", math.nan),
                             c.get("newton_iterations", math.nan), c.get("face_iterations", 0),
                             summary["process_seconds"], summary["status"][:200]])
        rows.append([*row, what])
    return rows, csv_rows


def write_table(stem: str, title: str, command: str, setting: str,
                formulations: tuple[str, ...], rows: list[list], csv_rows: list[list]) -> None:
    """``DOCS/stem.{csv,md}``: the table, its command and date, and what its cells mean."""
    stamp = f"Generated {datetime.date.today()} by `{command}`"
    DOCS.mkdir(parents=True, exist_ok=True)
    write_csv(DOCS / f"{stem}.csv", CSV_HEADER, csv_rows, stamp)
    header = ["case", *formulations, "what it probes"]
    (DOCS / f"{stem}.md").write_text(
        f"# {title}\n\n{stamp} (1 MPI rank). {setting}, Anderson (a step it fails on is "
        "solved again by NGMRES before it is cut), unless the case says otherwise. Cell: ✓ g "
        "evaluations / contact Newton iterations over the run, every attempt of a cut step "
        "included (`+ N face`: iterations of the face Newton of the condensed `mixed` solve, "
        "docs/poromechanics.md), or ✗ and the reason. Every field written by a converged run "
        "was checked to be finite.\n\n" + markdown_table(header, rows))


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--again", action="store_true")
    p.add_argument("--degree", type=int, choices=(1, 2), default=2,
                   help="displacement degree (default: 2, the scenes' own)")
    p.add_argument("--3d", dest="three", action="store_true",
                   help="the 3D fault scene's cases instead (CASES_3D)")
    args = p.parse_args()
    command = "python scripts/poromechanics_robustness.py"
    if args.three:
        cases = {n: (FAULT, [*FAULT_BASE, *sets], what) for n, (sets, what) in CASES_3D.items()}
        rows, csv_rows = run_table(cases, FORMULATIONS_3D, "robustness3d", args.again)
        write_table("robustness3d", "Coupled solver in 3D: stiff and extreme cases",
                    command + " --3d", "The 3D fault scene (configs/fault_reactivation3d.yaml) "
                    "on its coarse uniform mesh (7k P1 displacement and 36k flow unknowns), P1, "
                    "20 steps", FORMULATIONS_3D, rows, csv_rows)
        return
    p1 = args.degree == 1
    cases = {n: (scene, [*sets, *(["degree=1"] if p1 else [])], what)
             for n, (scene, sets, what) in CASES.items()}
    stem = "robustness_p1" if p1 else "robustness"
    rows, csv_rows = run_table(cases, FORMULATIONS, stem, args.again)
    write_table(stem, f"Coupled solver: stiff and extreme cases{' (P1)' if p1 else ''}",
                command + (" --degree 1" if p1 else ""),
                f"Six-fracture scene, m = 0, {'P1' if p1 else 'P2'}", FORMULATIONS, rows,
                csv_rows)


if __name__ == "__main__":
    main()
