"""Outputs of the shipped scenes, run and compared with those of another version of poromech.

A redesign must not change a number. This script runs a fixed list of cases (every shipped scene,
and the six-fracture scenes with every formulation and degree) into one directory per case, and
compares two such collections:

* ``summary.json``: every integer, string and boolean (iteration, ``g`` and factorization counts,
  reasons, states, sizes) identical; timings, versions and paths are left out;
* every ``*.csv`` (``fractures.csv``, probes, ...): the same rows and columns, every number equal
  to the precision it is printed with (a rounding flip of the last printed digit allowed);
* every dataset of every HDF5 file of the XDMF series: equal to ``--rtol`` (1e-12) relative to
  the largest value of the dataset, the points and cells of each series (and the fields on
  them) taken in an order that depends on the geometry only (cells by centroid, points by first
  use), so that versions numbering the same mesh differently compare equal. The checkpoint
  (``checkpoint.h5``) is restart state, not a result, and its layout may change between
  versions (its displacements went from rows per cell to rows per node on 2026-11-29): it is
  left out; the restart tests compare restarted runs with uninterrupted ones.

Usage (the reference made with the other version's environment, e.g. a clone at that commit)::

    python scripts/regression_outputs.py run OUT [--only NAME ...] [--ranks 2]
    python scripts/regression_outputs.py compare REF NEW [--markdown docs/regression.md]
        [--rtol 1e-12] [--csv-rtol R]   # 2 ranks: --rtol 1e-7 --csv-rtol 1e-7 (see below)

On 2 ranks the coupled runs are not reproducible bitwise from one run to the next (MUMPS'
parallel factorization): compare them with tolerances above their own run-to-run spread.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time
import xml.etree.ElementTree as ET
from pathlib import Path

import h5py
import numpy as np

FORMULATIONS = ("mixed", "stabilized_mixed", "mean_nitsche", "nitsche")
#: Restart state, not a result: not compared (see the module docstring).
CHECKPOINT = "checkpoint.h5"
SHIPPED = ("flemisch_case1", "flemisch_case2", "flemisch_case2_csv", "flow_barrier_conduit",
           "flow_barrier_conduit_cut", "flow_six_fractures", "inclined_crack_frictionless",
           "inclined_crack_slip", "inclined_crack_stick", "injection", "six_fractures",
           "six_fractures_mechanics", "six_fractures_msh", "sneddon", "terzaghi")


def cases() -> dict[str, list[str]]:
    """Case name -> ``poromech run`` arguments."""
    import yaml

    out = {name: [name] for name in SHIPPED}
    root = Path(__file__).resolve().parents[1] / "configs"
    for scene in ("six_fractures", "six_fractures_mechanics"):
        raw = yaml.safe_load((root / f"{scene}.yaml").read_text())
        shipped = (raw["contact"]["formulation"], raw.get("degree", 1))
        for f in FORMULATIONS:
            for p in (1, 2):
                if scene == "six_fractures" and (f, p) == shipped:
                    continue  # the shipped scene itself
                out[f"{scene}-{f}-P{p}"] = [scene, "--set", f"contact.formulation={f}",
                                            "--set", f"degree={p}"]
    for theta in (0, 1):
        out[f"six_fractures_mechanics-nitsche-theta{theta}"] = [
            "six_fractures_mechanics", "--set", f"contact.theta={theta}"]
    out["inclined_crack_slip-tresca"] = ["inclined_crack_slip", "--set", "contact.friction=tresca",
                                         "--set", "contact.slip_bound=1e6"]
    return out


def run(out: Path, only: list[str] | None, ranks: int) -> None:
    """Run the cases into ``out/<case>`` with the python running this script."""
    out.mkdir(parents=True, exist_ok=True)
    timings = {}
    for name, args in cases().items():
        if only and name not in only:
            continue
        cmd = [sys.executable, "-m", "poromech", "run", *args, "-o", str(out / name),
               "--overwrite", "-q"]
        if ranks > 1:
            cmd = [str(Path(sys.executable).parent / "mpirun"), "-n", str(ranks), *cmd]
        t0 = time.perf_counter()
        proc = subprocess.run(cmd, capture_output=True, text=True,
                              env={**os.environ, "PYTHONHASHSEED": "0"})
        timings[name] = round(time.perf_counter() - t0, 1)
        print(f"{name}: exit {proc.returncode}, {timings[name]} s", flush=True)
        if proc.returncode != 0:
            print(proc.stderr[-2000:], flush=True)


#: summary.json keys whose values change from run to run or from version to version.
VOLATILE = {"wall_time", "poromech_version", "time_assembly", "time_linear", "mechanics_seconds",
            "darcy_seconds", "solve_seconds", "seconds", "setup_seconds", "factor_seconds",
            "schur_seconds", "face_seconds", "output", "path"}


def _walk(a, b, path: str, diffs: list[str]) -> None:
    """Exact comparison of the discrete entries of two JSON values."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k in VOLATILE or "seconds" in k or k.startswith("time_"):
                continue
            if k not in a:  # an output added since the reference: listed, not a difference
                ADDED.add(f"summary {path}/{k}")
                continue
            if k not in b:
                diffs.append(f"{path}/{k}: only in the reference")
                continue
            _walk(a[k], b[k], f"{path}/{k}", diffs)
    elif isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            diffs.append(f"{path}: length {len(a)} != {len(b)}")
            return
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            _walk(x, y, f"{path}[{i}]", diffs)
    elif isinstance(a, bool | int | str) or a is None:
        if a != b:
            diffs.append(f"{path}: {a!r} != {b!r}")


