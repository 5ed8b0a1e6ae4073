"""The shared time loop (poromech/stepping.py): a failed step is cut, and the record of a cut
step counts the solver work of every attempt, failed ones and sub-steps included."""

import pytest
from conftest import mechanics_scene
from mpi4py import MPI

from poromech.errors import SolverError
from poromech.physics import StepResult
from poromech.scene.loading import scene_from_dict
from poromech.stepping import run_steps


class Halving:
    """A physics whose solve fails on steps longer than ``longest``: 100 iterations when it
    fails, 10 when it converges, half a second each time."""

    counters = ("iterations", "seconds")

    def __init__(self, longest: float):
        self.longest, self.calls, self.accepted = longest, [], []

    def solve(self, t, dt):
        self.calls.append((t, dt))
        ok = dt <= self.longest
        record = {"reason": "CONVERGED" if ok else "DIVERGED", "converged": ok,
                  "iterations": 10 if ok else 100, "seconds": 0.5, "residuals": [1.0, 0.1]}
        return StepResult(ok, record, "" if ok else "it failed; history", record["reason"])

    def write(self, t):
        pass

    def accept(self, t):
        self.accepted.append(t)

    def reject(self):
        pass

    def progress(self, k, n, t, result):
        return f"step {k + 1}/{n}"


def scene(max_cuts: int):
    return scene_from_dict(mechanics_scene(time={"final": 1.0, "steps": 2,
                                                 "max_cuts": max_cuts}))


def test_a_cut_step_counts_every_attempt():
    physics, records = Halving(0.3), []
    run_steps(physics, scene(4), MPI.COMM_WORLD, records, lambda k, t: None)
    assert physics.calls == [(0.5, 0.5), (0.25, 0.25), (0.5, 0.25),
                             (1.0, 0.5), (0.75, 0.25), (1.0, 0.25)]
    assert physics.accepted == [0.25, 0.5, 0.75, 1.0]
    for rec in records:
        assert rec["cuts"] == 1 and [a["converged"] for a in rec["attempts"]] == [0, 1, 1]
        assert rec["iterations"] == 100 + 10 + 10 and rec["seconds"] == pytest.approx(1.5)
        assert [a["iterations"] for a in rec["attempts"]] == [100, 10, 10]
        assert rec["residuals"] == [1.0, 0.1]  # of the solve that ended the step
    physics, records = Halving(1.0), []
    run_steps(physics, scene(4), MPI.COMM_WORLD, records, lambda k, t: None)
    assert [r["iterations"] for r in records] == [10, 10]
    assert not any("attempts" in r or "cuts" in r for r in records)


def test_a_failed_run_reports_the_work_of_every_attempt():
    with pytest.raises(SolverError, match="after 1 step cuts") as err:
        run_steps(Halving(0.1), scene(1), MPI.COMM_WORLD, [], lambda k, t: None)
    assert err.value.record["iterations"] == 200
    assert [a["time"] for a in err.value.record["attempts"]] == [0.5, 0.25]


class Failing(Halving):
    """A physics that never converges; its first residual is ``first(t)``."""

    def __init__(self, first):
        super().__init__(0.0)
        self.first = first

    def solve(self, t, dt):
        result = super().solve(t, dt)
        return StepResult(False, result.record, result.message, result.reason,
                          [self.first(t), 0.5 * self.first(t)])


def test_cuts_stop_when_a_shorter_step_starts_from_the_same_residual():
    """Loads constant over the step: the cut step starts from the failed step's residual and
    solves the same problem, so the cuts stop there (they re-solved it max_cuts times, 5 x 100
    Newton iterations for a `mixed` P1 scene that cannot converge); loads that change with t
    are cut as far as max_cuts allows."""
    physics = Failing(lambda t: 3.5e5 * (1 + 1e-14 * t))
    with pytest.raises(SolverError, match="the loads do not change with t there") as err:
        run_steps(physics, scene(4), MPI.COMM_WORLD, [], lambda k, t: None)
    assert physics.calls == [(0.5, 0.5), (0.25, 0.25)]
    assert [a["time"] for a in err.value.record["attempts"]] == [0.5, 0.25]
    assert err.value.record["iterations"] == 200
    physics = Failing(lambda t: 3.5e5 * (1 + t))
    with pytest.raises(SolverError, match="after 4 step cuts"):
        run_steps(physics, scene(4), MPI.COMM_WORLD, [], lambda k, t: None)
    assert len(physics.calls) == 5
