"""The start of each step's Newton: the last accepted unknowns or their extrapolation in time."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from dolfinx import fem
from mpi4py import MPI

__all__ = ["MAX_RATIO", "START_NAMES", "StepPredictor", "extrapolated", "start_rule"]

History = list[tuple[float, list[npt.NDArray[np.float64]]]]

#: Each rule of :func:`start_rule`, as the log names the start it gives.
START_NAMES = {"extrapolate": "last two steps extrapolated", "last": "last accepted step",
               "lower_residual": "last accepted step or the last two steps extrapolated, "
                                 "whichever has the lower residual"}

#: Longest step, in lengths of the last one, over which the unknowns are extrapolated. Beyond it
#: the change of the last step says nothing about the next one, and the extrapolation can
#: overflow: listed times ``[1e-300, 1]`` scaled the first step's change by 1e300, and every
#: cut of the second step failed on a residual that was not finite. Steps after a cut grow by
#: at most the factor of the cut (16 after four halvings), far below it.
MAX_RATIO = 1.0e3


def extrapolated(t: float, earlier: tuple[float, list], last: tuple[float, list],
                 comm: MPI.Comm) -> list[npt.NDArray[np.float64]] | None:
    """Arrays at ``t`` extrapolated linearly from ``(t₀, x₀)`` and ``(t₁, x₁)`` (collective).

    None, on every rank, for a step more than :data:`MAX_RATIO` times the last one or an
    extrapolation that is not finite somewhere: start from ``x₁`` then.
    """
    (t0, x0), (t1, x1) = earlier, last
    r = (t - t1) / (t1 - t0)
    if not r <= MAX_RATIO:
        return None
    with np.errstate(over="ignore", invalid="ignore"):
        values = [a1 + r * (a1 - a0) for a0, a1 in zip(x0, x1, strict=True)]
    finite = all(bool(np.isfinite(v).all()) for v in values)
    return values if comm.allreduce(finite, op=MPI.LAND) else None


def start_rule(choice: str, dim: int, coupled: bool, formulation: str) -> str:
    """Where each step's contact Newton starts: ``extrapolate``, ``last`` or ``lower_residual``.

    Args:
        choice: The scene's ``solver.predictor`` (``auto`` or one of the three).
        dim: Space dimension.
        coupled: The mechanics is part of a coupled (poromechanics) scene.
        formulation: ``contact.formulation``.

    ``auto`` in a mechanics-only 3D scene: ``lower_residual`` for ``nitsche``, ``last`` for
    ``mean_nitsche`` and ``stabilized_mixed``, ``extrapolate`` for ``mixed``; ``extrapolate``
    in coupled and 2D scenes. In a mechanics-only scene the loads are boundary data along the
    path the scene writes, and neither start is right on every step. The extrapolation assumes
    that the last step's response goes on: across a change of path (compression, then shear)
    it doubles the compression (on the eleven-fracture network a residual of 7.6e6 against 2.4e6
    from the last unknowns), and after the step where slip starts it repeats the slip that step
    released; where the shear goes on it is the better guess by orders of magnitude (1.4e4
    against 2.4e6). Measured on two networks at 5 + 5 mesh levels (docs/mechanics3d.md, "Where
    each step starts"):

    * ``nitsche``: the start of lower residual (one more residual assembly per step) takes the
      last unknowns at the first shear step and the extrapolation after it; the sum of a run's
      Newton iterations is that from the last unknowns or lower in 27 of the 28 runs of the
      scaling study (one more in the other), and 43 against 50 (last) and 51 (extrapolation)
      on the eleven-fracture network's level-4 mesh;
    * the face-mean formulations: the extrapolation has the lower residual after the slip
      onset but costs 12-29 Newton iterations in that step against 5-8 from the last unknowns
      (one state per face, decided by face means, starts on the wrong branch);
    * ``mixed``, which extrapolates its multipliers with the displacement, converges from the
      extrapolation where it fails from the last unknowns (β⁰ × 0.1).

    In a coupled scene the pressures change smoothly and the extrapolation pays (112 against
    117 Newton iterations on the 3D fault scene's coarse mesh); 2D keeps it, which its scenes
    and reference outputs were built with.
    """
    if choice != "auto":
        return choice
    if coupled or dim == 2 or formulation == "mixed":
        return "extrapolate"
    return "lower_residual" if formulation == "nitsche" else "last"


class StepPredictor:
    """Accepted unknowns of the last two steps and their linear extrapolation (collective).

    When the unknowns are those of the last accepted step ``tₙ`` and the step before was accepted
    too, :meth:`predict` extrapolates them linearly to the new time ``t``:
    ``x ← xₙ + (t - tₙ)/(tₙ - tₙ₋₁) (xₙ - xₙ₋₁)`` (``u``, ``λ`` and the face averages). Points
    that slid in the last step then start the step sliding at the same rate, instead of all
    sticking (zero slip increment) in the first Newton iteration. Zero unknowns at the first
    call count as the state at ``t = 0``; unknowns that are not the last accepted ones (a
    restored checkpoint, a second call in the same step) are kept, and the history restarts.
    With a ``merit``, the extrapolation is kept only if its merit is lower than that of the
    last accepted unknowns (:attr:`start` says which was kept). A step longer than
    :data:`MAX_RATIO` times the last one, or an extrapolation that is not finite, starts from
    the last unknowns.

    Args:
        unknowns: The functions in block order.
        comm: Communicator.
        extrapolate: Extrapolate (else only keep the history).
        merit: The Newton's merit of the residual at the current unknowns (collective), to
            choose between the extrapolated and the last unknowns; None: always extrapolate.
    """

    def __init__(self, unknowns: list[fem.Function], comm: MPI.Comm, extrapolate: bool = True,
                 merit: Callable[[], float] | None = None):
        self.unknowns, self.comm, self.extrapolate = unknowns, comm, extrapolate
        self.merit = merit
        self.time = 0.0  # time of the step being solved (that of the last predict)
        self.start = "last"  # the start of the step being solved: "last" or "extrapolated"
        self._history: History | None = None  # None until the first predict or accept

    def _copy(self) -> list[npt.NDArray[np.float64]]:
        return [f.x.array.copy() for f in self.unknowns]

    def predict(self, t: float) -> None:
        """Set the unknowns to the extrapolation at ``t`` where that applies (see the class)."""
        if self._history is None:
            zero = self.comm.allreduce(all(not f.x.array.any() for f in self.unknowns),
                                       op=MPI.LAND)
            self._history = [(0.0, self._copy())] if zero else []
        self.time = t
        self.start = "last"
        if self._history:
            last = self._history[-1][1]
            same = all(np.array_equal(f.x.array, a)
                       for f, a in zip(self.unknowns, last, strict=True))
            if not self.comm.allreduce(same, op=MPI.LAND):
                self._history = [] if t > self._history[-1][0] else self._history
                return
        if self.extrapolate and len(self._history) == 2 and t > self._history[1][0]:
            values = extrapolated(t, *self._history, self.comm)
            if values is None:
                return
            at_last = self.merit() if self.merit is not None else None
            for f, a in zip(self.unknowns, values, strict=True):
                f.x.array[:] = a
            self.start = "extrapolated"
            if at_last is not None and not self.merit() < at_last:  # (a nan keeps the last)
                for f, a1 in zip(self.unknowns, self._history[1][1], strict=True):
                    f.x.array[:] = a1
                self.start = "last"

    def accept(self) -> None:
        """The current unknowns are the accepted state at the time of the last prediction."""
        t = self.time
        history = [h for h in (self._history or []) if h[0] < t][-1:]
        self._history = history + [(t, self._copy())]

    @property
    def previous(self) -> tuple[float, list[npt.NDArray[np.float64]]] | None:
        """The accepted step before the last one, ``(time, arrays)``, if known."""
        history = self._history or []
        return history[0] if len(history) == 2 else None

    def restore(self, t: float, previous: tuple[float, list] | None) -> None:
        """After a restart: the current unknowns are accepted at ``t``, ``previous`` before."""
        self.time = t
        self._history = [previous] if previous else []
        self._history.append((t, self._copy()))

    @property
    def history(self) -> History:
        """The accepted ``(time, arrays)`` kept (at most two)."""
        return list(self._history or [])
