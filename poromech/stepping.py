"""The one time-stepping layer of poromech: steps, failed-step policy, output cadence, checkpoints.

Every run goes through :func:`run_steps`, called by the lifecycle :class:`poromech.run.Run`; the
physics sits behind :class:`poromech.physics.Physics`, and the loop does not know which it is.

For every step ``tⁿ⁻¹ → tⁿ`` the loop

1. solves (``physics.solve(t, dt)``); when that fails, the state of ``tⁿ⁻¹`` is restored
   (``physics.reject()``) and the step is retried as two halves, then quarters, ... up to
   ``time.max_cuts`` times (sub-steps are solved and accepted but not written), or until a
   halved step starts from the same residual as the failed one (the loads do not change with
   t over it: a shorter step would solve the same problem); when the last
   cut fails, the run stops with :class:`~poromech.errors.SolverError` (exit status 3), every
   output of the earlier steps being kept. The record of a cut step counts the work of all its
   attempts (``Physics.counters`` summed over them), and lists them under ``attempts``;
2. writes the output of the step just solved (every ``output.every`` steps and the last one),
   *before* accepting it, so that contact states and slip rates describe that step;
3. accepts the step (``physics.accept(t)``: the solved state becomes the reference of the next
   step, e.g. of the slip increment), then rewrites ``summary.json`` and the checkpoint
   atomically.

A SIGINT or SIGTERM stops the run at the next step boundary, with the completed steps written
(:class:`Interrupted`, exit status 130 or 143), and says so at once on the standard output (a step
may take minutes); a second signal ends the process at once.
"""

from __future__ import annotations

import logging
import signal
import sys
import time
from collections.abc import Callable
from dataclasses import replace

from mpi4py import MPI

from poromech.errors import SolverError
from poromech.physics import Physics, StepResult
from poromech.scene.schema import Scene, step_times

__all__ = ["Interrupted", "run_steps", "stop_at_once", "stop_signals"]

log = logging.getLogger("poromech")


class Interrupted(RuntimeError):
    """The run was stopped by a signal at a step boundary; ``signum`` tells which."""

    def __init__(self, signum: int, setting_up: bool = False):
        super().__init__(
            f"stopped by {signal.Signals(signum).name} while setting up, before the first step "
            "(nothing was solved)" if setting_up else
            f"stopped by {signal.Signals(signum).name} after the last completed step; its "
            "outputs are complete")
        self.signum = signum


def _stop_now(signum, frame) -> None:
    raise Interrupted(signum, setting_up=True)


class stop_at_once:
    """Context manager: SIGINT/SIGTERM raise :class:`Interrupted` at once (the set-up).

    Meshing, building the physics and compiling forms can take minutes in 3D: a signal there
    ends the run with the one-line message of a stop at a step boundary, and a summary, where
    SIGINT printed a traceback and SIGTERM ended it without a word or a summary.
    """

    def __enter__(self) -> None:
        self._previous: dict[int, object] = {}
        try:
            for s in (signal.SIGINT, signal.SIGTERM):
                self._previous[s] = signal.signal(s, _stop_now)
        except ValueError:  # not in the main thread: signals act as usual
            pass

    def __exit__(self, *exc) -> None:
        for s, h in self._previous.items():
            signal.signal(s, h)


class _StopFlag:
    """Signal handler that records the first SIGINT/SIGTERM and re-raises on the second."""

    def __init__(self) -> None:
        self.signum = 0
        self._previous: dict[int, object] = {}

    def __call__(self, signum, frame) -> None:
        if self.signum:
            signal.signal(signum, signal.SIG_DFL)
            signal.raise_signal(signum)
        self.signum = signum
        if MPI.COMM_WORLD.rank == 0:  # (mpirun passes the signal to every rank)
            # a step can take minutes: say that the signal was heard, and how to stop now
            sys.stdout.write(f"poromech: {signal.Signals(signum).name} received: the run stops "
                             "after the step being solved, with its outputs complete; a second "
                             "signal stops it at once\n")
            sys.stdout.flush()

    def install(self) -> None:
        for s in (signal.SIGINT, signal.SIGTERM):
            self._previous[s] = signal.signal(s, self)

    def restore(self) -> None:
        for s, h in self._previous.items():
            signal.signal(s, h)


class stop_signals:
    """Context manager catching SIGINT/SIGTERM for a clean stop at the next step boundary."""

    def __enter__(self) -> _StopFlag:
        self.flag = _StopFlag()
        try:
            self.flag.install()
        except ValueError:  # not in the main thread: no handler, signals act as usual
            pass
        return self.flag

    def __exit__(self, *exc) -> None:
        self.flag.restore()


#: A cut attempt whose first residual equals the failed longer attempt's from the same start to
#: this relative precision solves the same problem (loads constant in t over the step): the cuts
#: stop there. Different loads move the first residual far more than rounding does.
SAME_PROBLEM = 1e-12


