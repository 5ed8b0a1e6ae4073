"""The 3D fault-reactivation scene: history, error against run time, and the cost ratios.

    python scripts/fault_reactivation3d.py  # 3 levels: nitsche, stabilized_mixed, mean_nitsche P1
    python scripts/fault_reactivation3d.py --levels coarse medium --formulations nitsche-P1
    python scripts/fault_reactivation3d.py --levels xfine --formulations nitsche-P2 --ranks 2
    python scripts/fault_reactivation3d.py --levels local4 local2 local1 --formulations nitsche-P2
    python scripts/fault_reactivation3d.py --report              # tables and figures only
    python scripts/fault_reactivation3d.py --histories --levels coarse --formulations nitsche-P1
    python scripts/fault_reactivation3d.py --redo --levels fine --formulations nitsche-P2 --ranks 2

Runs ``configs/fault_reactivation3d.yaml`` (a normal fault at 2 km depth crossed by a
conjugate fault, with a joint ending on it; in-situ stress, gravity, hydrostatic pressure;
injection into the fault's centre, then shut-in) on uniform meshes (:data:`LEVELS`) and on
meshes refined around the injection point (:data:`ZONES`) with every contact
formulation, one run at a time, and records per run (appending to the CSV as it goes, so an
interrupted study keeps its finished rows):

* the fault's history per output time: area-weighted mean slip ``|[[u]]_τ|``, slipping area,
  mean aperture, and the mean fracture pressure within 30 m of the injection point;
* the cost: wall time, peak memory (resident size of the largest rank), g evaluations per
  step, contact Newton and Krylov iterations, Darcy solves and CG iterations, and the ratio
  ``total time / (steps × (one elastic solve + one Darcy solve))``. One elastic solve is the
  scene's mechanics alone with open fractures (``contact.formulation: none``, one step: the
  assembly, solver set-up and solve of its linear system, from its ``summary.json``), one
  Darcy solve the scene's flow alone (``physics: flow``, one step: assembly, set-up, solve),
  each on the same mesh and ranks with the same solver defaults, run by the command line as
  a user does. The per-iteration ratio beside it divides instead by the run's own mean cost
  of a contact Newton iteration and of a Darcy solve, both of which reuse set-ups (stale
  factorizations, the constant bulk stiffness, the lagged AMG of the Darcy solve);
* the error of the mean-slip and pressure histories (relative L² over the output times)
  against the reference run (``--reference``; by default the most accurate run there is:
  ``nitsche`` P2 on the ``local1`` mesh, refined to 1.2 m on the fractures around the
  injection point (``mesh.zones``, :data:`ZONES`), when it has run, else ``nitsche`` P2 on the
  uniform ``xfine`` mesh (1M displacement unknowns), else ``stabilized_mixed`` P1 on the fine
  mesh; ``mixed`` P2, the one formulation with exact stick, costs too much on the fine meshes
  here).

Writes docs/poromechanics/fault_reactivation3d.{csv,md,png}, the histories of the runs in
docs/poromechanics/fault_reactivation3d_history.csv (the errors and the figure are made from
it; a run folder's history is recorded there when it completes, or by any later invocation
while the folder exists) and docs/images/fault_reactivation3d.png (slip on the faults at
shut-in).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from report_common import fmt, read_csv, write_csv  # noqa: E402

from poromech.io.xdmf import read_series  # noqa: E402
from poromech.scene.loading import load_scene  # noqa: E402

DOCS = ROOT / "docs" / "poromechanics"
IMAGES = ROOT / "docs" / "images"
COMMAND = "python scripts/fault_reactivation3d.py"
SCENE = ROOT / "configs" / "fault_reactivation3d.yaml"
CSV = DOCS / "fault_reactivation3d.csv"
#: Each run's history per output time (:func:`history`), so that the errors and the figure are
#: made from the repository's files, not from the run folders under :data:`RUNS`.
HISTORY_CSV = DOCS / "fault_reactivation3d_history.csv"
HISTORY = ("time", "slip", "slip_area", "aperture", "pressure")
RUNS = ROOT / "results" / "fault_reactivation3d_study"

#: Mesh levels: (mesh.size, mesh.fracture_size) in m. ``xfine`` is the ≥ 1M-unknown level of
#: the performance target with P2 (232k tetrahedra, 1.02M P2 displacement unknowns).
LEVELS = {"coarse": (60.0, 22.0), "medium": (40.0, 15.0), "fine": (28.0, 10.0),
          "xfine": (15.0, 5.0)}
#: Locally refined levels (``mesh.zones``): the ``medium`` mesh with, around the injection
#: point, ``size`` on the fractures within 45 m and ``3 size + 2`` m in the whole ball of 60 m,
#: both growing over 40 m. The slipping patch (32 m radius at shut-in) and the pressure's
#: leak-off layer (~45 m) lie inside: ``local1`` has 12k fault faces of ~1.2 m there.
#: ``local4`` is the scene's own mesh.
ZONES = {"local4": 4.0, "local2": 2.0, "local1": 1.0}
CENTRE = (200.0, 200.0, -2000.0)
#: Line style and error-plot label of each level.
STYLES = {"coarse": ":", "medium": "--", "fine": "-", "xfine": "-.", "local4": (0, (1, 1)),
          "local2": (0, (5, 1)), "local1": (0, (3, 1, 1, 1))}
MARK = {"coarse": "c", "medium": "m", "fine": "f", "xfine": "x", "local4": "L4", "local2": "L2",
        "local1": "L1"}


def mesh_overrides(level: str) -> list[str]:
    """The ``--set`` options of a mesh level."""
    size, fsize = LEVELS.get(level, LEVELS["medium"])
    zones = "[]"  # uniform: without the scene's zones
    if level in ZONES:
        h, c = ZONES[level], list(CENTRE)
        zones = (f"[{{center: {c}, radius: 45, size: {h}, transition: 40}}, "
                 f"{{center: {c}, radius: 60, size: {3 * h + 2}, transition: 40, region: ball}}]")
    return [f"mesh.size={size}", f"mesh.fracture_size={fsize}", f"mesh.zones={zones}"]


#: Formulation and degree of each run (mixed P1 is not inf-sup stable in 3D).
VARIANTS = {
    "nitsche-P1": ("nitsche", 1),
    "mean_nitsche-P1": ("mean_nitsche", 1),
    "stabilized_mixed-P1": ("stabilized_mixed", 1),
    "nitsche-P2": ("nitsche", 2),
    "mixed-P2": ("mixed", 2),
}
#: The reference of the errors, the first of these that ran (``--reference`` overrides).
REFERENCES = ("nitsche-P2@local1", "nitsche-P2@xfine", "stabilized_mixed-P1@fine")
INJECTION_RADIUS = 30.0
RANK_MARKS = {1: "o", 2: "s", 4: "^"}  # the error-time panel: wall times on 1, 2, 4 ranks
COLUMNS = ["variant", "level", "ranks", "dofs", "flow_unknowns", "steps", "wall_s", "peak_gb",
           "g_per_step", "newton", "krylov", "smoother", "darcy_solves", "darcy_cg", "elastic_s",
           "darcy_s", "cost_ratio", "newton_s", "darcy_solve_s", "ratio_per_iteration",
           "slip_mm_at_shut_in", "slip_mm_final", "slip_error", "pressure_error", "status"]


def fault_mask(scene, points, cells):
    """Faces of the first fracture (the fault), by their centroids lying on its plane."""
    fault = scene.geometry.fractures[0]
    pts = np.asarray(fault.polygon, dtype=float)
    n = np.cross(pts[1] - pts[0], pts[2] - pts[0])
    n /= np.linalg.norm(n)
    c = points[cells].mean(axis=1)
    return np.abs((c - pts[0]) @ n) < 1e-6 * 400.0, c


def history(scene, outdir: Path) -> dict[str, np.ndarray]:
    """The fault's history per output time (see the module docstring)."""
    s = read_series(outdir, "fractures")
    x = s.points[s.cells]
    area = 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)
    on, c = fault_mask(scene, s.points, s.cells)
    near = on & (np.linalg.norm(c - [200.0, 200.0, -2000.0], axis=1) < INJECTION_RADIUS)
    a = area[on]
    out = {k: [] for k in ("slip", "slip_area", "aperture", "pressure")}
    for k in range(len(s.times)):
        f = s.fields(k)
        out["slip"].append(a @ f["jump_t"][on] / a.sum())
        out["slip_area"].append(a @ (f["state"][on] == 2) / a.sum())
        out["aperture"].append(a @ f["aperture"][on] / a.sum())
        out["pressure"].append(area[near] @ f["p_f"][near] / area[near].sum())
    return {"time": np.array(s.times), **{k: np.array(v) for k, v in out.items()}}


