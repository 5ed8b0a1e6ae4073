"""What the benchmark scripts share for their tables: number format, CSV with comment lines.

Every script of ``scripts/`` writes its rows as a CSV under ``docs/`` whose first lines are
``# `` comments (the commands that made it) and can redraw its report from that CSV.
"""

from __future__ import annotations

import csv
from pathlib import Path


def fmt(v) -> str:
    """Three significant digits for floats, the value otherwise."""
    return f"{v:.3g}" if isinstance(v, float) else str(v)


def number(v):
    """A CSV field as a bool, int or float where it is one, else unchanged."""
    if not isinstance(v, str):
        return v
    if v in ("True", "False"):
        return v == "True"
    for kind in (int, float):
        try:
            return kind(v)
        except ValueError:
            pass
    return v


def read_csv(path: Path, text: tuple[str, ...] = ()) -> tuple[list[str], list[dict]]:
    """The comment lines (without ``# ``) and the rows of a CSV, numbers parsed.

    Columns in ``text`` stay strings. A missing file has no comments and no rows.
    """
    if not path.exists():
        return [], []
    lines = path.read_text().splitlines()
    comments = [ln[2:] for ln in lines if ln.startswith("# ")]
    rows = list(csv.DictReader(ln for ln in lines if not ln.startswith("#")))
    return comments, [{k: v if k in text else number(v) for k, v in r.items()} for r in rows]


def write_csv(path: Path, comments: list[str], fields: list[str], rows: list[dict]) -> None:
    """Rows (the ``fields`` columns) under ``# `` comment lines."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as fh:
        for c in comments:
            fh.write(f"# {c}\n")
        w = csv.DictWriter(fh, fields, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
