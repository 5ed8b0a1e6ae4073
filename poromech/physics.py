"""The physics interface: everything the run lifecycle and the time loop ask of a physics.

A physics (``mechanics``, ``flow``, ``poromechanics``, and later ones) is a class implementing
:class:`Physics`, registered under its scene name in :data:`poromech.run.PHYSICS`. The lifecycle
(:class:`poromech.run.Run`) calls, in this order::

    physics = Class(scene, mesh, timer)           # builds only what the scene needs
    summary.update(physics.describe())
    physics.initialize()  or  physics.restore(arrays, t)     # (--restart)
    physics.open_output(outdir, resume_until)     # skipped for in-memory runs
    for each step (poromech.stepping.run_steps):
        physics.solve(t, dt) -> StepResult; on failure physics.reject() and retry (cut step)
        physics.write(t)                          # every output.every steps
        physics.accept(t); physics.state()        # checkpoint
    physics.finish(summary); physics.close()

Every method is collective; a :class:`StepResult` is identical on every rank.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import ClassVar, Protocol

import numpy as np
import numpy.typing as npt

__all__ = ["Keyed", "Physics", "StepResult"]

#: A checkpoint array keyed independently of the partition: ``(keys, values)``, keys being
#: input cell numbers, global fracture face numbers or dof keys (:mod:`poromech.io.checkpoint`).
Keyed = tuple[npt.NDArray[np.int64], npt.NDArray[np.float64]]


@dataclass
class StepResult:
    """Outcome of one attempted solve (identical on every rank).

    Attributes:
        converged: Whether the solve converged.
        record: JSON-ready details (iterations, residuals, counts, ...).
        message: Why it failed (reason and residual history), for the error message.
        reason: PETSc's converged reason of a failed solve.
        history: Residual norms of a failed solve.
    """

    converged: bool
    record: dict = field(default_factory=dict)
    message: str = ""
    reason: str = ""
    history: list[float] = field(default_factory=list)


class Physics(Protocol):
    """What the lifecycle and the time loop need from a physics (every method collective).

    Attributes:
        counters: Entries of a step record that add up over the attempts of a cut step (solver
            work: iterations, evaluations, seconds).
        records_section: Where the step records go in ``summary.json``: ``None`` for the top
            level (``summary["solves"]``), else the name of a section (``"flow"``:
            ``summary["flow"]["solves"]``).
        writes_initial_state: Whether the state at ``t = 0`` is written before the first step
            of a time-dependent run.
    """

    counters: ClassVar[tuple[str, ...]]
    records_section: ClassVar[str | None]
    writes_initial_state: bool

    def describe(self) -> dict:
        """Discretization and sizes, merged into the summary before the first solve."""

    def initialize(self) -> dict | None:
        """Set up the state at the initial time.

        Returns:
            A record of the initial solve (``summary["initial"]``), or None.
        """

    def solve(self, t: float, dt: float | None) -> StepResult:
        """Solve the step ending at ``t`` of length ``dt`` (None: a static solve)."""

    def accept(self, t: float) -> None:
        """Make the solved state the reference state of the next step."""

    def reject(self) -> None:
        """Restore the last accepted state (before a retry with a smaller step)."""

    def progress(self, step: int, nsteps: int, t: float, result: StepResult) -> str:
        """One line describing a converged step."""

    def open_output(self, outdir: Path, resume_until: float | None = None) -> None:
        """Create the writers selected by ``scene.output``.

        After a restart the series continue, with their entries up to ``resume_until`` kept.
        """

    def write(self, t: float) -> None:
        """Write the outputs of the state just solved (or of the initial state)."""

    def state(self) -> dict[str, Keyed]:
        """The accepted state as partition-independent checkpoint arrays."""

    def restore(self, arrays: dict[str, npt.NDArray], t: float) -> None:
        """Continue after the step ending at ``t`` from checkpoint arrays (indexed by key)."""

    def finish(self, summary: dict, records: list[dict]) -> None:
        """Totals of the step ``records`` and the final outputs (after the last step or failure)."""

    def close(self) -> None:
        """Free the PETSc objects."""
