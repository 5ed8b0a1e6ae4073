"""Semi-smooth Newton iterations against the mesh on a 3D fracture network in contact.

Scene: ``configs/network3d.yaml`` (a 2 m box, seven fractures making an X, a T, a fracture
reaching the front face and a kink of two rectangles; the bottom fixed, the top pushed down in
step 1 and sheared along x in steps 2-4; Coulomb friction F = 0.5). Mesh levels scale one size
family by ``s``: ``mesh.fracture_size = 0.1 s``, ``mesh.size = 0.3 s``. On every level and degree
one process solves the scene with every formulation, MUMPS LU as the linear solver:

* ``nitsche`` θ = -1 (the reference), ``nitsche`` θ = 0, ``mean_nitsche``, ``stabilized_mixed``
  (both θ = -1) and ``mixed`` (no θ), and records for each the Newton iterations of every load
  step, the states of the contact points at the final time (open / stick / slip; the Gauss
  points of the contact quadrature for ``nitsche``, one per face otherwise), the wall time of
  the solve and the 1-minute load average when the case started (2 shared cores: wall times are
  upper bounds);
* ``jump_diff``: the relative L² difference of the final jump field ``[[u]]`` from the
  reference's, over all fracture faces (same mesh, 6-point face quadrature), and ``diff_X``,
  ``diff_T``, ``diff_boundary``, ``diff_kink`` the same over each group of fractures (x1 + x2,
  bar + stem, edge, kink_a + kink_b), and ``diff_T_n``, ``diff_T_t`` the normal and tangential
  parts of the T's (each relative to the reference's whole jump there). The formulations are
  different discretizations of one problem: the differences must shrink under refinement (a
  self-convergence table);
* ``state_mismatch``: the fraction of the written face states (``fractures.csv``, every load
  step) that disagree with the written tractions and jumps, as
  ``tests/test_network3d.py::test_network_states_match_tractions_and_jumps`` checks them:
  open ⇔ T_n = 0 and [[u]]_n ≤ 0 (up to 1e-4 of the largest |[[u]]_τ|); stick ⇔ T_n < 0,
  |T_τ| < F|T_n| and a slip increment below 0.2 of the largest; slip ⇔ T_n < 0 and
  |T_τ| = F|T_n| within 1 %. ``mismatch`` counts the disagreeing open/stick/slip entries.

A load step is not cut when Newton fails (``time.max_cuts = 0``): ``iterations`` then ends
with the failed step's count, marked ✗, and the run stops there (its jump differences are left
out: nan).

The β⁰ cases (× 0.1 and × 10 of the defaults: ``beta_n``, ``beta_t`` = 250 E, 10 E; for
``mixed`` its only parameters ``beta_sm_n``, ``beta_sm_t`` = E, 0.04 E) run for every
formulation on one P1 and one P2 level (``BETA_LEVELS``); their ``jump_diff`` and group
differences are against the same formulation with the default β⁰ on that level.

Run (one process at a time, about 50 minutes on 2 shared cores; `--workers 2` about 35)::

    python scripts/contact3d_newton_scaling.py   # -> docs/mechanics3d/newton_scaling.{csv,md,png}
    python scripts/contact3d_newton_scaling.py --quick    # the two coarsest P1 levels only
    python scripts/contact3d_newton_scaling.py --only 2:1.3 --append   # one level, merged
    python scripts/contact3d_newton_scaling.py --only beta:2 --append  # the P2 β⁰ level
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
from report_common import fmt, read_csv, write_csv

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics3d"
SCENE = ROOT / "configs" / "network3d.yaml"
#: Mesh scale factors, coarse to fine, per degree (P2 at s = 1.0: about 77k unknowns).
SCALES = {1: (2.5, 1.8, 1.3, 1.0, 0.75), 2: (2.5, 2.0, 1.6, 1.3, 1.0)}
#: Formulations of every level: (name, formulation, θ or None); the first is the reference.
VARIANTS = (("nitsche", "nitsche", -1), ("nitsche θ=0", "nitsche", 0),
            ("mean_nitsche", "mean_nitsche", -1), ("stabilized_mixed", "stabilized_mixed", -1),
            ("mixed", "mixed", None))
NAMES = tuple(v[0] for v in VARIANTS)
#: β⁰ factors and the level (degree: scale) they run on (with the default, factor 1).
BETA_FACTORS = (0.1, 10.0)
BETA_LEVELS = {1: 1.3, 2: 2.0}
#: Fracture groups of the per-group jump differences.
GROUPS = {"X": ("x1", "x2"), "T": ("bar", "stem"), "boundary": ("edge",),
          "kink": ("kink_a", "kink_b")}
#: Young's modulus of the scene (Pa), which the default β⁰ scale with.
E = 1.0e10
#: Friction coefficient of the scene.
F = 0.5
#: Newton iterations per load step that every level must stay within.
TARGET = 15
FIELDS = ["case", "formulation", "theta", "degree", "scale", "beta_factor", "cells",
          "fracture_faces", "dofs", "iterations", "newton_max", "newton_total", "krylov",
          "open", "stick", "slip", "jump_diff", *(f"diff_{g}" for g in GROUPS),
          "diff_T_n", "diff_T_t", "state_mismatch", "mismatch", "converged", "time_solve", "load"]


def overrides(degree: int, scale: float, formulation: str, theta: int | None,
              beta_factor: float = 1.0) -> list[str]:
    """The ``--set`` overrides of one case (only keys that act on the formulation)."""
    sets = [f"degree={degree}", f"mesh.size={0.3 * scale:g}",
            f"mesh.fracture_size={0.1 * scale:g}", f"contact.formulation={formulation}",
            "solver.linear_solver=direct", "time.max_cuts=0", "output.xdmf=false",
            "output.checkpoint=false"]
    if theta is not None:
        sets.append(f"contact.theta={theta}")
    if beta_factor != 1.0:
        from poromech.scene.schema import Contact

        if formulation == "mixed":
            sets += [f"contact.beta_sm_n={Contact.BETA_SM_N_PER_E * E * beta_factor:g}",
                     f"contact.beta_sm_t={Contact.BETA_SM_T_PER_E * E * beta_factor:g}"]
        else:
            sets += [f"contact.beta_n={Contact.BETA_N_PER_E * E * beta_factor:g}",
                     f"contact.beta_t={Contact.BETA_T_PER_E * E * beta_factor:g}"]
    return sets


def state_mismatch(path: Path) -> tuple[float, str]:
    """Fraction of the written face states that disagree with the written tractions and jumps.

    Every output time of ``fractures.csv``; the criteria of the module docstring. Returns the
    fraction and the counts of disagreeing open/stick/slip entries.
    """
    with open(path) as fh:
        rows = list(csv.DictReader(fh))
    bad, total, prev = np.zeros(3, dtype=int), 0, None
    for t in sorted({float(r["time"]) for r in rows}):
        sel = [r for r in rows if float(r["time"]) == t]
        st = np.array([r["state"] for r in sel])
        tn, tt, jn = (np.array([float(r[k]) for r in sel])
                      for k in ("traction_n", "traction_t", "jump_n"))
        jt = np.array([[float(r[f"jump_t{c}"]) for c in "xyz"] for r in sel])
        scale_t, scale_j = np.abs(tn).max(initial=0.0), np.linalg.norm(jt, axis=1).max(initial=0.0)
        inc = np.zeros(len(sel)) if prev is None else np.linalg.norm(jt - prev, axis=1)
        o, s, sl = st == "open", st == "stick", st == "slip"
        bad[0] += np.count_nonzero(o & ((np.abs(tn) > 1e-12 * scale_t) | (jn >= 1e-4 * scale_j)))
        bad[1] += np.count_nonzero(s & ((tn >= 0.0) | (tt >= F * np.abs(tn))
                                        | (inc > 0.2 * inc.max(initial=0.0))))
        bad[2] += np.count_nonzero(sl & ((tn >= 0.0) | (np.abs(tt - F * np.abs(tn))
                                                        > 0.01 * F * np.abs(tn))))
        total += len(sel)
        prev = jt
    return float(bad.sum() / max(total, 1)), "/".join(map(str, bad))


def solve(sets: list[str]) -> tuple[dict, np.ndarray]:
    """One run in this process: the row's numbers and, per face point, (weight, group, jump)."""
    import dolfinx_solver  # noqa: F401

    from poromech.run import Run
    from poromech.scene.loading import load_scene
    from poromech.verification.jumps import face_quadrature, jump_values

    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    scene = load_scene(SCENE, sets)
    with tempfile.TemporaryDirectory() as tmp, Run(scene, tmp) as run:
        status = "converged"
        try:
            summary = run.execute()
        except Exception as exc:  # noqa: BLE001 - a failed solve is a row of the study
            summary, status = run.summary, f"failed: {exc}"[:100]
        elapsed = time.perf_counter() - t0
        codes = run.physics.model.active_set()
        fm = run.physics.fm
        q = face_quadrature(fm, 6)
        jumps = jump_values(run.physics.model.u, q)
        names = [fr.name for fr in fm.geometry.fractures]
        group_of = [next(k for k, g in enumerate(GROUPS.values()) if n in g) for n in names]
        group = np.asarray(group_of)[fm.fractures.fracture[q.face]]
        mismatch = state_mismatch(Path(tmp) / "fractures.csv") if status == "converged" \
            else (float("nan"), "")
    its = [int(r["iterations"]) for r in summary.get("solves", [])]
    ok = status == "converged" and all(r["converged"] for r in summary.get("solves", []))
    failed = re.search(r"after (\d+) iterations", summary.get("status", status))
    if failed:  # the failed load step: its iterations, marked
        its.append(int(failed.group(1)))
    text = "/".join(map(str, its)) + ("✗" if failed else "")
    row = {"cells": summary["mesh"]["cells"], "fracture_faces": summary["mesh"]["fracture_faces"],
           "dofs": summary["dofs"], "iterations": text,
           "newton_max": max(its, default=0), "newton_total": sum(its),
           "krylov": summary["linear_solver"]["krylov_iterations"],
           "open": int(np.count_nonzero(codes % 2 == 0)),
           "stick": int(np.count_nonzero(codes == 1)),
           "slip": int(np.count_nonzero((codes % 2 == 1) & (codes != 1))),
           "state_mismatch": mismatch[0], "mismatch": mismatch[1],
           "converged": ok, "time_solve": elapsed, "load": load}
    return row, np.column_stack([q.weights, group, jumps, q.normal])


