"""The 3D fault-reactivation scene: history, error against run time, and the cost ratios.

    python scripts/fault_reactivation3d.py            # three levels, nitsche and stabilized_mixed
    python scripts/fault_reactivation3d.py --levels coarse medium --formulations nitsche
    python scripts/fault_reactivation3d.py --report              # tables and figures only

Runs ``configs/fault_reactivation3d.yaml`` (a normal fault at 2 km depth crossed by a
conjugate fault, with a joint ending on it; in-situ stress, gravity, hydrostatic pressure;
injection into the fault's centre, then shut-in) on three meshes with every contact
formulation, one run at a time, and records per run (appending to the CSV as it goes, so an
interrupted study keeps its finished rows):

* the fault's history per output time: area-weighted mean slip ``|[[u]]_τ|``, slipping area,
  mean aperture, and the mean fracture pressure within 30 m of the injection point;
* the cost: wall time, g evaluations per step, contact Newton iterations, Darcy solves, and
  the ratio ``total time / (steps × (one elastic solve + one Darcy solve))``, where one elastic
  solve is the mean cost of a contact Newton iteration (assembly and linear solve) and one
  Darcy solve the mean cost of a Darcy solve of the run;
* the error of the mean-slip and pressure histories (relative L² over the output times)
  against the reference run (``--reference``, by default the finest ``stabilized_mixed`` P1
  run; ``mixed`` P2, the one formulation with exact stick, costs too much on the fine mesh
  here; ``mean_nitsche`` gives the jumps of ``stabilized_mixed`` to round-off, as on every
  3D scene measured, and is left out by default).

Writes docs/poromechanics/fault_reactivation3d.{csv,md,png} and
docs/images/fault_reactivation3d.png (slip on the faults at shut-in).
"""

from __future__ import annotations

import argparse
import datetime
import json
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
RUNS = ROOT / "results" / "fault_reactivation3d_study"

