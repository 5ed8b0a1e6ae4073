"""The coupled six-fracture scene and its one-layer 3D slab: apertures, states, pressures, g.

Scene: ``configs/six_fractures.yaml`` (Biot matrix, Coulomb contact, HFV Darcy flow in matrix
and fractures, Anderson fixed point; 20 steps to T = 2000 s), in 2D and as the slab of
``poromech.verification.slab`` (the 2D mesh extruded one layer thick in y, ``u_y = 0`` and no
flow on front and back, the 2D flow and coupling sections mapped by ``slab_scene``), for each
formulation asked (default: the scene's, ``mixed`` P2). The slab is the plane-strain problem of
the 2D scene with the same flow per unit depth, so it must reproduce the 2D results up to the
2D discretization error, which is measured here by the same scene in 2D on the once-refined
mesh. Each output directory is ``results/poromechanics3d_slab/<formulation>_P<degree>_<case>``
(``2d_m0``, ``slab_m0``, ``2d_m1``); a run whose ``summary.json`` says ``converged`` with the
same overrides is not repeated unless ``--again``. ``--set KEY=VALUE`` overrides apply to every
run (e.g. fewer steps)::

    python scripts/poromechanics3d_slab.py                       # mixed P2, 20 steps
    python scripts/poromechanics3d_slab.py --formulations mixed nitsche --degrees 2
    python scripts/poromechanics3d_slab.py --set time.final=1000 --set time.steps=10
    python scripts/poromechanics3d_slab.py --report    # redraw slab.md, slab.png from slab.csv

``slab.csv`` has a row per case, output time and fracture (and ``all``, the whole network):
``model`` is ``2d`` or ``slab``, ``refinement`` the 2D mesh; ``aperture`` the mean aperture
(m), ``p_f`` the mean fracture pressure (Pa), both weighted by face length (2D) or area (slab),
``open``, ``stick``, ``slip`` the fractions of the fracture in each contact state (as written in
``fractures.xdmf``), ``g_evaluations`` those of the step ending at that time (the coupled
fixed-point iterations; empty at t = 0), ``seconds`` the run's wall time. ``slab.md`` compares
them, ``slab.png`` draws the network's mean aperture against time.
"""

from __future__ import annotations

import argparse
import datetime
import json
import shutil
import time
from pathlib import Path

import dolfinx_solver  # noqa: F401

import numpy as np
from report_common import fmt, read_csv, write_csv

from poromech.io.results import STATES, open_results
from poromech.run import Run
from poromech.scene.geometry import mesh_sizes, scene_geometry
from poromech.scene.loading import load_scene_and_raw
from poromech.verification.slab import slab_geometry, slab_mesh, slab_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "six_fractures.yaml"
RUNS = ROOT / "results" / "poromechanics3d_slab"
OUT = ROOT / "docs" / "poromechanics3d"
#: The slab thickness, as a fraction of the 2D fracture mesh size.
THICKNESS = 0.5
#: The three runs of a formulation: (model, 2D mesh refinement).
CASES = (("2d", 0), ("slab", 0), ("2d", 1))
FIELDS = ["formulation", "degree", "model", "refinement", "time", "fracture", "aperture", "p_f",
          *STATES, "g_evaluations", "seconds"]


def run_case(formulation: str, degree: int, model: str, refinement: int, sets: list[str],
             again: bool) -> Path:
    """Run one case into its output directory (unless done with the same overrides)."""
    out = RUNS / f"{formulation}_P{degree}_{model}_m{refinement}"
    done = out / "summary.json"
    overrides = [f"contact.formulation={formulation}", f"degree={degree}",
                 f"mesh.refinement={refinement}", "output.checkpoint=false", *sets]
    if done.exists() and not again:
        summary = json.loads(done.read_text())
        if summary["status"] == "converged" and summary.get("overrides") == overrides:
            return out
    shutil.rmtree(out, ignore_errors=True)
    scene, raw = load_scene_and_raw(SCENE, overrides)
    start = time.perf_counter()
    fm = None
    if model == "slab":
        thickness = THICKNESS * mesh_sizes(scene).fracture_size
        fm = slab_mesh(scene, thickness)
        scene = slab_scene(raw, slab_geometry(scene_geometry(scene), thickness))
    with Run(scene, out, mesh=fm) as run:
        summary = run.execute()
    summary["process_seconds"] = time.perf_counter() - start
    summary["overrides"] = overrides
    done.write_text(json.dumps(summary, indent=1))
    return out