def _advance(physics: Physics, t0: float, t1: float, max_cuts: int,
             static: bool) -> tuple[StepResult, list[dict]]:
    """Solve from ``t0`` to ``t1``, cutting the step on failure (see the module docstring)."""
    if static:
        result = physics.solve(t1, None)
        if not result.converged:
            raise SolverError(result.message, result.reason, result.history,
                              {"time": t1, **result.record})
        return result, []
    dt, cuts, attempts = t1 - t0, 0, []
    failed_from = None  # (start time, first residual) of the last failed attempt
    while True:
        t = t1 if t0 + dt >= t1 * (1 - 1e-12) else t0 + dt
        result = physics.solve(t, t - t0)
        if not result.converged and result.history:
            first = float(result.history[0])
            if (failed_from is not None and failed_from[0] == t0
                    and abs(first - failed_from[1]) <= SAME_PROBLEM * abs(failed_from[1])):
                attempts.append({"time": t, "converged": False, **_brief(result.record)})
                raise SolverError(
                    f"{result.message} (the step cut to t = {t:g} s started from the residual "
                    f"of the longer step, {first:.6g}: the loads do not change with t there, "
                    "and a shorter step would solve the same problem; not cut further)",
                    result.reason, result.history,
                    {"time": t, **_totals(result.record, attempts, physics.counters),
                     "attempts": attempts})
            failed_from = (t0, first)
        if result.converged:
            if t == t1 and not attempts:
                return result, attempts
            attempts.append({"time": t, "converged": True, **_brief(result.record)})
            if t == t1:
                return replace(result, record=_totals(result.record, attempts,
                                                      physics.counters)), attempts
            physics.accept(t)
            t0 = t
            continue
        attempts.append({"time": t, "converged": False, **_brief(result.record)})
        physics.reject()
        cuts += 1
        if cuts > max_cuts:
            raise SolverError(f"{result.message} (after {max_cuts} step cuts)", result.reason,
                              result.history,
                              {"time": t, **_totals(result.record, attempts, physics.counters),
                               "attempts": attempts})
        dt *= 0.5
        log.warning("step to t=%g s failed (%s); retrying with dt=%g s (cut %d of %d)",
                    t, result.message.split(";")[0], dt, cuts, max_cuts)


def _totals(record: dict, attempts: list[dict], counters: tuple[str, ...]) -> dict:
    """``record`` with each of ``counters`` summed over ``attempts`` (which include it)."""
    return {**record, **{k: sum(a.get(k, 0) for a in attempts) for k in counters if k in record}}


def _brief(record: dict) -> dict:
    """The scalar entries of a record (for the list of attempts)."""
    return {k: v for k, v in record.items() if isinstance(v, int | float | str | bool)}


def run_steps(
    physics: Physics,
    scene: Scene,
    comm: MPI.Comm,
    records: list[dict],
    on_step: Callable[[int, float], None],
    start: int = 0,
    write_initial: bool = False,
    stop=None,
) -> None:
    """Run the time steps ``start, start+1, ...`` of a scene (collective).

    Args:
        physics: The physics (already initialized or restored).
        scene: The scene (time stepping and output cadence).
        comm: Communicator.
        records: One record per completed step is appended here.
        on_step: Called as ``on_step(k, t)`` after step ``k`` is accepted and recorded (summary
            and checkpoint).
        start: Index of the first step to solve (a restart continues after the last one done).
        write_initial: Write the initial state at ``t = 0`` first.
        stop: A flag object with an attribute ``signum`` (see :class:`stop_signals`).

    Raises:
        SolverError: A step failed after every allowed cut.
        Interrupted: A stop signal arrived; the completed steps are written.
    """
    times = step_times(scene)
    static = scene.time is None
    every = scene.output.every
    max_cuts = 0 if static else scene.time.max_cuts
    if write_initial and start == 0:
        physics.write(0.0)
    t_prev = 0.0 if start == 0 else times[start - 1]
    for k in range(start, len(times)):
        _check_stop(comm, stop)
        t = times[k]
        t0 = time.perf_counter()
        result, attempts = _advance(physics, t_prev, t, max_cuts, static)
        if (k + 1) % every == 0 or k + 1 == len(times):
            physics.write(t)
        physics.accept(t)
        wall = comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)
        entry = {"step": k + 1, "time": t, "wall_time": wall, **result.record}
        if attempts:
            entry["cuts"] = sum(not a["converged"] for a in attempts)
            entry["attempts"] = attempts
        records.append(entry)
        cut = f" ({len(attempts)} attempts, {entry['cuts']} cut; counts of all)" if attempts else ""
        log.info("%s%s, %.2f s", physics.progress(k, len(times), t, result), cut, wall)
        on_step(k, t)
        t_prev = t


def _check_stop(comm: MPI.Comm, stop) -> None:
    """Raise :class:`Interrupted` on every rank when any rank received a stop signal."""
    signum = 0 if stop is None else stop.signum
    signum = comm.allreduce(signum, op=MPI.MAX)
    if signum:
        raise Interrupted(signum)
