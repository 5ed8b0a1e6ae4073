"""Terzaghi's consolidation with the coupled solver: observed orders in time and in space.

    python scripts/terzaghi_convergence.py            # 2D
    python scripts/terzaghi_convergence.py --dim 3    # 3D

Runs ``configs/terzaghi.yaml`` (a confined poroelastic column under a constant load on its
drained top; ``--dim 3``: ``configs/terzaghi3d.yaml``, the column as a box) and compares the
pressure (relative L² over the cells) and the settlement of the top at t = 20 s with the
classical series (``poromech.analytic``):

* in time, on a fine mesh (2D: ``mesh.refinement=2``; 3D: the scene's mesh of size 0.05), with
  5 ... 80 implicit Euler steps, against the exact solution (implicit Euler: order 1);
* in space, with 4 steps on meshes ``m = 0 ... 3`` (2D, from size 0.1) or ``m = 0 ... 2`` (3D,
  from size 0.125) of uniform refinement, against the exact solution *of the time-discrete
  problem* (each Fourier mode decays as after 4 implicit Euler steps), which isolates the space
  error (HFV pressure and P2 displacement: order 2).

Writes docs/poromechanics/terzaghi.{csv,md,png} (3D: terzaghi3d.*).
"""

from __future__ import annotations

import argparse
import datetime
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))
sys.path.insert(0, str(ROOT / "scripts"))

from poromechanics_study import markdown_table, write_csv  # noqa: E402

from poromech.run import run_scene  # noqa: E402
from poromech.scene.loading import load_scene  # noqa: E402
from poromech.verification.consolidation import terzaghi_errors  # noqa: E402

DOCS = ROOT / "docs" / "poromechanics"
COMMAND = "python scripts/terzaghi_convergence.py"
#: Per dimension: scene, output stem, overrides of the time study, base size and levels of the
#: space study.
STUDIES = {
    2: ("terzaghi", "terzaghi", ["mesh.refinement=2"], 0.1, (0, 1, 2, 3)),
    3: ("terzaghi3d", "terzaghi3d", [], 0.125, (0, 1, 2)),
}


def run(tmp: Path, name: str, overrides: list[str], steps: int | None):
    scene = load_scene(ROOT / "configs" / f"{name}.yaml", overrides)
    out = tmp / "_".join(o.replace("=", "") for o in overrides)
    summary = run_scene(scene, out)
    err_p, err_u, _ = terzaghi_errors(scene, out, steps=steps)
    return err_p, err_u, summary["wall_time"]["total"], summary["mesh"]["cells"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--dim", type=int, choices=(2, 3), default=2)
    dim = parser.parse_args().dim
    name, stem, fine, size, levels = STUDIES[dim]
    command = COMMAND + (" --dim 3" if dim == 3 else "")
    DOCS.mkdir(parents=True, exist_ok=True)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for n in (5, 10, 20, 40, 80):
            rows.append(["time", n, *run(tmp, name, [*fine, f"time.steps={n}"], None)])
        for m in levels:
            rows.append(["space", m, *run(tmp, name, [f"mesh.size={size}",
                                                      f"mesh.refinement={m}", "time.steps=4"],
                                          4)])
    for kind in ("time", "space"):
        sel = [r for r in rows if r[0] == kind]
        for prev, cur in zip(sel[:-1], sel[1:], strict=True):
            cur.extend([np.log2(prev[2] / cur[2]), np.log2(prev[3] / cur[3])])
        sel[0].extend([float("nan"), float("nan")])
    header = ["study", "steps or m", "pressure error", "settlement error", "wall s", "cells",
              "pressure order", "settlement order"]
    stamp = f"Generated {datetime.date.today()} by `{command}` (1 MPI rank)"
    write_csv(DOCS / f"{stem}.csv", header, rows, stamp)
    if dim == 2:
        title, meshes = "Terzaghi's consolidation", ("mesh refinement 2", "")
    else:
        title, meshes = ("Terzaghi's consolidation in a 3D column (tetrahedra)",
                         ("mesh size 0.05", " Uniform refinement of a mesh of size 0.125."))
    text = [f"# {title}\n\n{stamp}. Relative L² error of the pressure over the "
            "cells and relative error of the settlement of the top (to the total settlement) at "
            f"t = 20 s (T_v = 0.21). *time*: {meshes[0]}, against the exact series. "
            "*space*: 4 steps, against the exact solution of the time-discrete problem."
            f"{meshes[1]}\n\n",
            markdown_table(header, rows)]
    (DOCS / f"{stem}.md").write_text("".join(text))
    figure(rows, stem)


def figure(rows, stem: str) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    for ax, kind, order, xlabel in ((axes[0], "time", 1, "Δt (s)"),
                                    (axes[1], "space", 2, "h / h₀")):
        sel = [r for r in rows if r[0] == kind]
        x = np.array([20.0 / r[1] if kind == "time" else 0.5 ** r[1] for r in sel])
        for k, name in ((2, "pressure"), (3, "settlement")):
            ax.loglog(x, [r[k] for r in sel], "o-", label=name)
        y0 = sel[0][2]
        ax.loglog(x, y0 * (x / x[0]) ** order, "k--", label=f"order {order}")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative error")
        ax.set_title(f"Terzaghi{' 3D' if stem.endswith('3d') else ''}, {kind}")
        ax.grid(alpha=0.3, which="both")
        ax.legend()
    path = DOCS / f"{stem}.png"
    fig.savefig(path, dpi=100, bbox_inches="tight")
    assert path.stat().st_size < 300 * 1024


if __name__ == "__main__":
    main()
