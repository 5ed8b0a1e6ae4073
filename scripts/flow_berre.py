"""Berre et al. (2021) 3D benchmark, case 1 (single fracture) and case 2 (regular network).

Runs ``configs/berre_case1.yaml``, ``berre_case2_conductive.yaml`` and
``berre_case2_blocking.yaml`` on the refinement levels ``--levels`` (serial; each level has 8
times the cells of the one before), samples the benchmark's line with the scenes' probe and
compares the matrix head with the benchmark's reference (USTUTT-MPFA at its finest mesh). The
published curves of the other methods in the data folder (the HFV scheme UNICE_UNIGE-HFV_Disc at
the benchmark's coarse meshes) are compared the same way, so the table shows where poromech lies
among them at comparable cell counts. ``--reference``: the folder of the benchmark's data
(default ``../shared/data/fracture_flow_3d`` beside the repository). Writes
``docs/flow/berre.csv``, ``berre.md`` and ``berre_case1.png``, ``berre_case2.png``.

``--participants DATA``: also every participating method of the benchmark, from the ``data``
folder of a clone of its results repository (the benchmark's own,
git.iws.uni-stuttgart.de/benchmarks/fracture-flow-3d, or its public mirror
github.com/gridfunction/fracturedPorousMedia; ``DATA/single/results/<group>/<method>/`` and
``DATA/regular/results/...``): their misfits, computed the same way, are written to
``docs/flow/berre_participants.csv`` (derived numbers only, no copy of their data), which later
runs without ``--participants`` read back. Each poromech row is then placed in the participants'
spread at its own cell count: each method's misfit interpolated log-log between its refinements
(``berre_spread.png``, the spread table of ``berre.md``).

``--sizes f ...``: also a fresh gmsh mesh of each case at ``f`` times its scene's mesh size
(``mesh.size`` and ``mesh.fracture_size``, no refinement), rows ``size ×f``: whether a mesh made
at the published mesh's cell count does better than a uniformly refined coarse one.

``--graded f ...``: also a fresh mesh at ``f`` times the scene's sizes, graded to
``GRADED_ZONE_SIZE`` times that size in balls along the edge of the Dirichlet patch where the
head is singular (``Case.zone_centers``, ``mesh.zones``), rows ``graded ×f``: the misfit along
the line is set there (docs/flow3d.md, "Results").

    python scripts/flow_berre.py                 # levels 0-3: 1k to 630k cells, ~3 min
    python scripts/flow_berre.py --sizes 0.4 0.35 --cases case1   # fresh meshes of case 1
    python scripts/flow_berre.py --levels 0 1    # a quick look
    python scripts/flow_berre.py --levels        # the published curves only
    # the study of docs/flow3d.md (D: the data folder of a clone of the results repository):
    python scripts/flow_berre.py --sizes 0.5 0.4 0.25 --graded 1 0.5 0.25 --participants D
"""

from __future__ import annotations

import argparse
import csv
import os
import re
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

import matplotlib
import numpy as np
from flow_common import DOCS, ROOT, generated, markdown_table, save_figure, write_csv
from mpi4py import MPI

from poromech.io.probes import line_differences, read_csv, read_number_table

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

#: The benchmark's data, beside the repository (``../shared`` in CI).
DEFAULT_REFERENCE = ROOT.parent / "shared" / "data" / "fracture_flow_3d"

#: The reference solution of every case: this method at its finest refinement.
REFERENCE_METHOD = "USTUTT_MPFA"

#: Published method names as the figures and tables show them.
LABELS = {"UNICE_UNIGE_HFV_Disc": "UNICE_UNIGE-HFV_Disc", "USTUTT_MPFA": "USTUTT-MPFA"}

#: Columns of a benchmark ``*_results*.csv`` row (Berre et al. 2021, the data repository).
RESULT_COLUMNS = ("cells_0d", "cells_1d", "cells_2d", "cells_3d", "unknowns", "nonzeros")