def _execute(cmd: list[str]) -> tuple[float, float, int]:
    """Run ``cmd``; wall time (s), peak resident size of its largest process (GB), exit code."""
    start = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - start
    proc.stderr.read()
    proc.returncode = os.waitstatus_to_exitcode(status)
    return wall, usage.ru_maxrss * 1024.0 / 1e9, proc.returncode


def _command(scene: Path, out: Path, ranks: int, overrides: list[str]) -> list[str]:
    cmd = [str(Path(sys.executable).parent / "poromech"), "run", str(scene), "-q",
           "--overwrite", "-o", str(out)]
    for o in overrides:
        cmd += ["--set", o]
    if ranks > 1:
        cmd = [str(Path(sys.executable).parent / "mpirun"), "-n", str(ranks), *cmd]
    return cmd


def run_one(variant: str, level: str, ranks: int) -> tuple[Path, dict, float, float]:
    """Run one case through the command line (as a user does); outputs, summary, wall, GB."""
    formulation, degree = VARIANTS[variant]
    out = RUNS / f"{variant}-{level}-n{ranks}"
    wall, peak, code = _execute(_command(SCENE, out, ranks, [
        f"contact.formulation={formulation}", f"degree={degree}", *mesh_overrides(level)]))
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() \
        else {"status": f"failed ({code})"}
    return out, summary, wall, peak