def differences(wj: np.ndarray, ref: np.ndarray) -> dict:
    """Relative L² differences of the jumps from the reference's: all faces and per group.

    ``wj`` and ``ref``: per face point, (weight, group, jump (3), normal (3)). ``diff_T_n`` and
    ``diff_T_t``: the normal and tangential parts of the T group's difference, each relative to
    the reference's whole jump on the T (their squares add up to ``diff_T``²).
    """
    keys = ("jump_diff", *(f"diff_{g}" for g in GROUPS), "diff_T_n", "diff_T_t")
    if wj.shape != ref.shape or not np.any(ref[:, 2:5]):
        return dict.fromkeys(keys, float("nan"))
    w, group, normal = ref[:, 0], ref[:, 1], ref[:, 5:8]
    e = wj[:, 2:5] - ref[:, 2:5]
    en = np.einsum("ij,ij->i", e, normal)
    d2n = w * en**2
    d2 = w * np.sum(e**2, axis=1)
    r2 = w * np.sum(ref[:, 2:5] ** 2, axis=1)
    out = {"jump_diff": float(np.sqrt(d2.sum() / r2.sum()))}
    for k, g in enumerate(GROUPS):
        sel = group == k
        out[f"diff_{g}"] = float(np.sqrt(d2[sel].sum() / r2[sel].sum())) if np.any(sel) \
            else float("nan")
    t = group == list(GROUPS).index("T")
    out["diff_T_n"] = float(np.sqrt(d2n[t].sum() / r2[t].sum()))
    out["diff_T_t"] = float(np.sqrt((d2[t] - d2n[t]).sum() / r2[t].sum()))
    return out