@dataclass(frozen=True)
class Case:
    """One scene of the study and its benchmark data.

    Attributes:
        name: Key of ``--cases`` and of the rows.
        scene: Scene file name in ``configs/``.
        prefix: Prefix of its data files (``single``, ``regular``).
        cond: ``cond_<k>`` part of the case-2 file names (None for case 1).
        reference_refinement: Refinement of the reference method's curve.
        figure: PNG the case is drawn in (one per benchmark case).
        title: Panel title.
        zone_centers: Balls of ``--graded`` meshes, along the edge of the Dirichlet patch (the
            head's singularity: case 1 the inflow patch's edge x = 0, z = 90; case 2 the
            outflow corner).
        zone_radius: Their radius.
    """

    name: str
    scene: str
    prefix: str
    cond: int | None
    reference_refinement: int
    figure: str
    title: str
    zone_centers: tuple[tuple[float, float, float], ...] = ()
    zone_radius: float = 0.0

    def dol_pattern(self) -> re.Pattern:
        """``<prefix>_<method>_dol_[cond_<k>_]refinement_<r>.csv``."""
        cond = "" if self.cond is None else f"cond_{self.cond}_"
        return re.compile(rf"{self.prefix}_(?P<method>.+)_dol_{cond}refinement_(?P<r>\d+)\.csv")

    def results_files(self, method: str) -> list[str]:
        """Candidate ``*_results*.csv`` names, the case's own first.

        Case 2 falls back to the ``cond_0`` file: both variants use the same meshes.
        """
        if self.cond is None:
            return [f"{self.prefix}_{method}_results.csv"]
        return [f"{self.prefix}_{method}_results_cond_{k}.csv" for k in (self.cond, 0)]


_INFLOW_EDGE = tuple((0.0, float(y), 95.0) for y in range(0, 101, 20))
CASES = {
    "case1": Case("case1", "berre_case1", "single", None, 5, "berre_case1.png",
                  "case 1, single fracture", _INFLOW_EDGE, 12.0),
    "case2_conductive": Case("case2_conductive", "berre_case2_conductive", "regular", 0, 4,
                             "berre_case2.png", "case 2, conductive fractures",
                             ((1.0, 1.0, 1.0),), 0.25),
    "case2_blocking": Case("case2_blocking", "berre_case2_blocking", "regular", 1, 4,
                           "berre_case2.png", "case 2, blocking fractures",
                           ((1.0, 1.0, 1.0),), 0.25),
}

#: Element size in the balls of a ``--graded`` mesh, relative to its size elsewhere.
GRADED_ZONE_SIZE = 0.3

HEADER = ["case", "method", "refinement", "cells", "fracture_faces", "unknowns", "wall_s",
          "range_l2"]

#: The participants' misfits (``--participants``), read back by later runs.
PARTICIPANTS = DOCS / "berre_participants.csv"
PARTICIPANT_HEADER = ["case", "method", "refinement", "cells", "fracture_faces", "unknowns",
                      "range_l2", "same_as"]

#: Refinements the benchmark asked every participant for (finer ones are the reference's).
SUBMITTED_REFINEMENTS = (0, 1, 2)

#: A method's misfit is read at a cell count within its refinements' range, widened by this
#: factor at both ends (its end value there): participants' meshes of one refinement differ by
#: up to 3.4 times in cells.
SPREAD_MARGIN = 1.25

SPREAD_HEADER = ["case", "poromech", "cells", "range_l2", "methods", "min", "median", "max",
                 "better", "within"]