def unit_solves(level: str, degree: int, ranks: int) -> tuple[float, float]:
    """One elastic and one Darcy solve of the scene on ``level`` (s): see the module docstring."""
    import yaml

    raw = yaml.safe_load(SCENE.read_text())
    one_step = {"final": raw["time"]["final"] / raw["time"]["steps"], "steps": 1}
    mech = {**{k: v for k, v in raw.items() if k not in ("flow", "probes")},
            "physics": "mechanics", "contact": {"formulation": "none"}, "degree": degree,
            "time": one_step}
    flow = {**{k: v for k, v in raw.items()
               if k not in ("material", "contact", "boundary_conditions", "degree", "probes")},
            "physics": "flow", "time": one_step}
    seconds = []
    for name, data, key in (("mechanics", mech, None), ("flow", flow, "flow_solve")):
        scene = RUNS / f"unit-{name}.yaml"
        scene.parent.mkdir(parents=True, exist_ok=True)
        scene.write_text(yaml.safe_dump(data))
        out = RUNS / f"unit-{name}-{level}-P{degree}-n{ranks}"
        _execute(_command(scene, out, ranks, mesh_overrides(level)))
        summary = json.loads((out / "summary.json").read_text())
        if key is None:
            solve = summary["solves"][0]
            seconds.append(solve["time_assembly"] + solve["time_linear"])
        else:
            seconds.append(summary["wall_time"][key])
    return seconds[0], seconds[1]


def costs(summary: dict, units: tuple[float, float]) -> dict:
    """Per-run cost figures from the summary and the unit solves."""
    c = summary["coupling"]
    steps = summary["completed_steps"]
    newton = c["mechanics_seconds"] / max(c["newton_iterations"], 1)
    darcy = c["darcy_seconds"] / max(c["darcy_solves"], 1)
    total = summary["wall_time"]["total"]
    return {"dofs": summary["dofs"], "flow_unknowns": summary["flow_unknowns"], "steps": steps,
            "g_per_step": c["g_evaluations"] / steps, "newton": c["newton_iterations"],
            "krylov": summary["linear_solver"].get("krylov_iterations", 0),
            "smoother": summary["linear_solver"].get("level_smoother", "-"),
            "darcy_solves": c["darcy_solves"], "darcy_cg": c["darcy_iterations"],
            "elastic_s": units[0], "darcy_s": units[1],
            "cost_ratio": total / (steps * (units[0] + units[1])),
            "newton_s": newton, "darcy_solve_s": darcy,
            "ratio_per_iteration": total / (steps * (newton + darcy))}


