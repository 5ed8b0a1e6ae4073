"""A parameter study with poromech's Python API: the friction coefficient of an inclined crack.

The shipped scene ``inclined_crack_slip`` is a crack of half-length b at ψ = 20° to a remote
compression σ, with the exact far field imposed on the box. For each friction coefficient F the
scene is loaded with overrides, run, and its ``fractures.csv`` read back; the slip along the crack
is compared with the exact one, g(ξ) = 4 (1 - ν²)/E · σ sin ψ (cos ψ - F sin ψ) · √(ξ (2b - ξ)),
zero (stick) for F ≥ cot ψ (Phan et al. 2003). Uses only the API of docs/api.md::

    .venv/bin/python scripts/study_example.py                # writes docs/api/friction_sweep.*
    .venv/bin/python scripts/study_example.py --values 0 1 3 --out /tmp/study --set degree=1
"""

import poromech  # noqa: F401, I001  (first: loads MPI before DOLFINx/PETSc, docs/api.md)

import argparse
import csv
from pathlib import Path

import numpy as np

from poromech.scene.loading import load_scene
from poromech.io.results import open_results
from poromech.run import run_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = "inclined_crack_slip"
VALUES = (0.0, 0.5, 1.0, 1.5, 2.0, 2.5, 3.0)


def run_one(friction: float, outdir: Path, extra: list[str]) -> dict:
    """Run the scene with friction coefficient ``friction``; the slip along the crack."""
    overrides = [f"parameters.F={friction}", f"contact.friction_coefficient={friction}", *extra]
    scene = load_scene(SCENE, overrides)
    summary = run_scene(scene, outdir)
    rows = open_results(outdir).fractures(time=scene.time.end if scene.time else 0.0)
    p = dict(scene.parameters)
    return {"F": friction, "status": summary["status"], "s": rows["s"],
            "slip": np.abs(rows["jump_t"]), "state": rows["state"],
            "exact": exact_slip(rows["s"], p["b"], p["psi"], p["sigma"], friction, p["E"],
                                p["nu"]),
            "iterations": sum(s["iterations"] for s in summary["solves"]), "parameters": p}


def exact_slip(xi, b: float, psi: float, sigma: float, friction: float, E: float, nu: float):
    """Exact slip (m) at distance ``xi`` from the crack's first end (plane strain, mode II)."""
    tau = max(sigma * np.sin(psi) * (np.cos(psi) - friction * np.sin(psi)), 0.0)
    return 4 * (1 - nu**2) / E * tau * np.sqrt(np.clip(xi * (2 * b - xi), 0.0, None))


def write_csv(results: list[dict], path: Path) -> None:
    """One row per friction coefficient: peak slip (poromech, exact), slipping faces, error."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["F", "status", "max_slip", "max_slip_exact", "slip_faces", "faces",
                    "rel_l2_error", "newton_iterations"])
        for r in results:
            scale = max(np.linalg.norm(r["exact"]), 1e-300)
            err = np.linalg.norm(r["slip"] - r["exact"]) / scale if r["exact"].any() else 0.0
            w.writerow([r["F"], r["status"], f"{r['slip'].max():.6e}",
                        f"{r['exact'].max():.6e}", int((r["state"] == "slip").sum()),
                        len(r["state"]), f"{err:.3e}", r["iterations"]])


def plot(results: list[dict], path: Path) -> None:
    """Slip along the crack for each F, and the peak slip against F."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 3.8))
    colors = plt.cm.viridis(np.linspace(0, 0.9, len(results)))
    for r, c in zip(results, colors, strict=True):
        order = np.argsort(r["s"])
        ax1.plot(r["s"][order], 1e3 * r["exact"][order], "-", color=c, lw=1)
        ax1.plot(r["s"], 1e3 * r["slip"], "o", color=c, ms=3, label=f"F = {r['F']:g}")
    ax1.set(xlabel="distance along the crack ξ (m)", ylabel="slip |jump_t| (mm)",
            title="slip along the crack (dots: poromech, lines: exact)")
    ax1.legend(fontsize=7, ncol=2)
    f = np.array([r["F"] for r in results])
    ax2.plot(f, [1e3 * r["slip"].max() for r in results], "o", label="poromech (largest face)")
    p, first = results[0]["parameters"], results[0]
    s0 = first["s"][np.argmin(np.abs(first["s"] - p["b"]))]  # the face nearest the centre
    fd = np.linspace(f.min(), f.max(), 200)
    exact = [exact_slip(s0, p["b"], p["psi"], p["sigma"], x, p["E"], p["nu"]) for x in fd]
    ax2.plot(fd, 1e3 * np.asarray(exact), "-", label=f"exact at ξ = {s0:.3g} m")
    ax2.set(xlabel="friction coefficient F", ylabel="peak slip (mm)",
            title="peak slip against F (stick for F ≥ cot ψ)")
    ax2.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--values", type=float, nargs="+", default=VALUES, help="values of F")
    parser.add_argument("--out", type=Path, default=ROOT / "results" / "friction_sweep",
                        help="directory of the runs (one subdirectory per value)")
    parser.add_argument("--docs", type=Path, default=ROOT / "docs" / "api",
                        help="where friction_sweep.csv and .png go")
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="further scene overrides, e.g. --set degree=1")
    args = parser.parse_args(argv)
    results = [run_one(f, args.out / f"F_{f:g}", args.set) for f in args.values]
    write_csv(results, args.docs / "friction_sweep.csv")
    plot(results, args.docs / "friction_sweep.png")
    print(f"{len(results)} runs; wrote {args.docs / 'friction_sweep.csv'} and .png")


if __name__ == "__main__":
    main()