def matrix_head(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """Arc length and matrix head of a benchmark ``*_dol_*.csv`` (its first column pair)."""
    table = read_number_table(path)
    return table[:, 0], table[:, 1]


def reference_curve(case: Case, folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """The reference solution along the line."""
    cond = "" if case.cond is None else f"cond_{case.cond}_"
    name = f"{case.prefix}_{REFERENCE_METHOD}_dol_{cond}refinement_{case.reference_refinement}.csv"
    return matrix_head(folder / name)


def published_sizes(case: Case, folder: Path, method: str, refinement: int) -> dict:
    """Cells, fracture faces and unknowns of a published run (NaN where not in the folder)."""
    for name in case.results_files(method):
        if (folder / name).exists():
            rows = read_number_table(folder / name)
            if refinement < len(rows):
                row = dict(zip(RESULT_COLUMNS, rows[refinement], strict=True))
                return {"cells": int(row["cells_3d"]), "fracture_faces": int(row["cells_2d"]),
                        "unknowns": int(row["unknowns"]), "file": name}
    return {"cells": np.nan, "fracture_faces": np.nan, "unknowns": np.nan, "file": None}


def published_rows(case: Case, folder: Path, curves: dict) -> tuple[list[list], list[str]]:
    """One row per published curve of the case but the reference; notes on borrowed sizes."""
    s_ref, h_ref = reference_curve(case, folder)
    rows, notes = [], []
    found = []
    for path in sorted(folder.iterdir()):
        m = case.dol_pattern().fullmatch(path.name)
        if m is None:
            continue
        method, r = m["method"], int(m["r"])
        if method == REFERENCE_METHOD and r == case.reference_refinement:
            continue
        found.append((method, r, path))
    for method, r, path in sorted(found):
        s, h = matrix_head(path)
        sizes = published_sizes(case, folder, method, r)
        if sizes["file"] is not None and case.cond is not None \
                and f"cond_{case.cond}" not in sizes["file"]:
            notes.append(f"{case.name}, {LABELS.get(method, method)}: sizes from "
                         f"{sizes['file']} (same meshes)")
        misfit = line_differences(s_ref, h_ref, s, h)["range"]
        rows.append([case.name, LABELS.get(method, method), r, sizes["cells"],
                     sizes["fracture_faces"], sizes["unknowns"], np.nan, misfit])
        curves[(case.name, LABELS.get(method, method), r)] = (s, h)
    return rows, notes


def participant_rows(case: Case, data: Path, folder: Path) -> list[list]:
    """The misfit of every participating method of the case at its submitted refinements.

    ``data``: the ``data`` folder of the benchmark's results repository, one folder per method
    (``<prefix>/results/<group>/<method>/dol_[cond_<k>_]refinement_<r>.csv`` and
    ``results[_cond_<k>].csv``); ``folder``: this study's reference data. Methods with equal
    curves (one scheme submitted under two names) count once: the others name it in ``same_as``
    and are left out of the spread.
    """
    s_ref, h_ref = reference_curve(case, folder)
    cond = "" if case.cond is None else f"cond_{case.cond}_"
    pattern = re.compile(rf"dol_{cond}refinement_(?P<r>\d+)\.csv")
    base = data / case.prefix / "results"
    if not base.is_dir():
        raise FileNotFoundError(f"no participants' results in {base} (--participants: the "
                                "benchmark repository's data folder)")
    names = ([f"results_cond_{case.cond}.csv", "results_cond_0.csv", "results.csv"]
             if case.cond is not None else ["results.csv"])
    methods = []
    for method_dir in sorted(p for p in base.glob("*/*") if p.is_dir()):
        sizes = next((read_number_table(method_dir / n) for n in names
                      if (method_dir / n).exists()), np.empty((0, len(RESULT_COLUMNS))))
        curves = {}
        for path in sorted(method_dir.iterdir()):
            m = pattern.fullmatch(path.name)
            if m is not None and int(m["r"]) in SUBMITTED_REFINEMENTS:
                curves[int(m["r"])] = matrix_head(path)
        if curves:
            methods.append((f"{method_dir.parent.name}-{method_dir.name}", curves, sizes))
    # one scheme under two names: the first with its mesh sizes stands for both
    groups: dict[tuple, list[str]] = {}
    for method, curves, _ in sorted(methods, key=lambda m: (len(m[2]) == 0, m[0])):
        groups.setdefault(tuple(np.concatenate(curves[r]).tobytes() for r in sorted(curves)),
                          []).append(method)
    first = {m: group[0] for group in groups.values() for m in group}
    rows = []
    for method, curves, sizes in methods:
        for r, (s, h) in sorted(curves.items()):
            row = dict(zip(RESULT_COLUMNS, sizes[r], strict=True)) if r < len(sizes) else {}
            rows.append([case.name, method, r, int(row.get("cells_3d", -1)),
                         int(row.get("cells_2d", -1)), int(row.get("unknowns", -1)),
                         line_differences(s_ref, h_ref, s, h)["range"],
                         "" if first[method] == method else first[method]])
    return rows


def write_participants(rows: list[list], command: str) -> None:
    """``docs/flow/berre_participants.csv`` with its provenance line."""
    write_csv(PARTICIPANTS, PARTICIPANT_HEADER, rows,
              comment=f"{generated(command, 1)}; range_l2 of each participating method's matrix "
                      f"head against the reference {LABELS[REFERENCE_METHOD]} (Berre et al. 2021 "
                      "results repository); cells -1: not in the method's results file")


def read_participants(path: Path = PARTICIPANTS) -> list[list]:
    """The rows ``write_participants`` wrote (empty when the file is not there)."""
    if not path.exists():
        return []
    with open(path) as f:
        lines = [line for line in f if not line.startswith("#")]
    rows = list(csv.reader(lines))[1:]
    return [[c, m, int(r), int(n), int(ff), int(u), float(e), same]
            for c, m, r, n, ff, u, e, same in rows]


def spread_at(case: str, cells: float, participants: list[list]) -> dict[str, float]:
    """Each distinct participating method's misfit at ``cells`` (log-log between refinements).

    Methods with an unknown cell count, or whose refinements (widened by ``SPREAD_MARGIN``) do
    not reach ``cells``, are left out.
    """
    by_method: dict[str, list[tuple[int, float]]] = {}
    for c, method, _, n, _, _, misfit, same_as in participants:
        if c == case and not same_as and n > 0 and np.isfinite(misfit):
            by_method.setdefault(method, []).append((n, misfit))
    out = {}
    for method, points in by_method.items():
        n, e = np.array(sorted(points)).T
        if not n[0] / SPREAD_MARGIN <= cells <= n[-1] * SPREAD_MARGIN:
            continue
        out[method] = float(10 ** np.interp(np.log10(cells), np.log10(n), np.log10(e)))
    return out


def spread_rows(rows: list[list], participants: list[list]) -> list[list]:
    """Each poromech row against the participants' spread at its cell count."""
    out = []
    for case, method, tag, cells, _, _, _, misfit in rows:
        if method != "poromech":
            continue
        values = spread_at(case, cells, participants)
        if not values:
            out.append([case, tag, cells, misfit, 0, np.nan, np.nan, np.nan, "–",
                        "finer than every participant"])
            continue
        v = np.array(list(values.values()))
        within = "yes" if v.min() <= misfit <= v.max() else (
            "below (better)" if misfit < v.min() else "above (worse)")
        out.append([case, tag, cells, misfit, len(v), v.min(), float(np.median(v)), v.max(),
                    f"{int(np.sum(v < misfit))} of {len(v)}", within])
    return out


def plot_spread(cases: list[Case], rows: list[list], participants: list[list]) -> str:
    """Misfit against cells: every participating method (thin) and poromech (bold)."""
    fig, axes = plt.subplots(1, len(cases), figsize=(4.6 * len(cases), 4.2), squeeze=False)
    for ax, case in zip(axes[0], cases, strict=True):
        methods = dict.fromkeys(m for c, m, _, n, *_, same in participants
                                if c == case.name and not same and n > 0)
        for method in methods:
            n, e = np.array(sorted((n, e) for c, m, _, n, _, _, e, _ in participants
                                   if c == case.name and m == method and n > 0)).T
            hfv = method == "UNICE_UNIGE-HFV_Disc"
            ax.loglog(n, e, "s--" if hfv else ".-", color="tab:blue" if hfv else "0.65",
                      lw=1.4 if hfv else 0.8, ms=5 if hfv else 4, zorder=3 if hfv else 2,
                      label="UNICE_UNIGE-HFV_Disc (published)" if hfv else None)
        ax.plot([], [], ".-", color="0.65", label="participating methods")
        mine = [(r[3], r[7]) for r in rows if r[0] == case.name and r[1] == "poromech"
                and isinstance(r[2], int)]
        if mine:
            n, e = np.array(sorted(mine)).T
            ax.loglog(n, e, "o-", color="k", lw=2, zorder=4, label="poromech HFV (levels)")
        for kind, style, color, label in (("size", "D", "tab:red", "poromech, gmsh at a size"),
                                          ("graded", "^-", "tab:green",
                                           "poromech, graded at the patch edge")):
            fresh = sorted((r[3], r[7]) for r in rows if r[0] == case.name
                           and r[1] == "poromech" and str(r[2]).startswith(kind))
            if fresh:
                n, e = np.array(fresh).T
                ax.loglog(n, e, style, color=color, zorder=4, label=label)
        ax.set_title(f"{case.title} ({len(methods)} methods)", fontsize=10)
        ax.set_xlabel("matrix cells")
        ax.set_ylabel("range_l2 of the matrix head")
        ax.grid(alpha=0.3, which="both")
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="lower center", ncol=4, fontsize=8,
               bbox_to_anchor=(0.5, -0.04))
    fig.tight_layout(rect=(0, 0.04, 1, 1))
    save_figure(fig, DOCS / "berre_spread.png")
    plt.close(fig)
    return "berre_spread.png"


def probe_misfit(probe_csv: Path, s_ref: np.ndarray, h_ref: np.ndarray
                 ) -> tuple[float, np.ndarray, np.ndarray]:
    """Range-normalized L² misfit of a poromech probe (``p_m``) and its curve."""
    header, data = read_csv(probe_csv)
    s, h = data[:, header.index("arc_length")], data[:, header.index("p_m")]
    return line_differences(s_ref, h_ref, s, h)["range"], s, h


def graded_zones(case: Case, size: float, around: float) -> str:
    """The ``mesh.zones`` override of a graded mesh: balls of ``size`` along the patch edge.

    The size grows to ``around`` over at least twice the difference (a grading of 0.5, gentle
    enough for gmsh's tetrahedra).
    """
    transition = max(case.zone_radius, 2.0 * (around - size))
    balls = ", ".join(f"{{center: [{x:g}, {y:g}, {z:g}], radius: {case.zone_radius:g}, "
                      f"size: {size:g}, transition: {transition:g}, region: ball}}"
                      for x, y, z in case.zone_centers)
    return f"mesh.zones=[{balls}]"


def run_level(case: Case, level: int, folder: Path, work: Path, curves: dict,
              size_factor: float | None = None, graded: bool = False) -> list:
    """Run the case's scene at a refinement level and compare its probe with the reference.

    ``size_factor``: instead, a fresh mesh at that factor times the scene's mesh sizes (the row's
    refinement column says ``size ×f``; its curve is not drawn). ``graded``: that mesh graded
    towards the case's ``zone_centers`` (``graded ×f``).
    """
    from poromech.run import run_scene
    from poromech.scene.loading import load_scene

    path = ROOT / "configs" / f"{case.scene}.yaml"
    if size_factor is None:
        sets, tag = [f"mesh.refinement={level}"], level
    else:
        mesh = load_scene(path).mesh
        sets = [f"mesh.size={size_factor * mesh.size:g}",
                f"mesh.fracture_size={size_factor * mesh.fracture_size:g}"]
        tag = f"{'graded' if graded else 'size'} ×{size_factor:g}"
        if graded:
            sets.append(graded_zones(case, GRADED_ZONE_SIZE * size_factor * mesh.size,
                                     size_factor * mesh.size))
    scene = load_scene(path, [*sets, "output.xdmf=false"])
    out = work / f"{case.name}_{'m' if size_factor is None else 'g' if graded else 's'}{level}"
    summary = run_scene(scene, out, MPI.COMM_WORLD)
    s_ref, h_ref = reference_curve(case, folder)
    misfit, s, h = probe_misfit(out / f"probe_{scene.probes[0].name}.csv", s_ref, h_ref)
    if size_factor is None:
        curves[(case.name, "poromech", level)] = (s, h)
    mesh = summary["mesh"]
    return [case.name, "poromech", tag, mesh["cells"], mesh["fracture_faces"],
            summary["flow"]["unknowns"]["total"], summary["wall_time"]["total"], misfit]


def plot(cases: list[Case], folder: Path, curves: dict) -> list[str]:
    """One figure per benchmark case: head along the line (top), difference to the reference."""
    written = []
    for figure in dict.fromkeys(c.figure for c in cases):
        panels = [c for c in cases if c.figure == figure]
        fig, axes = plt.subplots(2, len(panels), figsize=(6.5 * len(panels), 6.5),
                                 squeeze=False, sharex="col",
                                 gridspec_kw={"height_ratios": [2, 1]})
        for col, case in enumerate(panels):
            top, bottom = axes[0, col], axes[1, col]
            s_ref, h_ref = reference_curve(case, folder)
            top.plot(s_ref, h_ref, "k-", lw=2.5,
                     label=f"reference ({LABELS[REFERENCE_METHOD]}, "
                           f"refinement {case.reference_refinement})")
            keys = [k for k in curves if k[0] == case.name]
            for key in sorted(keys, key=lambda k: (k[1] == "poromech", k[1], k[2])):
                _, method, r = key
                s, h = curves[key]
                style = "-" if method == "poromech" else "--"
                label = (f"poromech HFV, level {r}" if method == "poromech"
                         else f"{method}, refinement {r}")
                ok = np.isfinite(h)
                top.plot(s[ok], h[ok], style, lw=1.0, label=label)
                bottom.plot(s_ref, np.interp(s_ref, s[ok], h[ok]) - h_ref, style, lw=1.0,
                            label=label)
            top.set_ylabel("matrix head h (m)" if case.cond is None else "matrix pressure p")
            top.set_title(case.title)
            bottom.set_xlabel("arc length along the line")
            bottom.set_ylabel("difference to the reference")
            for ax in (top, bottom):
                ax.grid(alpha=0.3)
                ax.legend(fontsize=7)
        save_figure(fig, DOCS / figure)
        plt.close(fig)
        written.append(figure)
    return written


def command_line(argv: list[str]) -> str:
    """The command as typed, for the provenance line.

    A participants' folder is written as ``<clone>/data`` (no path of the machine that ran it).
    """
    words, hide = [], False
    for a in argv:
        words.append("<clone>/data" if hide else shlex.quote(a))
        hide = a == "--participants"
    return " ".join(["python scripts/flow_berre.py", *words])


def main(argv: list[str] | None = None) -> None:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--reference", default=os.environ.get("POROMECH_FLOW3D_REFERENCE",
                                                         str(DEFAULT_REFERENCE)),
                   help="folder of the benchmark's data (default ../shared/data/"
                        "fracture_flow_3d beside the repository)")
    p.add_argument("--levels", type=int, nargs="*", default=[0, 1, 2, 3],
                   help="refinement levels of the poromech runs (none: published curves only)")
    p.add_argument("--sizes", type=float, nargs="*", default=[],
                   help="also fresh meshes at these factors of the scenes' mesh sizes")
    p.add_argument("--graded", type=float, nargs="*", default=[],
                   help="also fresh meshes at these factors, graded towards the singular edge "
                        "of the Dirichlet patch")
    p.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    p.add_argument("--participants", type=Path,
                   help="the data folder of a clone of the benchmark's results repository: "
                        "every participating method's misfit (else docs/flow/"
                        "berre_participants.csv of an earlier run)")
    args = p.parse_args(argv)
    folder = Path(args.reference)
    if not folder.is_dir():
        p.error(f"no benchmark data in {folder} (give --reference)")
    if args.participants is not None and not (args.participants / "single").is_dir():
        p.error(f"--participants {args.participants}: no single/results folder in it (the "
                "data folder of the benchmark's results repository)")
    cases = [CASES[c] for c in args.cases]
    DOCS.mkdir(parents=True, exist_ok=True)
    rows, notes, curves = [], [], {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            published, case_notes = published_rows(case, folder, curves)
            rows += published
            notes += case_notes
            for level in args.levels:
                rows.append(run_level(case, level, folder, Path(tmp), curves))
                print(rows[-1], flush=True)
            for k, f in enumerate(args.sizes):
                rows.append(run_level(case, k, folder, Path(tmp), curves, size_factor=f))
                print(rows[-1], flush=True)
            for k, f in enumerate(args.graded):
                rows.append(run_level(case, k, folder, Path(tmp), curves, size_factor=f,
                                      graded=True))
                print(rows[-1], flush=True)
    command = command_line(argv)
    ranks = MPI.COMM_WORLD.size
    if args.participants is not None:
        participants = [r for case in CASES.values()
                        for r in participant_rows(case, args.participants, folder)]
        write_participants(participants, command)
    else:
        participants = read_participants()
    participants = [r for r in participants if r[0] in args.cases]
    write_csv(DOCS / "berre.csv", HEADER, rows, comment=generated(command, ranks))
    figures = plot(cases, folder, curves)
    spread = spread_rows(rows, participants) if participants else []
    if spread:
        figures.append(plot_spread(cases, rows, participants))
    text = (generated(command, ranks) + ". range_l2 = ‖h - h_ref‖/(|line|^½ (max h_ref - "
            "min h_ref)) in L² along the benchmark's line (the matrix head; the normalization of "
            "the 2D study, docs/flow/flemisch.md), h_ref the reference "
            f"{LABELS[REFERENCE_METHOD]} at its finest mesh; poromech levels: the scene's mesh "
            "refined uniformly (8 times the cells per level), or made by gmsh at a factor of its "
            "sizes (size ×f), or that mesh graded to "
            f"{GRADED_ZONE_SIZE:g} of its size along the singular edge of the head's Dirichlet "
            "patch (graded ×f; scripts/flow_berre.py, Case.zone_centers), wall_s the whole run "
            "(meshing "
            "included); published methods: cells, fracture faces and unknowns from their "
            "results files.\n\n")
    if notes:
        text += "".join(f"* {n}\n" for n in notes) + "\n"
    text += markdown_table(HEADER, rows)
    if spread:
        same = sorted({f"{m} = {same}" for _, m, *_, same in participants if same})
        text += ("\n## Among the benchmark's participating methods\n\nEach poromech row against "
                 "the participating methods of the benchmark at its cell count (berre_"
                 "participants.csv: each method's misfit at its refinements 0-2, computed as "
                 "above; here interpolated log-log between them, methods whose meshes do not "
                 f"reach the count within a factor {SPREAD_MARGIN:g} left out). methods: how "
                 "many; min / median / max of their misfits; better: how many have a smaller "
                 "one; within: poromech between the smallest and the largest. Identical curves "
                 "submitted under two names count once"
                 + (f" ({'; '.join(same)})" if same else "") + ".\n\n")
        text += markdown_table(SPREAD_HEADER, spread)
    text += "\n" + "".join(f"![{f}]({f})\n" for f in figures)
    (DOCS / "berre.md").write_text(text)


if __name__ == "__main__":
    main()