def relative_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def study(levels, variants, ranks: int, scene, redo: bool = False) -> None:
    """Run each level × variant on ``ranks`` that has no row yet (``redo``: all, replacing)."""
    done = set() if redo else {(r["variant"], r["level"], int(r["ranks"])) for r in read_rows()}
    units: dict[tuple, tuple[float, float]] = {}
    for level in levels:
        for variant in variants:
            if (variant, level, ranks) in done:
                continue
            out, summary, wall, peak = run_one(variant, level, ranks)
            row = {"variant": variant, "level": level, "ranks": ranks, "wall_s": wall,
                   "peak_gb": peak, "status": summary["status"]}
            if summary["status"] == "converged":
                degree = VARIANTS[variant][1]
                if (level, degree, ranks) not in units:
                    units[level, degree, ranks] = unit_solves(level, degree, ranks)
                row.update(costs(summary, units[level, degree, ranks]))
                h = keep_history(scene, out, (variant, level, ranks))
                t_in = float(scene.parameters["T_inj"])
                row["slip_mm_at_shut_in"] = 1e3 * np.interp(t_in, h["time"], h["slip"])
                row["slip_mm_final"] = 1e3 * h["slip"][-1]
            put_row(row)
            print(f"{variant} {level} n{ranks}: {summary['status']}, {wall:.0f} s", flush=True)


def fill_histories(levels, variants, ranks: int, scene) -> None:
    """Record the history of the table's converged runs that have none, keeping their rows.

    Each such run is made again, untimed (its row's wall time, memory and counts were measured
    when it was added, perhaps on another machine), and the history is recorded only if the
    run repeats the row's g evaluations and Newton iterations: the same computation.
    """
    recorded = histories()
    for row in read_rows():
        key = (row["variant"], row["level"], int(row["ranks"]))
        if (key in recorded or row["status"] != "converged" or row["level"] not in levels
                or row["variant"] not in variants or key[2] != ranks):
            continue
        out, summary, wall, _ = run_one(*key)
        ran = summary["status"] == "converged"
        counts = (round(summary["coupling"]["g_evaluations"] / summary["completed_steps"], 6),
                  summary["coupling"]["newton_iterations"]) if ran else None
        same = counts == (round(float(row["g_per_step"]), 6), int(float(row["newton"])))
        print(f"{key[0]} {key[1]} n{ranks}: {summary['status']}, {wall:.0f} s, g/step and Newton "
              f"{counts} against the row's ({row['g_per_step']}, {row['newton']})"
              f"{'' if same else ': history not recorded'}", flush=True)
        if same:
            keep_history(scene, out, key)


def keep_history(scene, out: Path, key: tuple[str, str, int]) -> dict[str, np.ndarray]:
    """The history of the run in ``out``, kept beside it and recorded in :data:`HISTORY_CSV`."""
    h = history(scene, out)
    np.savez(out / "history.npz", **h)
    record_history(*key, h)
    return h


def read_rows() -> list[dict]:
    return read_csv(CSV, text=("variant", "level", "smoother", "status"))[1]


def put_row(row: dict) -> None:
    """Add ``row`` to the CSV, in place of the row of the same run if there is one."""
    new = {k: row.get(k, "") for k in COLUMNS}
    key = (row["variant"], row["level"], int(row["ranks"]))
    rows = read_rows()
    at = next((i for i, r in enumerate(rows)
               if (r["variant"], r["level"], int(r["ranks"])) == key), len(rows))
    rows[at:at + 1] = [new]
    save_rows(rows, datetime.date.today().isoformat())