#: Mesh levels: (mesh.size, mesh.fracture_size) in m.
LEVELS = {"coarse": (60.0, 22.0), "medium": (40.0, 15.0), "fine": (28.0, 10.0)}
#: Formulation and degree of each run (mixed P1 is not inf-sup stable in 3D).
VARIANTS = {
    "nitsche-P1": ("nitsche", 1),
    "mean_nitsche-P1": ("mean_nitsche", 1),
    "stabilized_mixed-P1": ("stabilized_mixed", 1),
    "mixed-P2": ("mixed", 2),
}
INJECTION_RADIUS = 30.0
COLUMNS = ["variant", "level", "ranks", "dofs", "flow_unknowns", "steps", "wall_s",
           "g_per_step", "newton", "darcy_solves", "elastic_s", "darcy_s", "cost_ratio",
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


def run_one(variant: str, level: str, ranks: int) -> tuple[Path, dict, float]:
    """Run one case through the command line (as a user does); its outputs and summary."""
    formulation, degree = VARIANTS[variant]
    size, fsize = LEVELS[level]
    out = RUNS / f"{variant}-{level}-n{ranks}"
    cmd = [str(Path(sys.executable).parent / "poromech"), "run", str(SCENE), "-q",
           "--overwrite", "-o", str(out),
           "--set", f"contact.formulation={formulation}", "--set", f"degree={degree}",
           "--set", f"mesh.size={size}", "--set", f"mesh.fracture_size={fsize}"]
    if ranks > 1:
        cmd = [str(Path(sys.executable).parent / "mpirun"), "-n", str(ranks), *cmd]
    start = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - start
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() \
        else {"status": f"failed ({proc.returncode})"}
    return out, summary, wall


def costs(summary: dict) -> dict:
    """Per-run cost figures from the summary."""
    c = summary["coupling"]
    steps = summary["completed_steps"]
    elastic = c["mechanics_seconds"] / max(c["newton_iterations"], 1)
    darcy = c["darcy_seconds"] / max(c["darcy_solves"], 1)
    total = summary["wall_time"]["total"]
    return {"dofs": summary["dofs"], "flow_unknowns": summary["flow_unknowns"], "steps": steps,
            "g_per_step": c["g_evaluations"] / steps, "newton": c["newton_iterations"],
            "darcy_solves": c["darcy_solves"], "elastic_s": elastic, "darcy_s": darcy,
            "cost_ratio": total / (steps * (elastic + darcy))}


def relative_l2(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def study(levels, variants, ranks: int, scene) -> None:
    done = {(r["variant"], r["level"], int(r["ranks"])) for r in read_rows()}
    for level in levels:
        for variant in variants:
            if (variant, level, ranks) in done:
                continue
            out, summary, wall = run_one(variant, level, ranks)
            row = {"variant": variant, "level": level, "ranks": ranks, "wall_s": wall,
                   "status": summary["status"]}
            if summary["status"] == "converged":
                row.update(costs(summary))
                h = history(scene, out)
                np.savez(out / "history.npz", **h)
                t_in = float(scene.parameters["T_inj"])
                row["slip_mm_at_shut_in"] = 1e3 * np.interp(t_in, h["time"], h["slip"])
                row["slip_mm_final"] = 1e3 * h["slip"][-1]
            append_row(row)
            print(f"{variant} {level} n{ranks}: {summary['status']}, {wall:.0f} s", flush=True)


def read_rows() -> list[dict]:
    return read_csv(CSV, text=("variant", "level", "status"))[1]


def append_row(row: dict) -> None:
    rows = read_rows()
    rows.append({k: row.get(k, "") for k in COLUMNS})
    write_csv(CSV, [f"generated by {COMMAND}"], COLUMNS, rows)


def errors(reference: str) -> list[dict]:
    """Fill the error columns against the reference run's history."""
    rows = read_rows()
    ref_variant, ref_level = reference.split("@")
    ref = RUNS / f"{ref_variant}-{ref_level}-n1" / "history.npz"
    if not ref.exists():
        return rows
    r = np.load(ref)
    for row in rows:
        path = RUNS / f"{row['variant']}-{row['level']}-n{row['ranks']}" / "history.npz"
        if row["status"] != "converged" or not path.exists():
            continue
        h = np.load(path)
        if len(h["time"]) != len(r["time"]):
            continue
        row["slip_error"] = relative_l2(h["slip"], r["slip"])
        row["pressure_error"] = relative_l2(h["pressure"] - r["pressure"][0],
                                            r["pressure"] - r["pressure"][0])
    write_csv(CSV, [f"generated by {COMMAND}"], COLUMNS, rows)
    return rows


def report(rows: list[dict], reference: str, scene) -> None:
    """The Markdown table and the figures."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    head = ["variant", "level", "ranks", "dofs", "flow unknowns", "wall s", "g/step",
            "Newton", "elastic s", "Darcy s", "cost ratio", "slip at shut-in mm",
            "final slip mm", "slip error", "Δp error", "status"]
    keys = ["variant", "level", "ranks", "dofs", "flow_unknowns", "wall_s", "g_per_step",
            "newton", "elastic_s", "darcy_s", "cost_ratio", "slip_mm_at_shut_in",
            "slip_mm_final", "slip_error", "pressure_error", "status"]
    lines = ["# 3D fault reactivation: error against run time\n",
             f"Generated by `{COMMAND}` on {datetime.date.today().isoformat()} "
             f"(reference: {reference.replace('@', ' on the ')} mesh). Errors are relative L² "
             "over the output times of the fault's mean slip and of the overpressure at the "
             "injection point. The cost ratio is total time / (steps × (one elastic solve + "
             "one Darcy solve)).\n",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for row in rows:
        lines.append("| " + " | ".join(fmt(row.get(k, "")) for k in keys) + " |")
    (DOCS / "fault_reactivation3d.md").write_text("\n".join(lines) + "\n")

    fig, ax = plt.subplots(1, 3, figsize=(13, 3.8))
    for row in rows:
        path = RUNS / f"{row['variant']}-{row['level']}-n{row['ranks']}" / "history.npz"
        if row["ranks"] != 1 or not path.exists():
            continue
        h = np.load(path)
        style = {"coarse": ":", "medium": "--", "fine": "-"}[row["level"]]
        label = f"{row['variant']} {row['level']}"
        ax[0].plot(h["time"] / 3600, 1e3 * h["slip"], style, label=label)
        ax[1].plot(h["time"] / 3600, (h["pressure"] - h["pressure"][0]) / 1e6, style)
        if row.get("slip_error") not in ("", None):
            ax[2].loglog(float(row["wall_s"]), float(row["slip_error"]), "o",
                         color=ax[0].lines[-1].get_color())
            ax[2].annotate(row["level"][0], (float(row["wall_s"]), float(row["slip_error"])))
    ax[0].set(xlabel="time (h)", ylabel="mean slip on the fault (mm)")
    ax[1].set(xlabel="time (h)", ylabel="overpressure at injection (MPa)")
    ax[2].set(xlabel="wall time (s)", ylabel="mean-slip error")
    ax[0].legend(fontsize=6)
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
            p.add_mesh(grid, scalars="slip (mm)", cmap="inferno", show_edges=True,
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
    ap.add_argument("--levels", nargs="+", default=list(LEVELS), choices=list(LEVELS))
    ap.add_argument("--formulations", nargs="+", choices=list(VARIANTS),
                    default=["nitsche-P1", "stabilized_mixed-P1"])
    ap.add_argument("--ranks", type=int, default=1)
    ap.add_argument("--reference", default="stabilized_mixed-P1@fine")
    ap.add_argument("--report", action="store_true", help="only the tables and figures")
    args = ap.parse_args()
    DOCS.mkdir(parents=True, exist_ok=True)
    scene = load_scene(SCENE)
    if not args.report:
        study(args.levels, args.formulations, args.ranks, scene)
    rows = errors(args.reference)
    report(rows, args.reference, scene)
    best = RUNS / f"{args.reference.split('@')[0]}-{args.reference.split('@')[1]}-n1"
    if (best / "fractures.xdmf").exists():
        picture(best, scene)


if __name__ == "__main__":
    main()
