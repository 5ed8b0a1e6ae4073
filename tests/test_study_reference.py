"""The reference of the coupled error study (scripts/poromechanics_study.py): Richardson, budgets.

Units with exactly known answers; the study itself runs for hours (docs/poromechanics/reference.md).
"""

import importlib
import sys

import numpy as np
import pytest
from conftest import ROOT


@pytest.fixture(scope="module")
def study():
    sys.path.insert(0, str(ROOT / "scripts"))  # the study imports flow_common
    try:
        return importlib.import_module("poromechanics_study")
    finally:
        sys.path.remove(str(ROOT / "scripts"))


@pytest.mark.parametrize("order", [0.6, 1.0, 2.0, 3.5])
def test_richardson_recovers_the_limit_of_a_power_law(study, order):
    x = np.linspace(0.0, 1.0, 7)
    limit, error = np.sin(3 * x) + 2.0, np.cos(x)  # q_m = limit + error h_m^p, h halving
    q = [limit + error * 2.0 ** (-order * m) for m in (2, 3, 4)]
    r = study.richardson(q, np.ones_like(x))
    assert r["regular"]
    assert r["order"] == pytest.approx(order, rel=1e-12)
    assert r["cosine"] == pytest.approx(1.0, abs=1e-12)
    assert np.allclose(r["extrapolated"], limit, rtol=0, atol=1e-12)


def test_richardson_refuses_irregular_sequences(study):
    w = np.ones(3)
    base = np.array([1.0, 2.0, 3.0])
    # differences that change shape: not extrapolated
    shape = study.richardson([base, base + [1e-2, 0, 0], base + [1e-2, 5e-3, 0]], w)
    assert not shape["regular"] and shape["extrapolated"] is None
    assert shape["cosine"] == pytest.approx(0.0)
    # differences that do not contract (order < 0.5)
    slow = study.richardson([base, base + 0.1, base + 0.1 + 0.09], w)
    assert not slow["regular"] and slow["order"] == pytest.approx(np.log2(0.1 / 0.09))
    # a scalar that overshoots (differences of opposite sign)
    sign = study.richardson([np.array([1.0]), np.array([1.1]), np.array([1.05])], np.ones(1))
    assert not sign["regular"] and sign["cosine"] == -1.0


def test_least_error_per_budget(study):
    rows = [["m0_mixed_P2_anderson_n1", 4.0, 0.1, 0.2, 0.3, 0.4],
            ["m1_mixed_P2_anderson_n1", 9.0, 0.05, 0.1, 0.3, 0.01],
            ["m1_nitsche_P2_anderson_n1", 40.0, 0.01, 0.2, 0.1, 0.2]]
    out = study.least_error_per_budget(rows, budgets=(3, 5, 10, 50))
    assert out[0][1:] == ["–"] * 4
    assert out[1][1].startswith("mixed P2 m0 (0.1,")
    assert out[2][4].startswith("mixed P2 m1 (0.01,")
    assert out[3][1].startswith("nitsche P2 m1 (0.01,")
    assert out[3][2].startswith("mixed P2 m1 (0.1,")


def test_errors_of_a_solution_against_itself_and_a_shifted_one(study):
    s = np.array([0.05, 0.15, 0.25])
    w = np.full(3, 0.1)
    sol = study.Solution("a", np.array([0.0, 1.0]), np.array([1e-4, 2e-4]),
                         {"1": (s, w, -1e-5 * s, 1e-3 * s), "2": (s, w, 0 * s, 2e-3 * s)},
                         500.0)
    assert all(v == 0.0 for v in study.errors(sol, sol).values())
    other = study.Solution("b", sol.times, 1.1 * sol.aperture, sol.jumps, 550.0)
    e = study.errors(sol, other)
    assert e["mean aperture"] == pytest.approx(0.1 / 1.1)
    assert e["mean overpressure at T"] == pytest.approx(50.0 / 550.0)
    assert e["jumps at T"] == 0.0 and e["fracture-1 slip at T"] == 0.0
    # replaced() round-trips the measures
    back = sol.replaced({k: v[0] for k, v in sol.vectors().items()}, "c")
    assert all(np.allclose(back.vectors()[k][0], sol.vectors()[k][0]) for k in study.MEASURES)
    # a separately estimated fracture-1 slip is what that measure compares against
    ref = sol.replaced({k: v[0] for k, v in sol.vectors().items()}
                       | {"fracture-1 slip at T": 2e-3 * s}, "ref")
    e = study.errors(sol, ref)
    assert e["fracture-1 slip at T"] == pytest.approx(0.5) and e["jumps at T"] == 0.0