def save_rows(rows: list[dict], day: str | None = None) -> None:
    """Write the CSV; its comment names the day of the newest run (kept unless ``day``)."""
    write_csv(CSV, [f"generated by {COMMAND}; last run on {day or last_run()}"], COLUMNS, rows)


def last_run() -> str:
    """The day of the CSV's newest run (its comment line), else today."""
    comments = read_csv(CSV)[0]
    found = [c.rpartition("last run on ")[2] for c in comments if "last run on " in c]
    return found[0] if found else datetime.date.today().isoformat()


def record_history(variant: str, level: str, ranks: int, h: dict[str, np.ndarray]) -> None:
    """Replace the rows of one run in :data:`HISTORY_CSV` by its history ``h``."""
    key = {"variant": variant, "level": level, "ranks": ranks}
    rows = [r for r in read_csv(HISTORY_CSV, text=("variant", "level"))[1]
            if (r["variant"], r["level"], r["ranks"]) != (variant, level, ranks)]
    rows += [{**key, **{k: h[k][i] for k in HISTORY}} for i in range(len(h["time"]))]
    write_csv(HISTORY_CSV, [f"generated by {COMMAND}"], [*key, *HISTORY], rows)


def histories() -> dict[tuple[str, str, int], dict[str, np.ndarray]]:
    """The recorded histories by (variant, level, ranks)."""
    out: dict[tuple[str, str, int], dict[str, list]] = {}
    for r in read_csv(HISTORY_CSV, text=("variant", "level"))[1]:
        h = out.setdefault((r["variant"], r["level"], int(r["ranks"])), {k: [] for k in HISTORY})
        for k in HISTORY:
            h[k].append(r[k])
    return {key: {k: np.array(v) for k, v in h.items()} for key, h in out.items()}


def reference_key(reference: str, recorded: dict) -> tuple[str, str, int] | None:
    """The run of ``variant@level`` in ``recorded`` (:func:`histories`; the fewest ranks)."""
    variant, level = reference.split("@")
    ranks = sorted(k[2] for k in recorded if k[:2] == (variant, level))
    return (variant, level, ranks[0]) if ranks else None


def reference_run(reference: str) -> Path:
    """The output folder of ``variant@level`` (1 rank, else the fewest ranks that ran it)."""
    variant, level = reference.split("@")
    runs = sorted(RUNS.glob(f"{variant}-{level}-n*"), key=lambda p: int(p.name.rsplit("n", 1)[1]))
    return runs[0] if runs else RUNS / f"{variant}-{level}-n1"


def errors(reference: str) -> list[dict]:
    """Fill the error columns of the runs with a recorded history against the reference's."""
    rows = read_rows()
    recorded = histories()
    key = reference_key(reference, recorded)
    if key is None:
        return rows
    r = recorded[key]
    for row in rows:
        h = recorded.get((row["variant"], row["level"], int(row["ranks"])))
        if row["status"] != "converged" or h is None or len(h["time"]) != len(r["time"]):
            continue
        row["slip_error"] = relative_l2(h["slip"], r["slip"])
        row["pressure_error"] = relative_l2(h["pressure"] - r["pressure"][0],
                                            r["pressure"] - r["pressure"][0])
    save_rows(rows)
    return rows


