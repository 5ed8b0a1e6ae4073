"""Wall-clock timing by phase, reduced over MPI ranks for reporting."""

from __future__ import annotations

import contextlib
import time
from collections import defaultdict

from mpi4py import MPI

__all__ = ["Timer"]


class Timer:
    """Accumulates wall time per named phase (mesh, setup, assembly, linear_solve, output, ...)."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = defaultdict(float)
        self._start = time.perf_counter()

    @contextlib.contextmanager
    def phase(self, name: str):
        """Time a block of code under ``name``."""
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[name] += time.perf_counter() - t0

    def add(self, name: str, seconds: float) -> None:
        """Add time measured elsewhere."""
        self.seconds[name] += seconds

    def report(self, comm: MPI.Comm) -> dict[str, float]:
        """Maximum over ranks of each phase, plus ``total`` since construction (collective)."""
        names = sorted(comm.allreduce(set(self.seconds), op=MPI.BOR)) if comm.size > 1 else sorted(
            self.seconds
        )
        out = {n: comm.allreduce(self.seconds.get(n, 0.0), op=MPI.MAX) for n in names}
        out["total"] = comm.allreduce(time.perf_counter() - self._start, op=MPI.MAX)
        return {k: round(v, 4) for k, v in out.items()}
