"""Shared test helpers: running a snippet under ``mpirun -n 2`` and reading its JSON result."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

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
    script = Path(os.environ.get("TMPDIR", "/tmp")) / f"poromech_mpi_{os.getpid()}_{abs(hash(code))}.py"
    script.write_text(textwrap.dedent(code))
    try:
        proc = subprocess.run(
            [mpirun(), "-n", str(nprocs), sys.executable, str(script)],
            capture_output=True, text=True, timeout=timeout, cwd=ROOT,
        )
    finally:
        script.unlink(missing_ok=True)
    if proc.returncode != 0:
        pytest.fail(f"mpirun failed ({proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("{")]
    if not lines:
        pytest.fail(f"no JSON result from the parallel run:\n{proc.stdout[-3000:]}")
    return json.loads(lines[-1])