def report(rows: list[dict], reference: str, scene) -> None:
    """The Markdown table and the figures."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    head = ["variant", "level", "ranks", "dofs", "flow unknowns", "wall s", "peak GB", "g/step",
            "Newton", "Krylov", "smoother", "Darcy CG", "elastic s", "Darcy s", "cost ratio",
            "ratio per iteration", "slip at shut-in mm", "final slip mm", "slip error",
            "Δp error", "status"]
    keys = ["variant", "level", "ranks", "dofs", "flow_unknowns", "wall_s", "peak_gb",
            "g_per_step", "newton", "krylov", "smoother", "darcy_cg", "elastic_s", "darcy_s",
            "cost_ratio", "ratio_per_iteration", "slip_mm_at_shut_in", "slip_mm_final",
            "slip_error", "pressure_error", "status"]
    lines = ["# 3D fault reactivation: error against run time\n",
             f"Generated by `{COMMAND}` from runs up to {last_run()} "
             f"(reference: {reference.replace('@', ' on the ')} mesh). Levels coarse, medium, "
             "fine and xfine are uniform meshes (22, 15, 10 and 5 m on the fractures, without the "
             "scene's zones); local4, local2 and local1 are the medium mesh refined around the "
             "injection point with mesh.zones (4, 2 and 1 m on the fractures; local4 is the "
             "scene's own mesh). Errors are relative L² "
             "over the output times of the fault's mean slip and of the overpressure at the "
             "injection point. Peak GB: resident size of the largest rank. Krylov: the "
             "mechanics' iterations (0 with a factorization); smoother: GAMG's level smoother "
             "chosen by the run (blank: rows run before the choice, with SOR where GAMG ran; -: a "
             "factorization, CG, or the p-multigrid of P2 contact). The cost ratio is total time / "
             "(steps × (one elastic solve + one Darcy solve)), where the elastic and Darcy "
             "solves are the scene's mechanics (fractures open) and flow alone, one step each, "
             "from the command line (columns elastic s and Darcy s); the ratio per iteration "
             "divides by the run's mean cost of a contact Newton iteration and of a Darcy "
             "solve instead, which reuse set-ups.\n",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        lines.append("| " + " | ".join(fmt(row.get(k, "")) for k in keys) + " |")
    (DOCS / "fault_reactivation3d.md").write_text("\n".join(lines) + "\n")

    fig, ax = plt.subplots(2, 2, figsize=(11, 7))
    ax = ax.ravel()
    single = {(r["variant"], r["level"]) for r in rows if r["ranks"] == 1}
    recorded, plotted = histories(), set()
    for row in rows:  # one curve per variant and level (1 rank where it ran)
        if row["ranks"] != 1 and (row["variant"], row["level"]) in single:
            continue
        color = f"C{list(VARIANTS).index(row['variant'])}"  # colour: variant; style: level
        # (a run that equals the reference to round-off has no point on the log axis)
        if row.get("slip_error") not in ("", None) and float(row["slip_error"]) > 1e-8:
            plotted.add(int(row["ranks"]))
            ax[3].loglog(float(row["wall_s"]), float(row["slip_error"]),
                         RANK_MARKS.get(int(row["ranks"]), "*"), color=color)
            ax[3].annotate(MARK[row["level"]], (float(row["wall_s"]), float(row["slip_error"])))
        h = recorded.get((row["variant"], row["level"], int(row["ranks"])))
        if h is None:
            continue
        style = STYLES[row["level"]]
        label = f"{row['variant']} {row['level']}" + (f" ({row['ranks']} ranks)"
                                                      if row["ranks"] != 1 else "")
        ax[0].plot(h["time"] / 3600, 1e3 * h["slip"], ls=style, color=color, label=label)
        ax[1].plot(h["time"] / 3600, 1e6 * h["aperture"], ls=style, color=color)
        ax[2].plot(h["time"] / 3600, (h["pressure"] - h["pressure"][0]) / 1e6, ls=style,
                   color=color)
    ax[0].set(xlabel="time (h)", ylabel="mean slip on the fault (mm)")
    ax[1].set(xlabel="time (h)", ylabel="mean aperture of the fault (µm)")
    ax[2].set(xlabel="time (h)", ylabel="overpressure at injection (MPa)")
    ax[3].set(xlabel="wall time (s; marker: MPI ranks)", ylabel="mean-slip error")
    ax[3].xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax[0].legend(fontsize=5.5, ncol=2, loc="upper left")  # the slip is 0 there until ~3 h
    shown = [v for v in VARIANTS if any(r["variant"] == v and r.get("slip_error") not in ("", None)
                                        for r in rows)]
    ranks = sorted(plotted)
    ax[3].legend([plt.Line2D([], [], marker="o", ls="", color=f"C{list(VARIANTS).index(v)}")
                  for v in shown] + [plt.Line2D([], [], marker=RANK_MARKS.get(n, "*"), ls="",
                                                color="k") for n in ranks],
                 shown + [f"{n} rank{'s' if n > 1 else ''}" for n in ranks], fontsize=6,
                 title="letters: mesh level", title_fontsize=6)
    for a in ax:
        a.grid(True, alpha=0.3)
    fig.tight_layout()
    fig.savefig(DOCS / "fault_reactivation3d.png", dpi=90)


def picture(outdir: Path, scene) -> None:
    """Slip on the fault at shut-in, seen from above its hanging wall; the other fractures grey."""
    import pyvista as pv

    pv.OFF_SCREEN = True
    s = read_series(outdir, "fractures")
    k = int(np.argmin(np.abs(np.array(s.times) - float(scene.parameters["T_inj"]))))
    on, _ = fault_mask(scene, s.points, s.cells)
    slip = 1e3 * s.fields(k)["jump_t"]
    p = pv.Plotter(off_screen=True, window_size=(900, 700))
    for mask, opaque in ((on, True), (~on, False)):
        cells = np.hstack([np.full((int(mask.sum()), 1), 3), s.cells[mask]]).ravel()
        grid = pv.PolyData(s.points, cells)
        if opaque:
            grid.cell_data["slip (mm)"] = slip[mask]
            p.add_mesh(grid, scalars="slip (mm)", cmap="inferno",
                       show_edges=bool(mask.sum() < 4000),  # edges hide a fine mesh's colours
                       edge_color="#555555", line_width=0.3)
        else:
            p.add_mesh(grid, color="lightgrey", opacity=0.35)
    p.add_mesh(pv.Box(bounds=(0, 400, 0, 400, -2200, -1800)), style="wireframe", color="gray")
    p.view_vector((-0.8, -0.45, 0.6))
    p.add_text(f"fault slip at shut-in (t = {s.times[k]:.0f} s); conjugate fault and joint grey",
               font_size=9)
    IMAGES.mkdir(parents=True, exist_ok=True)
    p.screenshot(str(IMAGES / "fault_reactivation3d.png"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--levels", nargs="+", default=["coarse", "medium", "fine"],
                    choices=[*LEVELS, *ZONES])
    ap.add_argument("--formulations", nargs="+", choices=list(VARIANTS),
                    default=["nitsche-P1", "stabilized_mixed-P1", "mean_nitsche-P1"])
    ap.add_argument("--ranks", type=int, default=1)
    ap.add_argument("--reference", default=None,
                    help=f"variant@level (default: the first of {', '.join(REFERENCES)} that ran)")
    ap.add_argument("--report", action="store_true", help="only the tables and figures")
    ap.add_argument("--redo", action="store_true",
                    help="run the selected runs again even if the table has them, replacing "
                         "their rows and histories")
    ap.add_argument("--histories", action="store_true",
                    help="run again, untimed, the selected runs of the table that have no "
                         "recorded history, and record it (their rows are kept)")
    args = ap.parse_args()
    DOCS.mkdir(parents=True, exist_ok=True)
    scene = load_scene(SCENE)
    if args.histories:
        fill_histories(args.levels, args.formulations, args.ranks, scene)
    elif not args.report:
        study(args.levels, args.formulations, args.ranks, scene, redo=args.redo)
    recorded = histories()
    for row in read_rows():  # run folders of this machine not yet recorded
        key = (row["variant"], row["level"], int(row["ranks"]))
        path = RUNS / "{}-{}-n{}".format(*key) / "history.npz"
        if path.exists() and key not in recorded:
            record_history(*key, dict(np.load(path)))
            recorded = histories()
    if args.reference is None:
        ran = [r for r in REFERENCES if reference_key(r, recorded) is not None]
        args.reference = ran[0] if ran else REFERENCES[-1]
    rows = errors(args.reference)
    report(rows, args.reference, scene)
    best = reference_run(args.reference)
    summary = best / "summary.json"
    if summary.exists() and json.loads(summary.read_text())["status"] == "converged":
        picture(best, scene)
    else:  # a run folder without a finished run (none, or interrupted): the picture is kept
        print(f"{best}: no converged run there, docs/images/fault_reactivation3d.png not redrawn")


if __name__ == "__main__":
    main()
