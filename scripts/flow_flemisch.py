"""Flemisch et al. (2018) benchmarks 1 (Hydrocoin) and 2 (regular network, conductive).

Runs ``configs/flemisch_case1.yaml`` and ``configs/flemisch_case2.yaml`` on refinement levels
``--levels`` (serial), samples the reference lines with the scenes' probes and compares with the
published reference curves (``--reference``: the folder with the three ``case*.csv`` files of
``data/fracture_flow_2d``). Writes ``docs/flow/flemisch.csv``, ``flemisch.md`` and one PNG per
case.

    python scripts/flow_flemisch.py
"""

from __future__ import annotations

import argparse
import os
import tempfile
from pathlib import Path

import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

import matplotlib
import numpy as np
from flow_common import (
    DOCS,
    ROOT,
    generated,
    line_differences,
    markdown_table,
    read_csv,
    save_figure,
)
from flow_common import write_csv as write_table
from mpi4py import MPI

from poromech.run import run_scene
from poromech.scene.loading import load_scene

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

COMMAND = "python scripts/flow_flemisch.py"

#: (case, probe, reference file, compared field)
LINES = [
    (1, "y_-200", "case1_hydrocoin_y_eq_-200.csv", "p_m"),
    (2, "x_0.5", "case2_conductive_x_eq_0.5.csv", "p_f"),
    (2, "y_0.7", "case2_conductive_y_eq_0.7.csv", "p_m"),
]

#: Sensitivity variant "1b": the fracture ends on the top get the head averaged over the
#: zone's footprint on the wavy top (slope 1/8; half footprints 5 m for A and 7.5 m for B)
#: instead of the head at the end point, as an equi-dimensional zone of that width sees it.
ZONE_AVERAGED_TOP = ("flow.boundary_conditions.0.pressure="
                     "'where(abs(x - 400) < 1e-6, 100 + 2.5/8, "
                     "where(abs(x - 1200) < 1e-6, 100 + 3.75/8, y))'")


def zone_mask(scene, x: np.ndarray, y: float) -> np.ndarray:
    """False on the footprint of the Hydrocoin fracture zones (their width) on y = const."""
    keep = np.ones_like(x, dtype=bool)
    widths = {ff.fracture: ff.aperture.value() for ff in scene.flow.fractures}
    for fr in scene.geometry.fractures:
        a, b = np.array(fr.points[0]), np.array(fr.points[-1])
        t = (b - a) / np.linalg.norm(b - a)
        xc = a[0] + (y - a[1]) * (b[0] - a[0]) / (b[1] - a[1])
        half = 0.5 * widths[fr.name] / abs(t[1])  # strip width over |n_x| = |t_y|
        keep &= np.abs(x - xc) > half
    return keep


def run_case(case, level: int, work: Path) -> tuple[dict, object]:
    overrides = [f"mesh.refinement={level}", "output.xdmf=false"]
    if case == "1b":
        overrides.append(ZONE_AVERAGED_TOP)
    scene = load_scene(ROOT / "configs" / f"flemisch_case{str(case)[0]}.yaml", overrides)
    out = work / f"case{case}_m{level}"
    summary = run_scene(scene, out, MPI.COMM_WORLD)
    return summary, scene


def compare(case, level, summary, scene, reference: Path, work: Path, curves) -> list[list]:
    rows = []
    for c, probe, ref_name, field in LINES:
        if str(c) != str(case)[0]:
            continue
        hr, ref = read_csv(reference / ref_name)
        h, data = read_csv(work / f"case{case}_m{level}" / f"probe_{probe}.csv")
        s_ref, p_ref = ref[:, hr.index("arc_length")], ref[:, 0]
        s, p = data[:, h.index("arc_length")], data[:, h.index(field)]
        d = line_differences(s_ref, p_ref, s, p)
        extra = ""
        if c == 1:
            keep = zone_mask(scene, ref[:, hr.index("Points:0")], -200.0)
            extra = line_differences(s_ref, p_ref, s, p, keep)["range"]
        solve = summary["flow"]["solves"][0]
        balance = summary["flow"]["conservation"]["relative_residual"]
        rows.append([case, probe, field, level, summary["mesh"]["cells"],
                     summary["flow"]["unknowns"]["total"], solve["iterations"],
                     round(solve["seconds"], 3), balance, d["rel"], d["range"], extra])
        curves.setdefault((case, probe), {"ref": (s_ref, p_ref)})[level] = (s, p)
    return rows


