"""Semi-smooth Newton iterations against the mesh on a 3D fracture network in contact.

Scene: ``configs/network3d.yaml`` (a 2 m box, five fractures making an X, a T and a fracture
reaching the front face; the bottom fixed, the top pushed down in step 1 and sheared along x in
steps 2-4; Coulomb friction F = 0.5). Mesh levels scale one size family by ``s``:
``mesh.fracture_size = 0.1 s``, ``mesh.size = 0.3 s``. On every level and degree one process
solves the scene with

* ``nitsche`` θ = -1 (the reference), ``mean_nitsche`` (θ = -1) and ``nitsche`` θ = 0, and
  records for each the Newton iterations of every load step, the Krylov iterations, the states
  of the contact points at the final time (open / stick / slip; the Gauss points of the contact
  quadrature for ``nitsche``, one per face for ``mean_nitsche``), the wall time of the solve and
  the 1-minute load average when the case started (2 shared cores: wall times are upper bounds);
* ``jump_diff``: the relative L² difference of the final jump field ``[[u]]`` from the
  reference's, over all fracture faces (same mesh, 6-point face quadrature). The formulations
  are different discretizations of one problem: the difference must shrink under refinement.

The β⁰ cases (``nitsche`` θ = -1, ``beta_n`` and ``beta_t`` × 0.1 and × 10 of the defaults
250 E and 10 E) run on one P1 level; ``jump_diff`` is then against the default β⁰ on that level.

Run (about 15 minutes of CPU on 2 cores; every level in its own process, two at a time)::

    python scripts/contact3d_newton_scaling.py   # -> docs/mechanics3d/newton_scaling.{csv,md,png}
    python scripts/contact3d_newton_scaling.py --quick    # the two coarsest P1 levels only
    python scripts/contact3d_newton_scaling.py --only 2:1.0 --append   # one level, merged
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import shlex
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics3d"
SCENE = ROOT / "configs" / "network3d.yaml"
#: Mesh scale factors, coarse to fine, per degree (P2 at s = 1 costs ~4 minutes a formulation:
#: there only ``nitsche`` θ = -1, ``FINE_ONLY``).
SCALES = {1: (2.5, 1.8, 1.3, 1.0, 0.75), 2: (2.5, 1.8, 1.3, 1.0)}
FINE_ONLY = {(2, 1.0)}
#: Formulations of every level: (name, formulation, θ); the first is the reference.
VARIANTS = (("nitsche", "nitsche", -1), ("mean_nitsche", "mean_nitsche", -1),
            ("nitsche θ=0", "nitsche", 0))
#: β⁰ factors and the P1 level they run on.
BETA_FACTORS = (0.1, 10.0)
BETA_SCALE = 1.3
#: Newton iterations per load step that every level must stay within.
TARGET = 15
FIELDS = ["case", "formulation", "theta", "degree", "scale", "beta_factor", "cells",
          "fracture_faces", "dofs", "iterations", "newton_max", "newton_total", "krylov",
          "open", "stick", "slip", "jump_diff", "converged", "time_solve", "load"]


def overrides(degree: int, scale: float, formulation: str, theta: int,
              beta_factor: float = 1.0) -> list[str]:
    """The ``--set`` overrides of one case."""
    sets = [f"degree={degree}", f"mesh.size={0.3 * scale:g}",
            f"mesh.fracture_size={0.1 * scale:g}", f"contact.formulation={formulation}",
            f"contact.theta={theta}", "output.xdmf=false", "output.fractures_csv=false"]
    if beta_factor != 1.0:
        from poromech.scene.schema import Contact

        E = 1.0e10
        sets += [f"contact.beta_n={Contact.BETA_N_PER_E * E * beta_factor:g}",
                 f"contact.beta_t={Contact.BETA_T_PER_E * E * beta_factor:g}"]
    return sets


def solve(sets: list[str]) -> tuple[dict, np.ndarray]:
    """One run in this process: the row's numbers and the final jumps at the face points."""
    import dolfinx_solver  # noqa: F401

    from poromech.run import Run
    from poromech.scene.loading import load_scene
    from poromech.verification.jumps import face_quadrature, jump_values

    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    scene = load_scene(SCENE, sets)
    with Run(scene) as run:
        status = "converged"
        try:
            summary = run.execute()
        except Exception as exc:  # noqa: BLE001 - a failed solve is a row of the study
            summary, status = run.summary, f"failed: {exc}"[:100]
        codes = run.physics.model.active_set()
        q = face_quadrature(run.physics.fm, 6)
        jumps = jump_values(run.physics.model.u, q)
        weights = q.weights
    its = [int(r["iterations"]) for r in summary.get("solves", [])]
    ok = status == "converged" and all(r["converged"] for r in summary.get("solves", []))
    row = {"cells": summary["mesh"]["cells"], "fracture_faces": summary["mesh"]["fracture_faces"],
           "dofs": summary["dofs"], "iterations": "/".join(map(str, its)),
           "newton_max": max(its, default=0), "newton_total": sum(its),
           "krylov": summary["linear_solver"]["krylov_iterations"],
           "open": int(np.count_nonzero(codes % 2 == 0)),
           "stick": int(np.count_nonzero(codes == 1)),
           "slip": int(np.count_nonzero((codes % 2 == 1) & (codes != 1))),
           "converged": ok, "time_solve": time.perf_counter() - t0, "load": load}
    return row, np.column_stack([weights, jumps])