def level(degree: int, scale: float, beta: bool, forms: list[str] | None = None) -> list[dict]:
    """Every case of one level, in this process.

    Jump differences against the reference formulation (default β⁰), or for the β⁰ cases
    against the same formulation with the default β⁰. ``forms``: only these variants (and the
    reference).
    """
    rows, ref, ref_ok = [], None, True
    for name, form, theta in VARIANTS:
        if forms and name not in forms and ref is not None:
            continue
        base = None
        for factor in (1.0, *BETA_FACTORS) if beta else (1.0,):
            row, wj = solve(overrides(degree, scale, form, theta, factor))
            if ref is None:
                ref, ref_ok = wj, row["converged"]
            if base is None:
                base, base_ok = wj, row["converged"]
            case = name if factor == 1.0 else f"{name} β⁰×{factor:g}"
            diff = differences(wj, ref if factor == 1.0 else base)
            # a failed run (or reference) holds the last accepted state, not its solution
            if not (row["converged"] and (ref_ok if factor == 1.0 else base_ok)):
                diff = dict.fromkeys(diff, float("nan"))
            row.update(diff)
            rows.append({"case": case, "formulation": form,
                         "theta": "" if theta is None else theta, "degree": degree,
                         "scale": scale, "beta_factor": factor, **row})
    return rows


