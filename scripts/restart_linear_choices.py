"""A restart after the P2 smoother's fallback: what the continued run's linear solves cost.

Scene (written below, not shipped): a 1 km box with a disc fault of radius 300 m (normal 30°
from vertical) under in-situ stress (σ_zz = ρ g z, σ_xx = σ_yy = K₀ ρ g z, K₀ = 0.8) and
gravity, P2 on 200 m cells, Coulomb F = 0.6, its right face pushed by 2 cm · t² in three steps
of 1 s. The iterative path runs (``solver.linear_solver: iterative``); on this coarse uniform
P2 mesh point-block Jacobi on the P2 level stalls, and the first solve falls back to Chebyshev
with SOR (``FALLBACK_IT`` GMRES iterations, then the solve again).

Three runs: ``uninterrupted`` (the three steps at once); ``restarted`` (one step, then the
three-step scene continued with ``restart``, as ``poromech run --restart`` does after a run was
stopped), which goes on with the fallback kept in the checkpoint; ``restarted, choices not
restored`` (the same with the restore of the linear solver's choices switched off: what a
restart did before the checkpoint kept them).

``restart.csv`` has a row per run and step: ``run``, ``step``, ``newton`` iterations,
``gmres`` iterations, ``setups`` preconditioner set-ups, ``seconds`` the step's wall time,
``fine_smoother`` the p-multigrid's P2 smoother at the end of the run.

Run (about a minute on one core)::

    python scripts/restart_linear_choices.py    # -> docs/mechanics3d/restart.{csv,md}
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import dolfinx_solver  # noqa: F401

import yaml
from report_common import generated, write_report

from poromech.mechanics.physics import MechanicsPhysics
from poromech.run import run_scene
from poromech.scene.loading import load_scene

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "docs" / "mechanics3d"
SCRIPT = "restart_linear_choices.py"
FIELDS = ("run", "step", "newton", "gmres", "setups", "seconds", "fine_smoother")

SCENE = {
    "name": "fault_box_insitu",
    "description": "a fault in a 1 km box under in-situ stress and gravity, then pushed",
    "parameters": {"rho": 2500.0, "g": 9.81, "K0": 0.8},
    "geometry": {
        "domain": {"box": [0.0, 0.0, -1000.0, 1000.0, 1000.0, 0.0]},
        "fractures": [{"name": "fault", "disc": {"center": [500.0, 500.0, -500.0],
                                                 "normal": [0.5, 0.0, 0.8660254037844386],
                                                 "radius": 300.0}}]},
    "mesh": {"size": 200.0, "fracture_size": 60.0},
    "degree": 2,
    "material": {"young": 1.0e10, "poisson": 0.25, "density": "rho",
                 "initial_stress": ["K0 * rho * g * z", "K0 * rho * g * z", "rho * g * z",
                                    0.0, 0.0, 0.0]},
    "gravity": [0.0, 0.0, -9.81],
    "contact": {"formulation": "nitsche", "friction": "coulomb", "friction_coefficient": 0.6},
    "boundary_conditions": [
        {"boundary": "bottom", "displacement": [None, None, 0.0]},
        {"boundary": "left", "displacement": [0.0, None, None]},
        {"boundary": "right", "displacement": ["-2e-2 * t * t", None, None]},
        {"boundary": "front", "displacement": [None, 0.0, None]},
        {"boundary": "back", "displacement": [None, 0.0, None]}],
    "time": {"final": 3.0, "steps": 3},
    "solver": {"linear_solver": "iterative"},
    "output": {"xdmf": False},
}


def rows_of(name: str, summary: dict, first: int) -> list[dict]:
    """The step rows of a run's summary from step ``first`` (1-based) on."""
    smoother = summary["linear_solver"].get("p_multigrid", {}).get("fine_smoother", "")
    return [{"run": name, "step": r["step"], "newton": r["iterations"],
             "gmres": r["linear_iterations"], "setups": r["factorizations"],
             "seconds": round(r["wall_time"], 2), "fine_smoother": smoother}
            for r in summary["solves"] if r["step"] >= first]


def run_all(work: Path) -> list[dict]:
    """The three runs (see the module docstring)."""
    path = work / "scene.yaml"
    path.write_text(yaml.safe_dump(SCENE, sort_keys=False))
    one_step = ["time.final=1", "time.steps=1"]
    rows = rows_of("uninterrupted", run_scene(load_scene(path), work / "full"), 1)
    restore = MechanicsPhysics._restore_linear_choices
    for name, restored in (("restarted", True), ("restarted, choices not restored", False)):
        out = work / name.replace(",", "").replace(" ", "_")
        run_scene(load_scene(path, one_step), out)
        if not restored:
            MechanicsPhysics._restore_linear_choices = lambda self, arrays: None
        try:
            summary = run_scene(load_scene(path), out, restart=True)
        finally:
            MechanicsPhysics._restore_linear_choices = restore
        rows += rows_of(name, summary, 2)
    return rows


def table(rows: list[dict]) -> str:
    """The Markdown page."""
    lines = [
        "# A restart after the P2 smoother's fallback", "",
        f"{generated(SCRIPT)}. See its docstring "
        "for the scene and the columns. The restarted runs continue a one-step run from its "
        "checkpoint (steps 2 and 3 below).", "",
        "| run | step | Newton | GMRES | set-ups | s | P2 smoother at the end |",
        "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['run']} | {r['step']} | {r['newton']} | {r['gmres']} | "
                     f"{r['setups']} | {r['seconds']} | {r['fine_smoother']} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as work:
        rows = run_all(Path(work))
    for r in rows:
        print(r, flush=True)
    write_report(args.out, "restart", SCRIPT, FIELDS, rows, table(rows))


if __name__ == "__main__":
    main()