#: Outputs of the new version that the reference does not have (summary keys, CSV columns).
ADDED: set[str] = set()


def compare_summary(ref: Path, new: Path) -> list[str]:
    diffs: list[str] = []
    _walk(json.loads(ref.read_text()), json.loads(new.read_text()), "", diffs)
    return diffs


def _digits(text: str) -> float:
    """Half a unit in the last printed digit of a number written in ``text``."""
    mant = text.lower().split("e")[0].lstrip("+-")
    decimals = len(mant.split(".")[1]) if "." in mant else 0
    exp = int(text.lower().split("e")[1]) if "e" in text.lower() else 0
    return 0.5 * 10.0 ** (exp - decimals)


def _column_scales(rows: list[list[str]]) -> list[float]:
    """Largest absolute number of each column (0 for text columns)."""
    scales = [0.0] * max((len(r) for r in rows), default=0)
    for r in rows[1:]:
        for i, v in enumerate(r):
            try:
                scales[i] = max(scales[i], abs(float(v)))
            except ValueError:
                pass
    return scales


def _aligned(ra: list[list[str]], rb: list[list[str]], name: str):
    """The new table's columns in the reference's order (added columns listed in ADDED).

    A ``time`` column added to a table the reference wrote once, at the end of the run (the
    probes of a flow run), keeps the rows of the last time.
    """
    ha, hb = ra[0], rb[0]
    missing = [c for c in ha if c not in hb]
    if missing:
        return None, f"{name}: columns {missing} missing"
    for c in hb:
        if c not in ha:
            ADDED.add(f"{name}: column {c}")
    if "time" in hb and "time" not in ha and len(rb) > 1:
        k = hb.index("time")
        last = max(float(r[k]) for r in rb[1:])
        rb = [hb] + [r for r in rb[1:] if float(r[k]) == last]
    idx = [hb.index(c) for c in ha]
    return [[r[i] for i in idx] for r in rb], None


def compare_csv(ref: Path, new: Path, rtol: float | None = None) -> tuple[list[str], float]:
    """Differences beyond the printed precision, and the largest difference in printed units.

    With ``rtol``: beyond ``rtol`` times the column's largest value, in those units. Columns are
    matched by name (see :func:`_aligned`).
    """
    with open(ref) as fa, open(new) as fb:
        ra, rb = list(csv.reader(fa)), list(csv.reader(fb))
    if ra and rb:
        rb, err = _aligned(ra, rb, new.name)
        if err:
            return [err], math.inf
    if len(ra) != len(rb):
        return [f"{new.name}: {len(ra)} rows != {len(rb)}"], math.inf
    scales = _column_scales(ra) if rtol is not None else None
    diffs, worst = [], 0.0
    for i, (x, y) in enumerate(zip(ra, rb, strict=True)):
        if len(x) != len(y):
            diffs.append(f"{new.name} row {i}: {len(x)} columns != {len(y)}")
            continue
        for j, (a, b) in enumerate(zip(x, y, strict=True)):
            if a == b:
                continue
            try:
                fa_, fb_ = float(a), float(b)
            except ValueError:
                diffs.append(f"{new.name} row {i}: {a!r} != {b!r}")
                continue
            if scales is not None:
                units = abs(fa_ - fb_) / (rtol * scales[j]) if scales[j] > 0 else math.inf
            else:
                units = abs(fa_ - fb_) / (2 * max(_digits(a), _digits(b)))
            worst = max(worst, units)
            if units > 1.0 + 1e-9:
                diffs.append(f"{new.name} row {i}: {a} != {b}")
    return diffs, worst