def _child(degree: int, scale: float, beta: bool, forms: list[str] | None) -> list[dict]:
    cmd = [sys.executable, __file__, "--level", str(degree), str(scale), str(int(beta))]
    cmd += ["--forms", *forms] if forms else []
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    rows = json.loads(proc.stdout.strip().splitlines()[-1])
    for r in rows:
        print({k: r[k] for k in ("case", "degree", "scale", "dofs", "iterations", "jump_diff",
                                 "state_mismatch", "time_solve")}, flush=True)
    return rows


def jobs(quick: bool, only: list[str] | None = None) -> list[tuple[int, float, bool]]:
    """(degree, scale, β study) of every process, the most expensive first.

    ``only``: ``degree:scale`` or ``beta:degree`` items selecting some of them (``beta``: both
    β⁰ levels). A β⁰ level also gives the default-β⁰ rows of its level.
    """
    if only:
        out = []
        for o in only:
            if o == "beta":
                out += [(d, s, True) for d, s in BETA_LEVELS.items()]
            elif o.startswith("beta:"):
                d = int(o.split(":")[1])
                out.append((d, BETA_LEVELS[d], True))
            else:
                out.append((int(o.split(":")[0]), float(o.split(":")[1]), False))
        return out
    if quick:
        return [(1, s, False) for s in SCALES[1][:2]]
    return [(d, s, BETA_LEVELS[d] == s) for d in (2, 1) for s in reversed(SCALES[d])]


def read_rows(path: Path) -> tuple[list[str], list[dict]]:
    """Commands and rows of an earlier CSV, numbers parsed."""
    comments, rows = read_csv(path, text=("case", "formulation", "iterations", "mismatch"))
    return [c.removeprefix("Generated by ") for c in comments], rows


def _order(r: dict) -> tuple:
    name = r["case"].split(" β⁰")[0]
    return (r["beta_factor"] != 1.0, r["degree"], NAMES.index(name) if name in NAMES else 9,
            -r["scale"], r["beta_factor"])


def _table(rows: list[dict], keys: tuple[str, ...]) -> list[str]:
    lines = ["| " + " | ".join(keys) + " |\n|" + "---|" * len(keys) + "\n"]
    return lines + ["| " + " | ".join(fmt(r[k]) for k in keys) + " |\n" for r in rows]


def _verdicts(rows: list[dict]) -> str:
    """Largest Newton count per formulation × degree (default β⁰) against the target."""
    out = []
    for name in NAMES:
        for d in (1, 2):
            sel = [r for r in rows if r["case"] == name and r["degree"] == d]
            if not sel:
                continue
            worst = max(r["newton_max"] for r in sel)
            ok = worst <= TARGET and all(r["converged"] for r in sel)
            out.append(f"{name} P{d} {worst} ({'met' if ok else 'not met'})")
    return ", ".join(out)