def level(degree: int, scale: float, beta: bool) -> list[dict]:
    """Every case of one level, in this process; jump differences against the first."""
    if beta:
        specs = [("nitsche β⁰×1", "nitsche", -1, 1.0)] + [
            (f"nitsche β⁰×{f:g}", "nitsche", -1, f) for f in BETA_FACTORS]
    else:
        variants = VARIANTS[:1] if (degree, scale) in FINE_ONLY else VARIANTS
        specs = [(name, form, theta, 1.0) for name, form, theta in variants]
    rows, ref = [], None
    for name, form, theta, factor in specs:
        row, wj = solve(overrides(degree, scale, form, theta, factor))
        if ref is None:
            ref = wj
        w, diff = ref[:, 0], wj[:, 1:] - ref[:, 1:]
        norm = np.sqrt(np.sum(w * np.sum(ref[:, 1:] ** 2, axis=1)))
        row["jump_diff"] = float(np.sqrt(np.sum(w * np.sum(diff**2, axis=1))) / norm) \
            if wj.shape == ref.shape else float("nan")
        rows.append({"case": name, "formulation": form, "theta": theta, "degree": degree,
                     "scale": scale, "beta_factor": factor, **row})
    return rows


def _child(degree: int, scale: float, beta: bool) -> list[dict]:
    cmd = [sys.executable, __file__, "--level", str(degree), str(scale), str(int(beta))]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    rows = json.loads(proc.stdout.strip().splitlines()[-1])
    for r in rows:
        print({k: r[k] for k in ("case", "degree", "scale", "dofs", "iterations", "jump_diff",
                                 "time_solve")}, flush=True)
    return rows


def jobs(quick: bool, only: list[str] | None = None) -> list[tuple[int, float, bool]]:
    """(degree, scale, β study) of every process, the most expensive first.

    ``only``: ``degree:scale`` or ``beta`` items selecting some of them.
    """
    if only:
        return [(1, BETA_SCALE, True) if o == "beta"
                else (int(o.split(":")[0]), float(o.split(":")[1]), False) for o in only]
    if quick:
        return [(1, s, False) for s in SCALES[1][:2]]
    out = [(d, s, False) for d in (2, 1) for s in reversed(SCALES[d])]
    return out + [(1, BETA_SCALE, True)]


