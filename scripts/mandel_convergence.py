"""Mandel's problem in a plane-strain 3D slab: the coupled solver against the series.

    python scripts/mandel_convergence.py

Runs ``configs/mandel3d.yaml`` (the quarter of a slab squeezed between rigid, frictionless,
impervious plates, one layer of tetrahedra thick with ``u_y = 0`` on front and back) and
compares with Mandel's solution (``poromech.analytic.mandel_pressure``,
``mandel_displacement_x``):

* the scene as shipped (mesh size 0.1, 50 steps of 1 s): at t = 1 ... 50 s, the relative L²
  error of the pressure over the cells, the mean pressure of the cells within 0.1 m of the
  centre (computed and exact, in units of the undrained p₀: the Mandel–Cryer rise) and the
  error of the horizontal displacement of the drained side;
* the errors at t = 10 s and 50 s (c t/a² = 0.1 and 0.5) with the time step and the mesh size
  halved.

Writes docs/poromechanics/mandel3d.{csv,md,png}.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from flow_common import markdown_table, save_figure, write_csv  # noqa: E402

from poromech.analytic import mandel_parameters, mandel_pressure  # noqa: E402
from poromech.io.xdmf import read_series  # noqa: E402
from poromech.run import run_scene  # noqa: E402
from poromech.scene.loading import load_scene  # noqa: E402
from poromech.verification.consolidation import mandel_errors  # noqa: E402

DOCS = ROOT / "docs" / "poromechanics"
COMMAND = "python scripts/mandel_convergence.py"
SCENE = ROOT / "configs" / "mandel3d.yaml"
TIMES = (1.0, 2.0, 5.0, 10.0, 20.0, 50.0)
#: (mesh size, steps) of the refinement study
VARIANTS = ((0.1, 25), (0.1, 50), (0.1, 100), (0.05, 50), (0.05, 100))


def run(tmp: Path, size: float, steps: int):
    scene = load_scene(SCENE, [f"mesh.size={size}", f"time.steps={steps}"])
    out = tmp / f"h{size}_n{steps}"
    summary = run_scene(scene, out)
    assert summary["status"] == "converged"
    return scene, out, summary


def main(argv: list[str] | None = None) -> None:
    # no options: --help says what the script runs and writes, and runs nothing
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    DOCS.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        scene, out, summary = run(tmp, 0.1, 50)
        times = read_series(out, "flow").times
        history = [mandel_errors(scene, out, k) for k in range(len(times))]
        profiles = profile_data(scene, out, (1.0, 10.0, 50.0))
        rows = [["shipped", 0.1, 50, summary["mesh"]["cells"], summary["wall_time"]["total"],
                 t, e["pressure"], e["centre"], e["centre_exact"], e["ux"]]
                for t in TIMES for e in [history[times.index(t)]]]
        for size, steps in VARIANTS:
            scene, out, summary = run(tmp, size, steps)
            times = read_series(out, "flow").times
            for t in (10.0, 50.0):
                e = mandel_errors(scene, out, times.index(t))
                rows.append(["refined", size, steps, summary["mesh"]["cells"],
                             summary["wall_time"]["total"], t, e["pressure"], e["centre"],
                             e["centre_exact"], e["ux"]])
    header = ["study", "mesh size", "steps", "cells", "wall s", "t (s)", "pressure error",
              "centre p/p0", "exact centre p/p0", "u_x error"]
    stamp = f"Generated {datetime.date.today()} by `{COMMAND}` (1 MPI rank)"
    write_csv(DOCS / "mandel3d.csv", header, rows, stamp)
    text = [f"# Mandel's problem in a plane-strain 3D slab\n\n{stamp}. `configs/mandel3d.yaml`: "
            "a = 1 m, c = 0.01 m²/s (c t/a² = 0.5 at t = 50 s), ν = 0.2, ν_u = 0.48. *pressure "
            "error*: relative L² over the cells; *centre p/p0*: mean pressure of the cells "
            "within 0.1 m of the centre over the undrained p₀ (computed, and the series at the "
            "same cell centroids); *u_x error*: relative error of the mean horizontal "
            "displacement of the drained side. *shipped*: the scene as shipped, at several "
            "times; *refined*: time step and mesh size halved.\n\n",
            markdown_table(header, rows, fmt=".4g")]
    (DOCS / "mandel3d.md").write_text("".join(text))
    figure(history, profiles)


def profile_data(scene, out: Path, times) -> dict:
    """Cell pressures by cell-centroid abscissa at ``times``, with the series."""
    p = scene.parameters
    c = mandel_parameters(p["E"], p["nu"], p["b"], p["M"], p["k"], p["a"], p["F"])
    flow = read_series(out, "flow")
    x = flow.points[flow.cells].mean(axis=1)[:, 0]
    xs = np.linspace(0.0, p["a"], 201)
    return {t: (x, flow.fields(flow.times.index(t))["p_m"] / c["p0"], xs,
                mandel_pressure(xs, t, c) / c["p0"]) for t in times}


def figure(history, profiles) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    ax = axes[0]
    for t, (x, ph, xs, pe) in profiles.items():
        line, = ax.plot(xs, pe, "-", label=f"t = {t:g} s, exact")
        ax.plot(x, ph, ".", ms=3, color=line.get_color(), label=f"t = {t:g} s, cells")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("p / p₀")
    ax.set_title("Mandel: pressure across the slab")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    ax = axes[1]
    t = [e["time"] for e in history]
    ax.plot(t, [e["centre_exact"] for e in history], "k-", label="exact")
    ax.plot(t, [e["centre"] for e in history], "o", ms=3, label="computed")
    ax.axhline(1.0, color="grey", lw=0.8, ls="--")
    ax.set_xlabel("t (s)")
    ax.set_ylabel("p / p₀ at the centre (x < 0.1 m)")
    ax.set_title("Mandel–Cryer effect")
    ax.legend()
    ax.grid(alpha=0.3)
    save_figure(fig, DOCS / "mandel3d.png")


if __name__ == "__main__":
    main()