def _trends(rows: list[dict]) -> str:
    """Sentences on the self-convergence and the states, from the default-β⁰ rows."""
    parts = []
    for d in (2, 1):
        items = []
        for name in NAMES[1:]:
            seq = sorted((r for r in rows if r["case"] == name and r["degree"] == d
                          and r["converged"]), key=lambda r: -r["scale"])
            if len(seq) > 1:
                items.append(f"{name} {seq[0]['jump_diff']:.2g} → {seq[-1]['jump_diff']:.2g}")
        if items:
            parts.append(f"P{d} jump difference from `nitsche` θ = -1, coarsest → finest level: "
                         + ", ".join(items) + ".")
    done = [r["state_mismatch"] for r in rows if r["converged"]]
    if done:
        parts.append(f"Converged runs: at most {max(done):.2g} of the written states disagree "
                     "with the tractions and jumps.")
    return " ".join(parts)


def report(rows: list[dict], stamps: list[str]) -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    stamp = "; ".join(f"Generated by {s}" for s in stamps)
    rows = sorted(rows, key=_order)
    diffs = ("jump_diff", *(f"diff_{g}" for g in GROUPS), "diff_T_n", "diff_T_t")
    for r in rows:  # (a failed run's jump differences are NaN from level())
        for k in FIELDS:  # columns added after a row was run
            r.setdefault(k, float("nan"))
    write_csv(OUT / "newton_scaling.csv", [stamp], FIELDS, rows)
    main_rows = [r for r in rows if r["beta_factor"] == 1.0]
    beta_rows = sorted((r for r in rows if (r["degree"], r["scale"]) in BETA_LEVELS.items()),
                       key=lambda r: (r["degree"], NAMES.index(r["case"].split(" β⁰")[0]),
                                      r["beta_factor"]))
    keys = ("case", "degree", "scale", "cells", "fracture_faces", "dofs", "iterations",
            "newton_max", "newton_total", "open", "stick", "slip", "jump_diff",
            "state_mismatch", "mismatch", "converged", "time_solve", "load")
    self_keys = ("case", "degree", "scale", "dofs", *diffs)
    lines = [f"# Newton iterations on a 3D fracture network in contact\n\n{stamp}. See the "
             "docstring of `scripts/contact3d_newton_scaling.py` for the scene, the levels and "
             "the columns. Linear solver: MUMPS LU (`krylov`: GMRES iterations of the "
             "directions solved with a kept factorization as preconditioner, the stale "
             "solves). `iterations`: Newton iterations of the 4 "
             "load steps (step 1 compression, steps 2-4 shear); `open`/`stick`/`slip`: contact "
             "points in each state at the final time (Gauss points for nitsche, faces "
             "otherwise); `jump_diff`: relative L² difference of the final jumps from "
             "`nitsche` θ = -1 on the same mesh; `state_mismatch`: fraction of the written "
             "face states (every step) that disagree with the written tractions and jumps, "
             "`mismatch` the disagreeing open/stick/slip entries.\n\n"
             f"Largest Newton count of a load step against the target ≤ {TARGET}: "
             + _verdicts(main_rows) + ". " + _trends(main_rows)
             + "\n\n## Levels (default β⁰)\n\n"]
    lines += _table(main_rows, keys)
    lines += ["\n## Self-convergence per fracture group\n\nRelative L² difference of the "
              "final jump from `nitsche` θ = -1 on the same mesh, over all fractures and over "
              "each group: X = x1 + x2, T = bar + stem, boundary = edge, kink = kink_a + "
              "kink_b; `diff_T_n`, `diff_T_t`: the normal and tangential parts of `diff_T` "
              "(nan in rows run before they were recorded).\n\n"]
    lines += _table([r for r in main_rows if r["case"] != NAMES[0]], self_keys)
    lines += ["\n## β⁰ sweep\n\n× 0.1, × 1, × 10 of the default β⁰ (`beta_n`, `beta_t`; "
              "for `mixed` `beta_sm_n`, `beta_sm_t`); `jump_diff` and the group columns of "
              "× 0.1 and × 10 are against the same formulation with the default β⁰.\n\n"]
    lines += _table(beta_rows, ("case", "degree", "scale", "dofs", "iterations", "newton_max",
                                "newton_total", "jump_diff", *(f"diff_{g}" for g in GROUPS),
                                "state_mismatch", "converged", "time_solve"))
    (OUT / "newton_scaling.md").write_text("".join(lines))
    _figure(rows)