def _fmt(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def read_csv(path: Path) -> tuple[list[str], list[dict]]:
    """Commands and rows of an earlier CSV, numbers parsed."""
    if not path.exists():
        return [], []
    lines = path.read_text().splitlines()
    stamps = [ln.lstrip("# ").removeprefix("Generated by ") for ln in lines if ln.startswith("#")]
    rows = list(csv.DictReader(ln for ln in lines if not ln.startswith("#")))
    for r in rows:
        for k, v in r.items():
            if k in ("case", "formulation", "iterations"):
                continue
            r[k] = v == "True" if v in ("True", "False") else (float(v) if "." in v or "e" in v
                                                               or "nan" in v else int(v))
    return stamps, rows


def report(rows: list[dict], stamps: list[str]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    stamp = "; ".join(f"Generated by {s}" for s in stamps)
    rows = sorted(rows, key=lambda r: (r["beta_factor"] != 1.0 or r["case"].startswith("nitsche β"),
                                       r["degree"], [v[0] for v in VARIANTS].index(r["case"])
                                       if r["case"] in [v[0] for v in VARIANTS] else 9,
                                       -r["scale"], r["beta_factor"]))
    with open(OUT / "newton_scaling.csv", "w", newline="") as fh:
        fh.write(f"# {stamp}\n")
        w = csv.DictWriter(fh, FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
    keys = ("case", "degree", "scale", "cells", "fracture_faces", "dofs", "iterations",
            "newton_max", "newton_total", "krylov", "open", "stick", "slip", "jump_diff",
            "time_solve", "load")
    verdicts = []
    for name in dict.fromkeys(r["case"] for r in rows):
        sel = [r for r in rows if r["case"] == name]
        worst = max(r["newton_max"] for r in sel)
        ok = worst <= TARGET and all(r["converged"] for r in sel)
        verdicts.append(f"{name} {worst} ({'met' if ok else 'not met'})")
    lines = [f"# Newton iterations on a 3D fracture network in contact\n\n{stamp}. See the "
             "docstring of `scripts/contact3d_newton_scaling.py` for the scene, the levels and "
             "the columns. `iterations`: Newton iterations of the 4 load steps (step 1 "
             "compression, steps 2-4 shear); `open`/`stick`/`slip`: contact points in each state "
             "at the final time (Gauss points for nitsche, faces for mean_nitsche); "
             "`jump_diff`: relative L² difference of the final jumps from `nitsche` θ = -1 on "
             "the same mesh (β⁰ rows: from the default β⁰).\n\n"
             f"Largest Newton count of a load step against the target ≤ {TARGET}: "
             + ", ".join(verdicts) + ".\n\n| "
             + " | ".join(keys) + " |\n|" + "---|" * len(keys) + "\n"]
    for r in rows:
        lines.append("| " + " | ".join(_fmt(r[k]) for k in keys) + " |\n")
    (OUT / "newton_scaling.md").write_text("".join(lines))
    _figure(rows)


def _figure(rows: list[dict]) -> None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if r["beta_factor"] == 1.0 and not r["case"].startswith("nitsche β")]
    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for k, (name, _, _) in enumerate(VARIANTS):
        for d, marker in ((1, "o"), (2, "s")):
            seq = sorted((r for r in rows if r["case"] == name and r["degree"] == d),
                         key=lambda r: r["dofs"])
            if not seq:
                continue
            x = [r["dofs"] for r in seq]
            kw = {"color": f"C{k}", "marker": marker, "ls": "-" if d == 2 else "--"}
            axes[0].plot(x, [r["newton_max"] for r in seq], label=f"{name} P{d}", **kw)
            if k:
                axes[1].loglog(x, [r["jump_diff"] for r in seq], label=f"{name} P{d}", **kw)
    axes[0].axhline(TARGET, color="k", lw=0.8, ls=":")
    axes[0].set_xscale("log")
    axes[0].set_ylim(0, max([TARGET] + [r["newton_max"] for r in rows]) + 3)
    axes[0].set_ylabel("Newton iterations, largest load step")
    axes[0].set_title("β⁰ default; dotted: the target")
    axes[1].set_ylabel("jump difference from nitsche θ=-1 (rel. L²)")
    for ax in axes:
        ax.set_xlabel("unknowns")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(OUT / "newton_scaling.png", dpi=80)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the two coarsest P1 levels only")
    parser.add_argument("--workers", type=int, default=2, help="processes at a time")
    parser.add_argument("--only", nargs="+", help="levels to run: degree:scale items or beta")
    parser.add_argument("--append", action="store_true",
                        help="merge into the existing CSV (new rows replace the same cases)")
    parser.add_argument("--level", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--report-only", action="store_true",
                        help="only remake the Markdown and the figure from the CSV")
    args = parser.parse_args()
    if args.report_only:
        report(*reversed(read_csv(OUT / "newton_scaling.csv")))
        return
    if args.level:
        d, s, b = args.level
        print(json.dumps(level(int(d), float(s), bool(int(b)))))
        return
    with ThreadPoolExecutor(args.workers) as pool:
        rows = [r for rows in pool.map(lambda job: _child(*job), jobs(args.quick, args.only))
                for r in rows]
    command = "python scripts/contact3d_newton_scaling.py " + shlex.join(sys.argv[1:])
    stamps = [f"`{command.strip()}` ({datetime.date.today()})"]
    if args.append:
        old_stamps, old = read_csv(OUT / "newton_scaling.csv")

        def key(r):
            return r["case"], int(r["degree"]), float(r["scale"]), float(r["beta_factor"])

        done = {key(r) for r in rows}
        rows = [r for r in old if key(r) not in done] + rows
        stamps = old_stamps + stamps
    report(rows, stamps)


if __name__ == "__main__":
    main()
