"""What the penny-crack studies share: a case in a child process, number format, the figure.

``scripts/penny_convergence.py`` (Sneddon, pressurized) and ``scripts/penny_shear.py`` (Segedin,
in contact) run each case in its own process (``--case``) and draw the error against unknowns
and against run time.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from report_common import fmt

__all__ = ["child_case", "error_figure", "fmt"]

ROOT = Path(__file__).resolve().parents[1]


def child_case(script: str, sets: list[str]) -> dict:
    """Run ``script --case sets`` in a new process; the JSON record it prints last."""
    cmd = [sys.executable, script, "--case", json.dumps(sets)]
    proc = subprocess.run(cmd, capture_output=True, text=True, cwd=ROOT, timeout=3600)
    if proc.returncode != 0:
        raise RuntimeError(proc.stderr[-2000:])
    return json.loads(proc.stdout.strip().splitlines()[-1])


def error_figure(curves: list[tuple[str, str, str, list[dict]]], ylabel: str, title: str,
                 path: Path, dpi: int = 110, legend_size: int = 8) -> None:
    """Error (``l2``) against unknowns and run time, a line per (label, style, color, rows)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for label, style, color, seq in curves:
        for ax, key in zip(axes, ("dofs", "time_total"), strict=True):
            ax.loglog([r[key] for r in seq], [r["l2"] for r in seq], style, color=color,
                      label=label)
    axes[0].set_xlabel("unknowns")
    axes[1].set_xlabel("run time (s), mesh + set-up + solve")
    for ax in axes:
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=legend_size)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