class Canonical:
    """The points and cells of an XDMF series in an order that depends on its geometry only.

    Cells are sorted by centroid (x, then y, then z, each rounded to ``TOLERANCE`` times the
    mesh's size so that round-off does not reorder them), points by their first use in the sorted
    cells: two files holding the same mesh and fields in different numberings (e.g. written on
    different numbers of ranks, or by versions that number the displacement nodes differently)
    give the same arrays.

    Args:
        run: Output directory.
        stem: The series (``displacement``, ``fractures``, ...).
    """

    #: Centroids closer than this, relative to the mesh's size, sort as equal coordinates.
    TOLERANCE = 1e-9

    def __init__(self, run: Path, stem: str):
        with h5py.File(run / f"{stem}.h5") as f:
            points, cells = f["mesh/points"][()], f["mesh/cells"][()]
        centroids = points[cells].mean(axis=1)
        size = float(np.ptp(points, axis=0).max()) if len(points) else 1.0
        grid = np.round(centroids / (self.TOLERANCE * size))  # round-off does not reorder
        self.cells = np.lexsort(grid.T[::-1])
        used, first = np.unique(cells[self.cells].ravel(), return_index=True)
        unused = np.setdiff1d(np.arange(len(points)), used)
        self.points = np.concatenate([used[np.argsort(first)], unused])
        self.label = np.empty(len(points), dtype=np.int64)
        self.label[self.points] = np.arange(len(points))
        self.centers = {att.get("Name"): att.get("Center") for att in
                        ET.parse(run / f"{stem}.xdmf").getroot().iter("Attribute")}

    def __call__(self, name: str, values: np.ndarray) -> np.ndarray:
        """A dataset of the series' files in the canonical order."""
        if name == "mesh/points" or self.centers.get(name) == "Node":
            return values[self.points]
        if name == "mesh/cells":
            return self.label[values[self.cells]]
        if self.centers.get(name) == "Cell":
            return values[self.cells]
        return values


def series_of(run: Path, file: Path) -> Canonical | None:
    """The canonical order of the XDMF series a file of ``run`` belongs to (None: no series)."""
    top = file.relative_to(run).parts[0]
    stem = top[: -len("_steps")] if top.endswith("_steps") else Path(top).stem
    return Canonical(run, stem) if (run / f"{stem}.xdmf").exists() else None


class SeriesOrders:
    """The :class:`Canonical` orders of the series of two runs, made once per series."""

    def __init__(self, ref: Path, new: Path):
        self.ref, self.new, self.cache = ref, new, {}

    def __call__(self, f: Path, g: Path) -> tuple[Canonical | None, Canonical | None]:
        """The orders of the series that file ``f`` of the reference and ``g`` belong to."""
        key = f.relative_to(self.ref).parts[0]
        if key not in self.cache:
            self.cache[key] = (series_of(self.ref, f), series_of(self.new, g))
        return self.cache[key]


def compare_h5(ref: Path, new: Path, rtol: float, orders=(None, None)) -> tuple[list[str], float]:
    """Datasets equal to ``rtol`` relative to their largest value; and the largest such error.

    ``orders``: the :class:`Canonical` orders of the two files' series (None: as stored).
    """
    diffs, worst = [], 0.0
    keep = (lambda n, v: v)  # noqa: E731
    order_a, order_b = (o or keep for o in orders)
    with h5py.File(ref) as fa, h5py.File(new) as fb:
        names: list[str] = []
        fa.visititems(lambda n, o: names.append(n) if isinstance(o, h5py.Dataset) else None)
        for n in names:
            if n not in fb:
                diffs.append(f"{new.name}:{n} missing")
                continue
            a, b = np.asarray(fa[n]), np.asarray(fb[n])
            if a.shape == b.shape:
                a, b = order_a(n, a), order_b(n, b)
            if a.shape != b.shape:
                diffs.append(f"{new.name}:{n} shape {a.shape} != {b.shape}")
                continue
            scale = float(np.max(np.abs(a))) if a.size else 0.0
            err = float(np.max(np.abs(a - b))) / scale if scale > 0 else float(np.abs(b).max(
                initial=0.0))
            worst = max(worst, err)
            if err > rtol:
                diffs.append(f"{new.name}:{n} differs by {err:.2e} relative")
    return diffs, worst


