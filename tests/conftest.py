"""Shared test helpers: running a snippet under ``mpirun -n 2`` and reading its JSON result."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import dolfinx_solver  # noqa: F401, I001  (loads MPI before any DOLFINx/PETSc import in tests)

import numpy as np
import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]


def mpirun() -> str:
    """The mpirun next to the Python interpreter (the mpich wheel), else the one on PATH."""
    local = Path(sys.executable).with_name("mpirun")
    found = str(local) if local.exists() else shutil.which("mpirun")
    if found is None:
        pytest.fail("mpirun not found: install the project with its dependencies (mpich wheel)")
    return found


def run_parallel(code: str, nprocs: int = 2, timeout: float = 600.0) -> dict:
    """Run ``code`` on ``nprocs`` ranks; it must print one JSON object on rank 0 as last line.

    Fails the test (never skips) when the run fails.
    """
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    script = tmp / f"poromech_mpi_{os.getpid()}_{abs(hash(code))}.py"
    script.write_text(textwrap.dedent(code))
    try:
        proc = subprocess.run(
            [mpirun(), "-n", str(nprocs), sys.executable, str(script)],
            capture_output=True, text=True, timeout=timeout, cwd=ROOT,
        )
    finally:
        script.unlink(missing_ok=True)
    if proc.returncode != 0:
        pytest.fail(f"mpirun failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n"
                    f"{proc.stderr[-3000:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        pytest.fail(f"no JSON result from the parallel run:\n{proc.stdout[-3000:]}")
    return json.loads(lines[-1])


def sigterm_after_steps(steps: int):
    """A ``Run`` ``prepare`` hook: SIGTERM raised after the physics accepts its ``steps``-th step.

    The run's handler takes it and stops at the next step boundary (``stepping.Interrupted``).
    """
    import signal

    def prepare(physics):
        accept, accepted = physics.accept, []

        def accept_and_signal(t):
            accept(t)
            accepted.append(t)
            if len(accepted) == steps:
                signal.raise_signal(signal.SIGTERM)

        physics.accept = accept_and_signal

    return prepare


def network_geometry() -> dict:
    """A network with every kind of fracture end: tips, a corner, a T, an X, the boundary."""
    return {
        "domain": {"rectangle": [0.0, 0.0, 2.0, 1.0]},
        "fractures": [
            {"name": "corner", "points": [[0.2, 0.8], [0.5, 0.88], [0.8, 0.8]]},
            {"name": "bar", "points": [[0.2, 0.5], [0.8, 0.5]]},
            {"name": "stem", "points": [[0.5, 0.2], [0.5, 0.5]]},
            {"name": "x1", "points": [[1.2, 0.2], [1.6, 0.6]]},
            {"name": "x2", "points": [[1.2, 0.6], [1.6, 0.2]]},
            {"name": "edge", "points": [[1.7, 0.8], [2.0, 0.8]]},
        ],
    }


def mechanics_scene(**overrides) -> dict:
    """A small valid mechanics scene as a raw mapping (compression + shear of the network)."""
    scene = {
        "name": "test",
        "geometry": network_geometry(),
        "mesh": {"size": 0.1, "fracture_size": 0.05},
        "degree": 2,
        "material": {"young": 1.0e9, "poisson": 0.25},
        "contact": {"formulation": "nitsche", "beta_n": 1.0e11, "beta_t": 1.0e11,
                    "friction_coefficient": 0.3},
        "boundary_conditions": [
            {"boundary": "bottom", "displacement": [0.0, 0.0]},
            {"boundary": "top", "displacement": [0.002, -0.001]},
        ],
    }
    for key, value in overrides.items():
        node = scene
        parts = key.split("__")
        for p in parts[:-1]:
            node = node[p]
        node[parts[-1]] = value
    return scene


def load_script(name: str):
    """Import ``scripts/<name>.py`` as a module (the scripts are not a package)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location(name, ROOT / "scripts" / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def config_error(raw) -> str:
    """The one-line ConfigError message a raw scene mapping is refused with."""
    from poromech.errors import ConfigError
    from poromech.scene.loading import scene_from_dict

    with pytest.raises(ConfigError) as info:
        scene_from_dict(raw)
    msg = str(info.value)
    assert "\n" not in msg
    return msg


def flow_3d_available() -> bool:
    """Whether this version runs physics 'flow' in a box (3D); False while it is refused."""
    from poromech.errors import ConfigError
    from poromech.scene.loading import scene_from_dict

    raw = {"name": "flow3d", "physics": "flow", "mesh": {"size": 0.5},
           "geometry": {"domain": {"box": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0]}},
           "flow": {"permeability": [1.0],
                    "boundary_conditions": [{"boundary": "left", "pressure": 0.0}]}}
    try:
        scene_from_dict(raw)
    except ConfigError as err:
        if "not available in 3D" in str(err):
            return False
        raise
    return True


def is_flow_3d_scene(path: Path) -> bool:
    """A scene file of physics 'flow' in a box (its geometry inline or by name)."""
    from poromech.scene.loading import resolve_geometry

    raw = resolve_geometry(yaml.safe_load(Path(path).read_text()))
    return raw.get("physics") == "flow" and "box" in (raw["geometry"].get("domain") or {})


#: Skip a test that runs or validates a 3D flow scene while this version refuses 3D flow.
needs_flow_3d = pytest.mark.skipif(not flow_3d_available(),
                                   reason="physics 'flow' is not available in 3D in this version")


def flow_properties(fm, perm, aperture=1e-2, kn=np.nan, kt=np.nan, cond=np.nan):
    """FlowProperties of a flow test: ``perm`` one ``(d, d)`` tensor; fracture values scalars or
    one per fracture; viscosity 1, no storage."""
    from poromech.flow.problem import FlowProperties

    d = fm.msh.topology.dim
    nc = fm.msh.topology.index_map(d).size_local
    nf = len(fm.fractures.facets)

    def per_face(v):
        v = np.asarray(v, dtype=float)
        return v[fm.fractures.fracture] if v.ndim else np.full(nf, float(v))

    return FlowProperties(
        permeability=np.broadcast_to(perm, (nc, d, d)).copy(), viscosity=1.0,
        aperture=per_face(aperture), fracture_permeability=per_face(kt),
        normal_permeability=per_face(kn), conductivity=per_face(cond), storage=np.zeros(nc),
    )
