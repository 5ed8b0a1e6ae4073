"""Fracture networks from CSV files, a common exchange format of DFN generators.

Two layouts, told apart by the header (column names are case-insensitive, in any order):

* one row per segment, ``fracture,x0,y0,x1,y1``: the rows of a fracture follow each other, each
  starting where the previous one ends; its polyline runs from ``(x0, y0)`` of its first row.
  Without a ``fracture`` column (``x0,y0,x1,y1``) every row is a fracture of its own, named by
  its number (1, 2, ...), as unnamed YAML fractures are;
* one row per polyline point, ``fracture,x,y``: the rows of a fracture follow each other, in the
  order of its polyline.

The order of a fracture's points fixes ``n⁺`` (the left normal,
:mod:`poromech.geometry.plane`). Blank
lines and lines starting with ``#`` are skipped. Only reading and the row rules are checked
here; the network is then checked like a YAML one (:func:`poromech.geometry.plane.check_geometry`).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

import numpy as np
import numpy.typing as npt

__all__ = ["MAX_BYTES", "FractureFileError", "read_fracture_csv"]

#: Largest fracture file read (bytes).
MAX_BYTES = 10_000_000
#: Consecutive segments of a fracture connect when the gap is below this fraction of the
#: coordinates' magnitude (the geometry's zero-length tolerance is 1e-9 of the domain size).
GAP_TOL = 1e-9

_LAYOUTS = {
    ("fracture", "x0", "y0", "x1", "y1"): "segments",
    ("x0", "y0", "x1", "y1"): "segments",
    ("fracture", "x", "y"): "points",
}

Network = tuple[tuple[str, npt.NDArray[np.float64]], ...]


class FractureFileError(ValueError):
    """A fracture file that cannot be read; the message is one line (with the line number)."""


def _text(path: Path) -> str:
    try:
        with open(path, "rb") as fh:
            data = fh.read(MAX_BYTES + 1)
    except OSError as err:
        raise FractureFileError(f"cannot be read: {err.strerror or err}") from None
    if len(data) > MAX_BYTES:
        raise FractureFileError(f"is larger than {MAX_BYTES / 1e6:g} MB")
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise FractureFileError("is not UTF-8 text (allowed: a CSV text file)") from None
    if "\x00" in text:  # valid UTF-8, but a binary file (csv would call it empty or fail)
        raise FractureFileError("holds NUL bytes, as a binary file does (allowed: a CSV text "
                                "file)")
    return text


def _rows(text: str):
    """(line number, cells) of the lines that are not blank or comments."""
    for number, line in enumerate(text.splitlines(), start=1):
        if line.strip() and not line.lstrip().startswith("#"):
            yield number, [c.strip() for c in next(csv.reader(io.StringIO(line)))]


def _header(cells: list[str], number: int) -> tuple[str, list[int], int | None]:
    """The layout, the position of its coordinate columns and of the name column (if any)."""
    names = [c.lower() for c in cells]
    for columns, layout in _LAYOUTS.items():
        if sorted(names) == sorted(columns):
            name_col = names.index("fracture") if "fracture" in names else None
            return layout, [names.index(c) for c in columns if c != "fracture"], name_col
    raise FractureFileError(f"line {number}: header {','.join(cells)!r} is not allowed (allowed: "
                            "fracture,x0,y0,x1,y1 or x0,y0,x1,y1 (a row per segment) or "
                            "fracture,x,y (a row per point))")


def _number(text: str, number: int, column: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise FractureFileError(f"line {number}: {column} = {text!r} is not a number") from None
    if not math.isfinite(value):
        raise FractureFileError(f"line {number}: {column} = {text} must be finite")
    return value


def read_fracture_csv(path: Path) -> Network:
    """Read the fracture polylines of a CSV file.

    Returns:
        ``(name, points)`` per fracture, in file order; ``points`` has shape ``(k + 1, 2)`` (m).

    Raises:
        FractureFileError: Unreadable file, unknown header, a malformed row, the rows of a
            fracture not together, or a segment not starting where the previous one ended.
    """
    rows = _rows(_text(Path(path)))
    first = next(rows, None)
    if first is None:
        raise FractureFileError("is empty (allowed: a header line, then one row per segment or "
                                "point)")
    header_line, header = first
    layout, cols, name_col = _header(header, header_line)
    labels = [c for c in ("x0", "y0", "x1", "y1") if layout == "segments"] or ["x", "y"]
    fractures: dict[str, list] = {}
    lines: dict[str, list[int]] = {}
    last = None
    for number, cells in rows:
        if len(cells) != len(header):
            raise FractureFileError(f"line {number}: {len(cells)} values (allowed: "
                                    f"{len(header)}, as in the header)")
        name = cells[name_col] if name_col is not None else str(len(fractures) + 1)
        if not name:
            raise FractureFileError(f"line {number}: the fracture name is empty")
        if name in fractures and name != last:
            raise FractureFileError(f"line {number}: fracture '{name}' continues after other "
                                    f"fractures (line {lines[name][-1]}) (allowed: the rows of a "
                                    "fracture together)")
        values = [_number(cells[c], number, lab) for c, lab in zip(cols, labels, strict=True)]
        fractures.setdefault(name, []).append(values)
        lines.setdefault(name, []).append(number)
        last = name
    if not fractures:
        raise FractureFileError(f"has a header (line {header_line}) and no fracture rows "
                                "(allowed: one row per segment or point; a scene without "
                                "fractures leaves geometry.fractures out)")
    return tuple((name, _polyline(name, rows_, lines[name], layout))
                 for name, rows_ in fractures.items())


def _polyline(name: str, rows: list, lines: list[int], layout: str) -> npt.NDArray[np.float64]:
    """The points of one fracture from its rows."""
    data = np.array(rows, dtype=np.float64)
    if layout == "points":
        if len(data) < 2:
            raise FractureFileError(f"line {lines[0]}: fracture '{name}' has 1 point (allowed: "
                                    "at least 2 rows per fracture)")
        return data
    starts, ends = data[:, :2], data[:, 2:]
    scale = max(float(np.abs(data).max()), 1.0)
    gap = np.linalg.norm(starts[1:] - ends[:-1], axis=1)
    if np.any(gap > GAP_TOL * scale):
        i = int(np.argmax(gap > GAP_TOL * scale)) + 1
        raise FractureFileError(
            f"line {lines[i]}: segment of fracture '{name}' starts at ({starts[i, 0]:g}, "
            f"{starts[i, 1]:g}), not where its previous segment ends ({ends[i - 1, 0]:g}, "
            f"{ends[i - 1, 1]:g}) (allowed: consecutive, connected segments per fracture)")
    return np.vstack([starts, ends[-1:]])
