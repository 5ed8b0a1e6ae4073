"""Shared helpers of the flow benchmark scripts: CSV, line norms, Markdown tables, figures."""

from __future__ import annotations

import csv
import datetime
import shlex
import sys
from pathlib import Path

import numpy as np

from poromech.io.probes import line_differences, read_csv  # noqa: F401  (re-exported for scripts)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "flow"


def generated(command: str, ranks: int) -> str:
    """The dated provenance line that starts every generated document.

    The options the script was run with are added when ``command`` does not hold them: a
    table made with fewer levels said it came from the full command.
    """
    given = shlex.join(sys.argv[1:])
    if given and given not in command:
        command = f"{command} {given}"
    return f"Generated {datetime.date.today()} by `{command}` ({ranks} MPI rank(s))"


def write_csv(path: Path, header: list[str], rows: list[list], comment: str | None = None) -> None:
    """Write rows with a header, after an optional ``# comment`` line (e.g. the provenance)."""
    with open(path, "w", newline="") as f:
        if comment is not None:
            f.write(f"# {comment}\n")
        w = csv.writer(f)
        w.writerow(header)
        for r in rows:
            w.writerow([f"{v:.6g}" if isinstance(v, float) else v for v in r])


def markdown_table(header: list[str], rows: list[list], fmt: str = ".3g") -> str:
    """A GitHub Markdown table."""
    def cell(v):
        if isinstance(v, float):
            return "–" if np.isnan(v) else format(v, fmt)
        return str(v)

    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def save_figure(fig, path: Path, limit_kb: int = 300) -> None:
    """Save a PNG and check that it stays small."""
    fig.savefig(path, dpi=110, bbox_inches="tight")
    size = path.stat().st_size / 1024
    if size > limit_kb:
        raise RuntimeError(f"{path.name} is {size:.0f} KB (limit {limit_kb} KB)")


def order_figure(path: Path, x, curves: dict[str, np.ndarray], order: int, reference: str,
                 xlabel: str, ylabel: str, title: str) -> None:
    """Log-log errors against a step size, with the expected order, saved as a small PNG.

    The order line starts at the first point of the first curve.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 4.2))
    for label, y in curves.items():
        ax.loglog(x, y, "o-", label=label)
    y0 = next(iter(curves.values()))[0]
    ax.loglog(x, y0 * (x / x[0]) ** order, "k--", label=reference)
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.set_title(title)
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=8)
    save_figure(fig, path)