def _figure(rows: list[dict]) -> None:
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    main_rows = [r for r in rows if r["beta_factor"] == 1.0]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    for k, name in enumerate(NAMES):
        for d, marker in ((1, "o"), (2, "s")):
            seq = sorted((r for r in main_rows if r["case"] == name and r["degree"] == d),
                         key=lambda r: r["dofs"])
            if not seq:
                continue
            x = [r["dofs"] for r in seq]
            kw = {"color": f"C{k}", "marker": marker, "ls": "-" if d == 2 else "--"}
            axes[0].plot(x, [r["newton_max"] for r in seq], label=f"{name} P{d}", **kw)
            if k:
                axes[1].loglog(x, [r["jump_diff"] for r in seq], label=f"{name} P{d}", **kw)
            beta = sorted((r for r in rows if r["case"].split(" β⁰")[0] == name
                           and r["degree"] == d and r["scale"] == BETA_LEVELS[d]),
                          key=lambda r: r["beta_factor"])
            axes[2].semilogx([r["beta_factor"] for r in beta], [r["newton_max"] for r in beta],
                             label=f"{name} P{d}", **kw)
    for ax in (axes[0], axes[2]):
        ax.axhline(TARGET, color="k", lw=0.8, ls=":")
        ax.set_ylabel("Newton iterations, largest load step")
    axes[0].set_xscale("log")
    top = min(max([TARGET] + [r["newton_max"] for r in rows]) + 3, 40)
    for ax in (axes[0], axes[2]):
        ax.set_ylim(0, top)
    axes[0].set_title(f"β⁰ default; dotted: the target; failed runs above {top}")
    axes[1].set_ylabel("jump difference from nitsche θ=-1 (rel. L²)")
    axes[2].set_xlabel("β⁰ / default")
    axes[2].set_title(f"β⁰ sweep: P1 s = {BETA_LEVELS[1]:g}, P2 s = {BETA_LEVELS[2]:g}")
    for ax in axes:
        if ax is not axes[2]:
            ax.set_xlabel("unknowns")
        ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(OUT / "newton_scaling.png", dpi=80)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="the two coarsest P1 levels only")
    parser.add_argument("--workers", type=int, default=1, help="processes at a time")
    parser.add_argument("--only", nargs="+",
                        help="levels to run: degree:scale, beta:degree or beta items")
    parser.add_argument("--forms", nargs="+", choices=NAMES,
                        help="only these formulations (the reference always runs)")
    parser.add_argument("--append", action="store_true",
                        help="merge into the existing CSV (new rows replace the same cases)")
    parser.add_argument("--level", nargs=3, help=argparse.SUPPRESS)
    parser.add_argument("--report-only", action="store_true",
                        help="only remake the Markdown and the figure from the CSV")
    args = parser.parse_args()
    if args.report_only:
        report(*reversed(read_rows(OUT / "newton_scaling.csv")))
        return
    if args.level:
        d, s, b = args.level
        print(json.dumps(level(int(d), float(s), bool(int(b)), args.forms)))
        return
    with ThreadPoolExecutor(args.workers) as pool:
        rows = [r for rows in pool.map(lambda job: _child(*job, args.forms),
                                       jobs(args.quick, args.only)) for r in rows]
    command = "python scripts/contact3d_newton_scaling.py " + shlex.join(sys.argv[1:])
    stamps = [f"`{command.strip()}` ({datetime.date.today()})"]

    def key(r):
        return r["case"], int(r["degree"]), float(r["scale"]), float(r["beta_factor"])

    # a level and a β⁰ level can share a mesh: its default-β⁰ rows are solved twice, kept once
    rows = list({key(r): r for r in rows}.values())
    if args.append:
        old_stamps, old = read_rows(OUT / "newton_scaling.csv")
        done = {key(r) for r in rows}
        rows = [r for r in old if key(r) not in done] + rows
        stamps = old_stamps + stamps
    report(rows, stamps)


if __name__ == "__main__":
    main()
