"""A conduit crossing a blocking barrier against the same conduit cut short of it.

Runs the three variants of ``configs/flow_barrier_conduit.yaml`` (the conduit crossing the
barrier; cut 1 mm short of it, ``configs/flow_barrier_conduit_cut.yaml``; the barrier alone) on
the refinement levels ``--levels`` and reports the outflow on the right, the pressure jump
across the barrier on ``y = 0.5`` (``p_m`` 0.1 mm either side), the differences between the
crossing and the cut conduit, CG iterations and the mass balance. Writes
``docs/flow/barrier.csv``, ``barrier.md`` and ``barrier.png``.

    python scripts/flow_barrier.py [--levels 0 1 2 3]
"""

from __future__ import annotations

import argparse

import dolfinx_solver  # noqa: F401  (MPI before PETSc/DOLFINx)

import numpy as np
from flow_common import DOCS, generated, markdown_table, save_figure, write_csv
from mpi4py import MPI

from poromech.verification.flow import (
    BARRIER_VARIANTS,
    barrier_metrics,
    barrier_scene,
    line_pressure,
    solve_scene,
)

COMMAND = "python scripts/flow_barrier.py"
#: Element size along the fractures at refinement 0 (``mesh.fracture_size`` of the scenes, m).
FRACTURE_SIZE = 0.025
PROFILE_SAMPLES = 1001


def run_level(comm: MPI.Comm, level: int) -> tuple[dict, dict]:
    """Metrics of every variant at one level, and ``p_m`` along ``y = 0.5`` (collective)."""
    metrics, profiles = {}, {}
    for variant in BARRIER_VARIANTS:
        pb = solve_scene(barrier_scene(variant, level), comm)
        rec = pb.records[-1]
        metrics[variant] = barrier_metrics(pb) | {"iterations": rec.iterations,
                                                  "seconds": rec.seconds}
        profiles[variant] = line_pressure(pb, (0.0, 0.5), (1.0, 0.5), PROFILE_SAMPLES)
        pb.destroy()
    return metrics, profiles


def table_row(level: int, m: dict) -> list:
    """One row of the table: sizes, outflows, jumps and the crossing/cut differences."""
    x, cut, bar = m["crossing"], m["cut"], m["barrier"]
    excess = (x["outflow"] - bar["outflow"]) / (cut["outflow"] - bar["outflow"]) - 1
    return [
        level, FRACTURE_SIZE / 2**level, x["unknowns"], x["outflow"], cut["outflow"],
        bar["outflow"], 100 * (x["outflow"] / cut["outflow"] - 1), 100 * excess,
        100 * (x["outflow"] / bar["outflow"] - 1), x["jump"], cut["jump"],
        100 * (x["jump"] / cut["jump"] - 1), x["iterations"], cut["iterations"],
        max(v["relative_residual"] for v in m.values()),
    ]


HEADER = [
    "refinement", "h_f", "unknowns", "outflow_crossing", "outflow_cut", "outflow_barrier",
    "outflow_vs_cut_pct", "excess_vs_cut_pct", "outflow_vs_barrier_pct", "jump_crossing",
    "jump_cut", "jump_vs_cut_pct", "cg_it_crossing", "cg_it_cut", "mass_balance_rel",
]


def figure(path, rows: np.ndarray, profiles: dict, stamp: str) -> None:
    """``p_m`` on ``y = 0.5`` (finest level) and the crossing/cut differences against ``h``."""
    import matplotlib
    import matplotlib.ticker

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 4))
    x = np.linspace(0.0, 1.0, PROFILE_SAMPLES)
    for (name, p), style in zip(profiles.items(), ("-", "--", ":"), strict=True):
        ax.plot(x, p, style, label=name)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("p_m on y = 0.5 (Pa)")
    ax.set_title(f"profiles, refinement {int(rows[-1, 0])}")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    h = rows[:, 1]
    bx.loglog(h, np.abs(rows[:, 11]), "o-", label="jump, crossing vs cut")
    bx.loglog(h, np.abs(rows[:, 6]), "s-", label="outflow, crossing vs cut")
    bx.loglog(h, np.abs(rows[:, 7]), "^-", label="outflow excess over barrier, vs cut")
    bx.axhline(2.0, color="k", ls="--", lw=0.8, label="2 %")
    bx.set_xticks(h, labels=[f"{v:g}" for v in h])
    bx.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    bx.set_xlabel("element size along the fractures h_f (m)")
    bx.set_ylabel("|relative difference| (%)")
    bx.set_title("crossing conduit against the cut conduit")
    bx.grid(alpha=0.3, which="both")
    bx.legend(fontsize=8)
    fig.text(0.01, -0.02, stamp, fontsize=7)
    save_figure(fig, path)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--levels", type=int, nargs="+", default=[0, 1, 2, 3])
    args = p.parse_args()
    comm = MPI.COMM_WORLD
    rows = []
    for level in args.levels:
        metrics, profiles = run_level(comm, level)
        rows.append(table_row(level, metrics))
        if comm.rank == 0:
            print(dict(zip(HEADER, rows[-1], strict=True)), flush=True)
    if comm.rank != 0:
        return
    stamp = generated(COMMAND + " --levels " + " ".join(map(str, args.levels)), comm.size)
    DOCS.mkdir(parents=True, exist_ok=True)
    write_csv(DOCS / "barrier.csv", HEADER, rows, comment=stamp)
    text = (stamp + ". Outflow on the right (m²/s per unit depth) and `p_m(0.4999, 0.5) - "
            "p_m(0.5001, 0.5)` (Pa) for the conduit crossing the barrier, cut 1 mm short of it, "
            "and the barrier alone; differences of the crossing against the cut conduit in %.\n\n")
    (DOCS / "barrier.md").write_text(text + markdown_table(HEADER, rows, fmt=".5g"))
    figure(DOCS / "barrier.png", np.array(rows, dtype=float), profiles, stamp)


if __name__ == "__main__":
    main()