def face_measures(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    """Lengths (2D segments) or areas (3D triangles) of the fracture faces (m or m²)."""
    x = points[cells]
    if cells.shape[1] == 2:
        return np.linalg.norm(x[:, 1] - x[:, 0], axis=1)
    return 0.5 * np.linalg.norm(np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]), axis=1)


def history(out: Path) -> dict:
    """Per output time and fracture (the last column: the network), the compared quantities.

    Returns:
        ``times`` ``(nt,)``, ``names`` (fractures, then ``all``), ``aperture``, ``p_f`` and the
        state fractions ``(nt, nfrac + 1)``, ``g`` ``(nt,)`` (NaN at t = 0), ``seconds``.
    """
    res = open_results(out)
    series = res.series("fractures")
    w = face_measures(series.points, series.cells)
    fracture = res.fractures(time=series.times[0])["fracture"]
    names = sorted(set(fracture), key=lambda n: (len(n), n))
    groups = [fracture == n for n in names] + [np.ones(len(w), dtype=bool)]
    out_ = {k: np.empty((len(series.times), len(groups))) for k in ("aperture", "p_f", *STATES)}
    for k in range(len(series.times)):
        f = series.fields(k)
        values = {"aperture": f["aperture"], "p_f": f["p_f"],
                  **{s: (f["state"] == c).astype(float) for c, s in enumerate(STATES)}}
        for j, sel in enumerate(groups):
            for key, v in values.items():
                out_[key][k, j] = w[sel] @ v[sel] / w[sel].sum()
    summary = res.summary
    g = [np.nan] + [float(r["g_evaluations"]) for r in summary["solves"]]
    return {"times": np.asarray(series.times), "names": [*names, "all"], **out_,
            "g": np.asarray(g[: len(series.times)]),
            "seconds": float(summary.get("process_seconds", summary["wall_time"]["total"]))}


def rows_of(formulation: str, degree: int, model: str, refinement: int, h: dict) -> list[dict]:
    """The CSV rows of one case."""
    rows = []
    for k, t in enumerate(h["times"]):
        for j, name in enumerate(h["names"]):
            g = h["g"][k]
            rows.append({"formulation": formulation, "degree": degree, "model": model,
                         "refinement": refinement, "time": float(t), "fracture": name,
                         "aperture": f"{h['aperture'][k, j]:.9g}", "p_f": f"{h['p_f'][k, j]:.9g}",
                         **{s: f"{h[s][k, j]:.6g}" for s in STATES},
                         "g_evaluations": "" if np.isnan(g) else int(g),
                         "seconds": f"{h['seconds']:.4g}"})
    return rows


def cases_from_rows(rows: list[dict]) -> dict:
    """The histories of the CSV rows, by (formulation, degree) and then (model, refinement)."""
    out: dict = {}
    for r in rows:
        key = (r["formulation"], int(r["degree"]))
        case = out.setdefault(key, {}).setdefault((r["model"], int(r["refinement"])), {})
        case.setdefault(r["fracture"], []).append(r)
    histories = {}
    for key, cases in out.items():
        for case, by_name in cases.items():
            names = list(by_name)
            times = np.array([r["time"] for r in by_name[names[0]]], dtype=float)
            h = {"times": times, "names": names,
                 "g": np.array([np.nan if r["g_evaluations"] == "" else r["g_evaluations"]
                                for r in by_name[names[0]]], dtype=float),
                 "seconds": float(by_name[names[0]][0]["seconds"])}
            for q in ("aperture", "p_f", *STATES):
                h[q] = np.array([[r[q] for r in by_name[n]] for n in names], dtype=float).T
            histories.setdefault(key, {})[case] = h
    return histories


def differences(a: dict, b: dict, p0: float, delta0: float) -> dict:
    """Largest differences of ``a`` from ``b`` over the output times and the fractures.

    ``aperture``: of a fracture's mean aperture, over δ₀; ``p_f``: of a fracture's mean
    pressure, over the largest mean overpressure ``|p̄_f - p⁰|`` of ``b``; ``states``: the
    largest share of a fracture in another state (half the sum of the fraction differences);
    ``all``: the network's mean aperture, over δ₀. The fractures only (not ``all``) for the
    first three.
    """
    scale = float(np.max(np.abs(b["p_f"] - p0)))
    states = 0.5 * sum(np.abs(a[s] - b[s]) for s in STATES)
    return {"aperture": float(np.max(np.abs(a["aperture"] - b["aperture"])[:, :-1])) / delta0,
            "p_f": float(np.max(np.abs(a["p_f"] - b["p_f"])[:, :-1])) / scale,
            "states": float(np.max(states[:, :-1])),
            "all": float(np.max(np.abs(a["aperture"] - b["aperture"])[:, -1])) / delta0}