def plot(curves, field_of) -> None:
    """Profiles against the reference (top) and differences to it (bottom), per line."""
    for case in (1, 2):
        keys = [k for k in curves if str(k[0])[0] == str(case)]
        lines = sorted({k[1] for k in keys})
        fig, axes = plt.subplots(2, len(lines), figsize=(6.0 * len(lines), 6.5), squeeze=False,
                                 sharex="col", gridspec_kw={"height_ratios": [2, 1]})
        for col, line in enumerate(lines):
            top, bottom = axes[0, col], axes[1, col]
            for key in [k for k in keys if k[1] == line]:
                data = dict(curves[key])
                s_ref, p_ref = data.pop("ref")
                if key[0] == case:
                    top.plot(s_ref, p_ref, "k-", lw=2.5, label="reference (Flemisch et al. 2018)")
                style = "-" if key[0] == case else "--"
                for level, (s, p) in sorted(data.items()):
                    label = f"HFV, refinement {level}" + ("" if key[0] == case else f" ({key[0]})")
                    ok = np.isfinite(p)
                    if key[0] == case:
                        top.plot(s, p, style, lw=1.0, label=label)
                    bottom.plot(s_ref, np.interp(s_ref, s[ok], p[ok]) - p_ref, style, lw=1.0,
                                label=label)
            top.set_ylabel("head (m)" if case == 1 else "pressure")
            top.set_title(f"case {case}, line {line} ({field_of[(case, line)]})")
            bottom.set_xlabel("arc length (m)")
            bottom.set_ylabel("HFV - reference")
            for ax in (top, bottom):
                ax.grid(alpha=0.3)
                ax.legend(fontsize=7)
        save_figure(fig, DOCS / f"flemisch_case{case}.png")
        plt.close(fig)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--reference", default=os.environ.get("POROMECH_FLOW_REFERENCE",
                                                         str(ROOT / "data" / "fracture_flow_2d")),
                   help="folder with the reference CSV files (default: data/fracture_flow_2d)")
    p.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    p.add_argument("--plot-levels", type=int, nargs="+", default=[0, 2, 4],
                   help="refinement levels drawn in the figures")
    args = p.parse_args()
    if not args.reference:
        p.error("--reference is required (folder of the Flemisch et al. reference curves)")
    reference = Path(args.reference)
    DOCS.mkdir(parents=True, exist_ok=True)
    rows, curves = [], {}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        for case in (1, "1b", 2):
            for level in args.levels:
                summary, scene = run_case(case, level, work)
                drawn = curves if level in args.plot_levels else {}
                rows += compare(case, level, summary, scene, reference, work, drawn)
                print(rows[-1], flush=True)
    header = ["case", "line", "field", "refinement", "cells", "unknowns", "iterations",
              "solve_s", "mass_balance_rel", "rel_l2", "range_l2", "range_l2_outside_zones"]
    write_table(DOCS / "flemisch.csv", header, rows)
    text = (generated(COMMAND, MPI.COMM_WORLD.size) + ". rel_l2 = "
            "‖p - p_ref‖/‖p_ref‖ and range_l2 = ‖p - p_ref‖/(|line|^½ (max p_ref - min p_ref)) "
            "in L² along the line; case 1b = case 1 with the zone-averaged head at the "
            "fracture tops.\n\n")
    (DOCS / "flemisch.md").write_text(text + markdown_table(header, rows))
    plot(curves, {(c, pr): f for c, pr, _, f in LINES})


if __name__ == "__main__":
    main()
