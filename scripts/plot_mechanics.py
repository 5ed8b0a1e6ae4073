"""Picture of a mechanics run: warped duplicated-node mesh coloured by |u|, fracture states.

Run after ``poromech run`` (``make run`` writes ``results/six_fractures_mechanics``)::

    python scripts/plot_mechanics.py results/six_fractures_mechanics \
        docs/images/six_fractures_mechanics.png
"""

from __future__ import annotations

import argparse
import csv
import json
from pathlib import Path

import h5py
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.tri import Triangulation  # noqa: E402

COLORS = {"open": "tab:blue", "stick": "tab:green", "slip": "tab:red"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", type=Path)
    parser.add_argument("image", type=Path)
    parser.add_argument("--warp", type=float, default=20.0, help="displacement magnification")
    args = parser.parse_args()
    with h5py.File(args.results / "displacement.h5") as f:
        x = np.asarray(f["Mesh/mesh/geometry"])[:, :2]
        cells = np.asarray(f["Mesh/mesh/topology"])
        times = sorted(f["Function/u"].keys(), key=float)
        u = np.asarray(f["Function/u"][times[-1]])[:, :2]
    rows = list(csv.DictReader(open(args.results / "fractures.csv")))
    last = max(float(r["time"]) for r in rows)
    rows = [r for r in rows if float(r["time"]) == last]
    fig, ax = plt.subplots(figsize=(9, 4.8))
    xw = x + args.warp * u
    tri = Triangulation(xw[:, 0], xw[:, 1], cells)
    mag = np.linalg.norm(u, axis=1) * 1e3
    pc = ax.tripcolor(tri, mag, shading="gouraud", cmap="viridis")
    ax.triplot(tri, lw=0.1, color="k", alpha=0.3)
    fig.colorbar(pc, ax=ax, label="|u| (mm)", shrink=0.8)
    for state, color in COLORS.items():
        pts = np.array([[float(r["x"]), float(r["y"])] for r in rows if r["state"] == state])
        if len(pts):
            ax.plot(pts[:, 0], pts[:, 1], "o", ms=2.5, color=color, label=state)
    ax.set_aspect("equal")
    name = json.loads((args.results / "summary.json").read_text())["scene"]
    ax.set_title(f"{name}: t = {last:g} s, displacement ×{args.warp:g}, "
                 "fracture states")
    ax.legend(loc="lower left", fontsize=8, ncol=3)
    fig.tight_layout()
    args.image.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.image, dpi=100)


if __name__ == "__main__":
    main()