def compare(ref: Path, new: Path, rtol: float, csv_rtol: float | None = None) -> list[dict]:
    """One row per case of ``ref``."""
    rows = []
    for case in sorted(p.name for p in ref.iterdir() if p.is_dir()):
        a, b = ref / case, new / case
        row = {"case": case, "summary": "", "csv": 0.0, "h5": 0.0, "diffs": []}
        if not (b / "summary.json").exists():
            row["diffs"].append("not run")
            rows.append(row)
            continue
        d = compare_summary(a / "summary.json", b / "summary.json")
        row["summary"] = "identical" if not d else f"{len(d)} differences"
        row["diffs"] += d
        orders = SeriesOrders(a, b)
        for kind, check in (("csv", lambda f, g: compare_csv(f, g, csv_rtol)),
                            ("h5", lambda f, g, o=orders: compare_h5(f, g, rtol, o(f, g)))):
            for f in sorted(a.rglob(f"*.{kind}")):
                if f.name == CHECKPOINT:
                    continue
                g = b / f.relative_to(a)
                if not g.exists():
                    row["diffs"].append(f"{f.relative_to(a)} missing")
                    continue
                d, w = check(f, g)
                row[kind] = max(row[kind], w)
                row["diffs"] += d
        rows.append(row)
    return rows


def markdown(rows: list[dict], rtol: float, title: str, csv_rtol: float | None = None) -> str:
    how = ("every number to its printed precision (largest difference in units of the last "
           "printed digit)" if csv_rtol is None else
           f"every number to {csv_rtol:g} of its column's largest value (largest difference in "
           "those units)")
    unit = "last digits" if csv_rtol is None else f"× {csv_rtol:g} scale"
    lines = [f"## {title}", "",
             f"`summary.json`: discrete entries (counts, reasons, states, sizes) compared exactly. "
             f"CSV: {how}. HDF5 (XDMF series): every dataset to {rtol:g} relative to its "
             "largest value (largest relative difference shown).", "",
             f"| case | summary.json | CSV ({unit}) | HDF5 (relative) | verdict |",
             "|---|---|---|---|---|"]
    for r in rows:
        ok = "equal" if not r["diffs"] else f"**{len(r['diffs'])} differences**"
        lines.append(f"| {r['case']} | {r['summary'] or '-'} | {r['csv']:.2g} | {r['h5']:.1e} "
                     f"| {ok} |")
    if ADDED:
        lines += ["", "Outputs added since the reference (not compared): "
                  + "; ".join(sorted(ADDED)) + "."]
    bad = [r for r in rows if r["diffs"]]
    if bad:
        lines += ["", "Differences:", ""]
        for r in bad:
            lines += [f"* {r['case']}: " + "; ".join(r["diffs"][:5])]
    return "\n".join(lines) + "\n"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run")
    r.add_argument("out", type=Path)
    r.add_argument("--only", nargs="*")
    r.add_argument("--ranks", type=int, default=1)
    c = sub.add_parser("compare")
    c.add_argument("ref", type=Path)
    c.add_argument("new", type=Path)
    c.add_argument("--rtol", type=float, default=1e-12)
    c.add_argument("--csv-rtol", type=float, default=None,
                   help="compare CSV numbers to this fraction of their column's largest value "
                        "instead of to their printed digits (runs that differ in round-off)")
    c.add_argument("--markdown", type=Path, help="append the table to this file")
    c.add_argument("--title", default="Outputs against the reference version")
    args = ap.parse_args()
    if args.cmd == "run":
        run(args.out, args.only, args.ranks)
        return
    rows = compare(args.ref, args.new, args.rtol, args.csv_rtol)
    text = markdown(rows, args.rtol, args.title, args.csv_rtol)
    if args.markdown:
        with open(args.markdown, "a") as fh:
            fh.write(text + "\n")
    print(text)
    sys.exit(1 if any(r["diffs"] for r in rows) else 0)


if __name__ == "__main__":
    main()
