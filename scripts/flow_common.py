"""Shared helpers of the flow benchmark scripts: CSV in/out, line norms, Markdown tables."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from poromech.probes import line_differences, read_csv  # noqa: F401  (re-exported for scripts)

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs" / "flow"


def write_csv(path: Path, header: list[str], rows: list[list]) -> None:
    """Write rows with a header."""
    with open(path, "w", newline="") as f:
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