def scene_constants() -> tuple[float, float]:
    """``p⁰`` (Pa) and ``δ₀`` (m) of the scene."""
    scene, _ = load_scene_and_raw(SCENE, [])
    return float(scene.flow.initial_pressure.value()), float(scene.parameters["delta0"])


def write_report(histories: dict, comments: list[str]) -> None:
    """``slab.md`` and ``slab.png`` from the histories of every case."""
    p0, delta0 = scene_constants()
    lines = ["# The coupled six-fracture scene as a one-layer 3D slab", "",
             f"Generated by `{comments[0]}` ({comments[1]}). See "
             "`scripts/poromechanics3d_slab.py` for the scene, the cases and the columns; "
             "every output time and fracture in [`slab.csv`](slab.csv).", "",
             "Coarse mesh (refinement 0: 2,965 triangles and 90 fracture faces in 2D; the slab: "
             "8,895 tetrahedra and 180 fracture triangles, one layer 0.019 m thick); `2D ref`: "
             "the 2D scene on the once-refined mesh (the 2D discretization error is `2D ref` − "
             "`2D`). Largest differences over the output times and the six fractures: of a "
             "fracture's mean aperture over δ₀ = 100 µm (`aperture`), of its mean pressure over "
             "the largest mean overpressure of the 2D run (`p_f`), the largest share of a "
             "fracture in another contact state (`states`), and of the network's mean aperture "
             "over δ₀ (`network`); `g`: the fixed-point evaluations of the run (all steps); "
             "seconds: the run's wall time on a shared 2-core machine.", "",
             "| formulation | compared | aperture | p_f | states | network | g | seconds |",
             "|---|---|---|---|---|---|---|---|"]
    for (formulation, degree), cases in histories.items():
        base = cases[("2d", 0)]
        for label, case in (("slab − 2D", ("slab", 0)), ("2D ref − 2D", ("2d", 1))):
            if case not in cases:
                continue
            d = differences(cases[case], base, p0, delta0)
            c = cases[case]
            lines.append(f"| {formulation} P{degree} | {label} | {fmt(d['aperture'])} | "
                         f"{fmt(d['p_f'])} | {fmt(d['states'])} | {fmt(d['all'])} | "
                         f"{int(np.nansum(c['g']))} (2D {int(np.nansum(base['g']))}) | "
                         f"{c['seconds']:.0f} (2D {base['seconds']:.0f}) |")
    for (formulation, degree), cases in histories.items():
        lines += per_fracture(formulation, degree, cases)
        lines += ["", f"## {formulation} P{degree}: per output time", "",
                  "Network mean aperture (µm), mean fracture pressure over the network (MPa), "
                  "share of the network in slip, and `g` evaluations of the step ending then.",
                  "", "| t (s) | aperture 2D | slab | 2D ref | p̄_f 2D | slab | 2D ref | "
                  "slip 2D | slab | 2D ref | g 2D | slab | 2D ref |",
                  "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        hs = [cases.get(c) for c in (("2d", 0), ("slab", 0), ("2d", 1))]
        for k, t in enumerate(hs[0]["times"]):
            cols = [f"{1e6 * h['aperture'][k, -1]:.3f}" if h else "" for h in hs]
            cols += [f"{1e-6 * h['p_f'][k, -1]:.4f}" if h else "" for h in hs]
            cols += [f"{h['slip'][k, -1]:.3f}" if h else "" for h in hs]
            cols += ["" if not h or np.isnan(h["g"][k]) else str(int(h["g"][k])) for h in hs]
            lines.append(f"| {t:g} | " + " | ".join(cols) + " |")
    (OUT / "slab.md").write_text("\n".join(lines) + "\n")
    figure(histories)


def per_fracture(formulation: str, degree: int, cases: dict) -> list[str]:
    """Per fracture, the largest differences from 2D over the output times: slab and 2D ref."""
    base, slab, ref = (cases.get(c) for c in CASES)
    lines = ["", f"## {formulation} P{degree}: per fracture", "",
             "Largest differences from 2D over the output times: of the mean aperture (µm), of "
             "the mean pressure (kPa), the share of the fracture in another state.", "",
             "| fracture | aperture slab | 2D ref | p_f slab | 2D ref | states slab | 2D ref |",
             "|---|---|---|---|---|---|---|"]
    for j, name in enumerate(base["names"][:-1]):
        cols = []
        for key, unit in (("aperture", 1e6), ("p_f", 1e-3), ("states", 1.0)):
            for h in (slab, ref):
                if h is None:
                    cols.append("")
                    continue
                if key == "states":
                    d = 0.5 * sum(np.abs(h[s][:, j] - base[s][:, j]) for s in STATES)
                else:
                    d = unit * np.abs(h[key][:, j] - base[key][:, j])
                cols.append(f"{np.max(d):.2f}" if key != "states" else f"{np.max(d):.3f}")
        lines.append(f"| {name} | " + " | ".join(cols) + " |")
    return lines


def figure(histories: dict) -> None:
    """``slab.png``: the network's mean aperture against time, and minus the 2D run's.

    Top: 2D, slab and 2D refined; bottom: the differences of the last two from 2D.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = len(histories)
    fig, axes = plt.subplots(2, n, figsize=(4.6 * n, 5.6), squeeze=False, sharex=True,
                             sharey="row", gridspec_kw={"height_ratios": [3, 2]})
    styles = ((("2d", 0), "k-", "2D"), (("slab", 0), "C1--", "slab"),
              (("2d", 1), "C0:", "2D refined"))
    for k, ((formulation, degree), cases) in enumerate(histories.items()):
        base = cases[("2d", 0)]
        for case, style, label in styles:
            if case not in cases:
                continue
            h = cases[case]
            axes[0, k].plot(h["times"], 1e6 * h["aperture"][:, -1], style, marker=".",
                            label=label)
            if case != ("2d", 0):
                axes[1, k].plot(h["times"], 1e6 * (h["aperture"][:, -1] - base["aperture"][:, -1]),
                                style, marker=".", label=f"{label} − 2D")
        axes[0, k].set_title(f"{formulation} P{degree}")
        axes[1, k].set_xlabel("t (s)")
        for ax in axes[:, k]:
            ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("mean aperture (µm)")
    axes[1, 0].set_ylabel("difference (µm)")
    axes[0, 0].legend()
    axes[1, 0].legend(fontsize="small")
    fig.tight_layout()
    fig.savefig(OUT / "slab.png", dpi=80)


def main() -> None:
    """Run the cases, write the CSV, the Markdown summary and the figure."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--formulations", nargs="+", default=["mixed"])
    parser.add_argument("--degrees", type=int, nargs="+", default=[2])
    parser.add_argument("--set", dest="sets", action="append", default=[],
                        help="scene override for every run, KEY=VALUE")
    parser.add_argument("--again", action="store_true", help="repeat converged runs")
    parser.add_argument("--report", action="store_true", help="only redraw from slab.csv")
    args = parser.parse_args()
    path = OUT / "slab.csv"
    if args.report:
        comments, rows = read_csv(path, text=("formulation", "model", "fracture"))
        write_report(cases_from_rows(rows), comments)
        return
    rows = []
    for degree in args.degrees:
        for formulation in args.formulations:
            for model, refinement in CASES:
                out = run_case(formulation, degree, model, refinement, args.sets, args.again)
                rows += rows_of(formulation, degree, model, refinement, history(out))
                print(f"{formulation} P{degree} {model} m{refinement}: done", flush=True)
    command = " ".join(["python scripts/poromechanics3d_slab.py",
                        *(["--formulations", *args.formulations]
                          if args.formulations != ["mixed"] else []),
                        *(["--degrees", *map(str, args.degrees)] if args.degrees != [2] else []),
                        *(f"--set {s}" for s in args.sets)])
    comments = [command, str(datetime.date.today())]
    OUT.mkdir(parents=True, exist_ok=True)
    write_csv(path, comments, FIELDS, rows)
    write_report(cases_from_rows(read_csv(path, text=("formulation", "model",
                                                      "fracture"))[1]), comments)


if __name__ == "__main__":
    main()
