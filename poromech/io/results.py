"""Read a run's output directory back as arrays: summary, XDMF series, fracture table, probes.

Serial and independent of DOLFINx: it reads the files that ``poromech run`` writes (see
``docs/outputs.md``) with h5py, the XDMF index and the CSV files::

    import poromech  # first: loads MPI before DOLFINx/PETSc (docs/api.md)
    from poromech.io.results import open_results

    res = open_results("results/six_fractures")
    res.summary["status"]                   # "converged", "running" (killed), "failed", ...
    res.times("fractures")                  # output times (s)
    u = res.series("displacement").at(500.0)["u"]     # (n, 3) on the duplicated-node mesh
    rows = res.fractures(time=500.0)        # fractures.csv rows of that time, column arrays
    rows["jump_n"][rows["fracture"] == "1"]

A run killed at any moment (even with ``kill -9``) is readable: every series lists exactly its
completed output steps.
"""

from __future__ import annotations

import csv
import json
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path

import numpy as np
import numpy.typing as npt
import yaml

from poromech.io.xdmf import Series, read_series

__all__ = ["STATES", "Results", "open_results", "read_table"]

#: Contact-state codes of the ``state`` field (``fractures.xdmf``) and their words
#: (``fractures.csv``).
STATES = ("open", "stick", "slip")

#: Columns of the CSV files that hold words, not numbers.
_TEXT_COLUMNS = {"fracture", "state"}

#: The series a run can write, in the order they are listed.
_SERIES = ("displacement", "fractures", "flow", "fractures_flow")


def read_table(path: str | Path) -> dict[str, npt.NDArray]:
    """A CSV file of poromech (``fractures.csv``, ``probe_<name>.csv``) as column arrays.

    Numbers become float arrays (empty cells NaN); the ``fracture`` and ``state`` columns stay
    strings (fracture names such as ``"1"``, states ``open``/``stick``/``slip``). Rows that a
    killed run left incomplete are left out.
    """
    with open(path, "rb") as fh:
        data = fh.read()
    lines = data[: data.rfind(b"\n") + 1].decode(errors="replace").splitlines(keepends=True)
    reader = csv.reader(line for line in lines if "\0" not in line)
    header = next(reader)
    rows = [r for r in reader if len(r) == len(header)]
    columns = list(zip(*rows, strict=True)) if rows else [()] * len(header)
    out: dict[str, npt.NDArray] = {}
    for name, values in zip(header, columns, strict=True):
        if name in _TEXT_COLUMNS:
            out[name] = np.asarray(values, dtype=str)
        else:
            out[name] = np.array([float(v) if v else np.nan for v in values], dtype=np.float64)
    return out


@dataclass(frozen=True)
class Results:
    """The outputs of one run (read lazily; the files may be those of a run still going).

    Attributes:
        path: The output directory.
    """

    path: Path

    @property
    def summary(self) -> dict:
        """``summary.json`` (read anew at each access: a running run rewrites it)."""
        path = self.path / "summary.json"
        try:
            return json.loads(path.read_text())
        except ValueError as err:  # a file cut short or edited by hand
            raise ValueError(f"{path} cannot be read as JSON ({err})") from None

    @cached_property
    def scene(self) -> dict | None:
        """The scene of the run after overrides (``poromech_scene.yaml``) as a mapping.

        None when not stored: ``run_scene`` stores it when given ``raw``, as ``poromech run``
        does.
        """
        path = self.path / "poromech_scene.yaml"
        return yaml.safe_load(path.read_text()) if path.exists() else None

    @property
    def series_names(self) -> tuple[str, ...]:
        """The XDMF series present (``displacement``, ``fractures``, ``flow``, ...)."""
        return tuple(s for s in _SERIES if (self.path / f"{s}.xdmf").exists())

    def series(self, stem: str) -> Series:
        """One XDMF series: ``points``, ``cells``, ``times``, ``fields(k)``, ``at(t)``."""
        if not (self.path / f"{stem}.xdmf").exists():
            raise FileNotFoundError(f"{self.path} has no series {stem!r} "
                                    f"(present: {', '.join(self.series_names) or 'none'})")
        return read_series(self.path, stem)

    def times(self, stem: str | None = None) -> list[float]:
        """Output times of a series (default: the first series present)."""
        stem = stem or next(iter(self.series_names), None)
        if stem is None:
            raise FileNotFoundError(f"{self.path} holds no XDMF series")
        return self.series(stem).times

    def fractures(self, time: float | None = None) -> dict[str, npt.NDArray]:
        """Rows of ``fractures.csv`` as column arrays.

        Args:
            time: Keep the rows of the output time nearest to it; None: every row.

        A time whose rows a killed run did not finish writing is left out.
        """
        table = read_table(self.path / "fractures.csv")
        times, counts = np.unique(table["time"], return_counts=True)
        faces = self.summary.get("mesh", {}).get("fracture_faces")
        if faces is not None and np.any(counts != faces):
            keep = np.isin(table["time"], times[counts == faces])
            table = {k: v[keep] for k, v in table.items()}
        return _at_time(table, time)

    def probe(self, name: str, time: float | None = None) -> dict[str, npt.NDArray]:
        """``probe_<name>.csv`` (the fields along a probe line) as column arrays.

        Args:
            name: The probe's name.
            time: Keep the rows of the output time nearest to it; None: every row.
        """
        return _at_time(read_table(self.path / f"probe_{name}.csv"), time)

    @property
    def probes(self) -> tuple[str, ...]:
        """Names of the probes written."""
        return tuple(sorted(p.stem[len("probe_"):] for p in self.path.glob("probe_*.csv")))


def _at_time(table: dict[str, npt.NDArray], time: float | None) -> dict[str, npt.NDArray]:
    """The rows of the output time nearest to ``time`` (all rows for None)."""
    if time is None or not len(table["time"]):
        return table
    times = np.unique(table["time"])
    keep = table["time"] == times[np.argmin(np.abs(times - time))]
    return {k: v[keep] for k, v in table.items()}


def open_results(outdir: str | Path) -> Results:
    """Open the output directory of a run (``poromech run -o OUTDIR`` or ``run_scene``)."""
    path = Path(outdir)
    if not (path / "summary.json").exists():
        raise FileNotFoundError(f"{path} is not a poromech output directory (no summary.json)")
    return Results(path)
