"""The coupled six-fracture scene of Beaude et al. (2023, §3): runs, figures, costs.

The paper's figures, error against run time and the cost of the coupled solver.

Runs go through the command line exactly as a user runs them (``python -m poromech run
configs/six_fractures.yaml --set ...``, under ``mpirun -n R`` for R > 1) into
``results/study/<tag>``; a run whose ``summary.json`` says ``converged`` is not repeated (pass
``--again`` to repeat it). Then ``report`` reads the outputs back (XDMF series, summary.json) and
writes CSV, Markdown and PNG to ``docs/poromechanics/``::

    python scripts/poromechanics_study.py paper        # m = 0, 1: Figs. 2-6, g evaluations
    python scripts/poromechanics_study.py reference    # mixed, nitsche P2 on m = 2, 3, 4
    python scripts/poromechanics_study.py accuracy     # formulations x degrees, m = 0-3
    python scripts/poromechanics_study.py performance  # accelerators, ranks, unit solve costs
    python scripts/poromechanics_study.py newtonkrylov # the paper's method against Anderson
    python scripts/poromechanics_study.py report       # all figures and tables from what was run

``report`` builds the reference of the error study from the ``reference`` runs (Richardson
extrapolation over m = 2, 3, 4 where the convergence is regular, the mean of ``mixed`` and
``nitsche``; :func:`build_reference`) and writes the errors of every run of ``accuracy`` against
it, the least error within each time budget and the construction of the reference
(``accuracy.{md,csv,png}``, ``reference.csv``, ``reference_spread.csv``,
``accuracy_budget.csv``).

Wall times are those of the whole process (start-up, mesh, set-up, 20 steps, output), with the
forms already compiled (every configuration is run once beforehand on one step).
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from flow_common import markdown_table, write_csv  # noqa: F401  (re-exported for scripts)

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "configs" / "six_fractures.yaml"
RUNS = ROOT / "results" / "study"
DOCS = ROOT / "docs" / "poromechanics"
FORMULATIONS = ("mixed", "stabilized_mixed", "mean_nitsche", "nitsche")
METHODS = ("anderson", "ngmres", "qn", "composite", "newtonkrylov", "picard")
T, QUARTER = 2000.0, 500.0
STATE_COLORS = ("tab:blue", "tab:green", "tab:red")  # open, stick, slip (the paper's Fig. 2)

#: Meshes of the reference ladder (Richardson over the last three).
REFERENCE_LADDER = (2, 3, 4)
#: The two reference solutions on the finest mesh (P2, 2 ranks).
REFERENCE_FORMULATIONS = ("mixed", "nitsche")
#: Overrides of the m = 4 runs, to fit in the memory of the 24-GB machine: CG + GAMG for Darcy
#: (relative tolerance 1e-12) instead of MUMPS, and the contact factorizations out of core
#: (MUMPS ICNTL(22) = 1: the factors, 6.5 GB on m = 4, go to files under /tmp and the page
#: cache). In core the condensed set-up of ``mixed`` holds two such factorizations at once and
#: a 2-rank run passed 22.7 GB before it was stopped. On m = 2 both change the fields by less
#: than 1e-9 relative (docs/poromechanics/reference.md).
FINE_SETS = ("flow.linear_solver=iterative", "solver.petsc.mat_mumps_icntl_22=1")


# -- running -----------------------------------------------------------------------------------
def tag(m: int, formulation: str, degree: int, method: str = "anderson", ranks: int = 1) -> str:
    """Directory name of one run."""
    return f"m{m}_{formulation}_P{degree}_{method}_n{ranks}"


def parse(run: str) -> dict:
    """The configuration of a run from its directory name (see :func:`tag`)."""
    m = re.fullmatch(r"m(\d+)_(.+)_P(\d)_([a-z]+)_n(\d+)", run)
    return {"m": int(m[1]), "formulation": m[2], "degree": int(m[3]), "method": m[4],
            "ranks": int(m[5])}


def label(run: str) -> str:
    """Formulation and degree of a run, for legends."""
    c = parse(run)
    return f"{c['formulation']} P{c['degree']}"


def _mpirun() -> str:
    return str(Path(sys.executable).with_name("mpirun"))


def _command(ranks: int, args: list[str], memory: Path | None = None) -> list[str]:
    """``python -m poromech args`` on ``ranks`` ranks.

    With ``memory``, every rank runs under ``/usr/bin/time -v`` writing ``memory/time.<rank>``
    (peak resident memory of that rank: :func:`peak_memory`).
    """
    cmd = [sys.executable, "-m", "poromech", *args]
    if memory is not None:
        cmd = ["sh", "-c", 'exec /usr/bin/time -v -o "$0/time.${PMI_RANK:-0}" "$@"',
               str(memory), *cmd]
    return [_mpirun(), "-n", str(ranks), *cmd] if ranks > 1 else cmd


def peak_memory(out: Path) -> tuple[float, float] | None:
    """Peak resident memory (GB) of the largest rank and summed over the ranks of a run."""
    peaks = []
    for f in sorted(out.glob("time.*")):
        m = re.search(r"Maximum resident set size \(kbytes\): (\d+)", f.read_text())
        if m:
            peaks.append(int(m[1]) * 1024 / 1e9)
    return (max(peaks), sum(peaks)) if peaks else None


def run_cli(out: Path, scene: Path, sets: list[str], ranks: int = 1, again: bool = False,
            timeout: float = 7200, warm: bool = True, memory: bool = False) -> dict:
    """Run ``poromech run scene --set ...`` into ``out`` (unless done); summary + process time.

    With ``warm``, the configuration is first run for one short step so that the forms are
    compiled before the timed run. With ``memory``, each rank runs under ``/usr/bin/time -v``
    and the peak resident memory is recorded (``peak_memory_gb``: largest rank, sum of ranks).
    """
    record = out / "study.json"
    if record.exists() and not again:
        done = json.loads(record.read_text())
        if done["status"] == "converged" or not done.get("retry", False):
            return done
    args = ["run", str(scene), "-o", str(out), "--overwrite", "-q"]
    args += [a for s in sets for a in ("--set", s)]
    if warm:
        short = [s for s in sets if not s.startswith(("mesh.", "time"))]
        subprocess.run(_command(1, ["run", str(scene), "-o", str(RUNS / "warmup"), "--overwrite",
                                    "-q", *[a for s in short for a in ("--set", s)],
                                    "--set", "time={times: [1.0]}"]),
                       cwd=ROOT, capture_output=True, timeout=timeout)
    out.mkdir(parents=True, exist_ok=True)
    for f in out.glob("time.*"):
        f.unlink()
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(_command(ranks, args, out if memory else None), cwd=ROOT,
                              capture_output=True, text=True, timeout=timeout)
        code, err = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired:
        code, err = -1, f"timed out after {timeout:g} s"
    wall = time.perf_counter() - t0
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() \
        else {"status": f"failed: {err.strip()[-300:]}"}
    summary["process_seconds"] = wall
    summary["exit_status"] = code
    summary["stderr"] = err.strip()[-2000:]
    summary["sets"] = sets
    summary["peak_memory_gb"] = peak_memory(out)
    # the machine is shared: the load average (1 min) before and after flags disturbed times
    summary["load_average"] = [load, os.getloadavg()[0]]
    record.write_text(json.dumps(summary))
    print(f"{out.name}: {summary['status'][:70]}, {wall:.1f} s, "
          f"{summary.get('coupling', {}).get('g_evaluations')} g evaluations", flush=True)
    return summary


def run_case(m: int, formulation: str, degree: int, method: str = "anderson", ranks: int = 1,
             again: bool = False, timeout: float = 7200, extra: tuple[str, ...] = (),
             memory: bool = False) -> dict:
    """Run one configuration of the six-fracture scene (if not done yet).

    ``extra`` are further ``--set`` overrides (recorded in ``study.json`` under ``sets``).
    """
    sets = [f"mesh.refinement={m}", f"contact.formulation={formulation}", f"degree={degree}",
            f"coupling.method={method}", *extra]
    return run_cli(RUNS / tag(m, formulation, degree, method, ranks), SCENE, sets, ranks, again,
                   timeout, memory=memory)


def unit_costs(m: int, degree: int, ranks: int) -> dict:
    """Seconds of one linear elastic solve and one Darcy solve on mesh ``m`` (``ranks`` ranks)."""
    out = RUNS / f"unit_m{m}_P{degree}_n{ranks}.json"
    RUNS.mkdir(parents=True, exist_ok=True)
    if out.exists():
        return json.loads(out.read_text())
    code = f"import sys; sys.path.insert(0, {str(ROOT / 'scripts')!r}); " \
           f"import poromechanics_study as s; s._measure_units({m}, {degree}, {str(out)!r})"
    cmd = [sys.executable, "-c", code]
    if ranks > 1:
        cmd = [_mpirun(), "-n", str(ranks), *cmd]
    subprocess.run(cmd, cwd=ROOT, check=True, timeout=7200)
    return json.loads(out.read_text())


def _measure_units(m: int, degree: int, path: str) -> None:
    """One elastic solve and one Darcy solve of the scene's mesh, after a first one.

    Elastic: assembly, numeric factorization, solve. Darcy: matrix values, factorization or
    AMG set-up, solve.
    """
    import dolfinx_solver  # noqa: F401

    import ufl
    from dolfinx import fem
    from dolfinx.fem.petsc import assemble_matrix, assemble_vector, create_matrix
    from mpi4py import MPI
    from petsc4py import PETSc

    from poromech.flow.setup import problem_from_scene
    from poromech.forms.elasticity import elastic_form
    from poromech.mesh.fractured import cracked_space
    from poromech.run import build_mesh
    from poromech.scene.loading import load_scene

    comm = MPI.COMM_WORLD
    scene = load_scene(SCENE, [f"mesh.refinement={m}", f"degree={degree}"])
    fm = build_mesh(scene, comm)
    V = cracked_space(fm, degree)
    u, v = ufl.TrialFunction(V), ufl.TestFunction(V)
    dx = ufl.Measure("dx", domain=fm.msh)
    a = fem.form(elastic_form(u, v, 4e9, 0.2, dx))
    L = fem.form(ufl.dot(fem.Constant(fm.msh, np.array([0.0, -1e4])), v) * dx)
    facets = fm.boundary_facets[np.isin(fm.boundary_edge, (0,))]
    bc = fem.dirichletbc(np.zeros(2), fem.locate_dofs_topological(V, 1, facets), V)
    A = create_matrix(a)
    ksp = PETSc.KSP().create(comm)
    ksp.setType("preonly")
    ksp.getPC().setType("lu")
    ksp.getPC().setFactorSolverType("mumps")
    x = A.createVecRight()

    def elastic() -> float:
        t0 = time.perf_counter()
        A.zeroEntries()
        assemble_matrix(A, a, [bc])
        A.assemble()
        b = assemble_vector(L)
        fem.petsc.apply_lifting(b, [a], [[bc]])
        b.ghostUpdate(addv=PETSc.InsertMode.ADD, mode=PETSc.ScatterMode.REVERSE)
        fem.petsc.set_bc(b, [bc])
        ksp.setOperators(A)
        ksp.solve(b, x)
        return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)

    elastic()
    t_elastic = min(elastic() for _ in range(2))
    problem = problem_from_scene(scene, fm)
    problem.set_pressure(scene.flow.initial_pressure, 0.0)

    def darcy() -> float:
        problem.set_aperture(problem.properties.aperture * 1.0001)  # new values: new set-up
        t0 = time.perf_counter()
        problem.solve(0.0)
        return comm.allreduce(time.perf_counter() - t0, op=MPI.MAX)

    darcy()
    t_darcy = min(darcy() for _ in range(2))
    if comm.rank == 0:
        Path(path).write_text(json.dumps({"elastic": t_elastic, "darcy": t_darcy,
                                          "dofs": V.dofmap.index_map.size_global * 2,
                                          "flow_unknowns": problem.dofs.num_global}))


# -- reading results ---------------------------------------------------------------------------
def _series(run: str, stem: str):
    from poromech.io.xdmf import read_series

    return read_series(RUNS / run, stem)


def fracture_table(run: str):
    """Face lengths, fracture ids, arc lengths and the fracture series of a run."""
    frac = _series(run, "fractures")
    seg = frac.points[frac.cells]
    length = np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)
    rows = np.genfromtxt(RUNS / run / "fractures.csv", delimiter=",", names=True, dtype=None,
                         encoding=None, max_rows=len(length))
    return length, np.asarray(rows["fracture"]).astype(str), np.asarray(rows["s"]), frac


def mean_aperture(run: str) -> tuple[np.ndarray, np.ndarray]:
    """Times and length-weighted mean aperture over all fractures (m)."""
    length, _, _, frac = fracture_table(run)
    values = [length @ frac.fields(k)["aperture"] / length.sum() for k in range(len(frac.times))]
    return np.asarray(frac.times), np.asarray(values)


def jumps_at(run: str, t: float):
    """Per fracture: arc length, normal and tangential jump at time ``t``."""
    _, names, s, frac = fracture_table(run)
    f = frac.at(t)
    return {n: (s[names == n], f["jump_n"][names == n], f["jump_t"][names == n])
            for n in np.unique(names)}


def summary(run: str) -> dict:
    return json.loads((RUNS / run / "study.json").read_text())


# -- figures and tables ------------------------------------------------------------------------
def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, name: str) -> None:
    path = DOCS / name
    fig.savefig(path, dpi=100, bbox_inches="tight")
    _plt().close(fig)
    size = path.stat().st_size / 1024
    if size > 300:
        raise RuntimeError(f"{name} is {size:.0f} KB (limit 300 KB)")


def _provenance(command: str) -> str:
    return f"Generated {datetime.date.today()} by `python scripts/poromechanics_study.py {command}`"


def figure_states(run: str) -> None:
    """Fig. 2: contact state along the fractures at T/4 and T."""
    plt = _plt()
    frac = _series(run, "fractures")
    fig, axes = plt.subplots(1, 2, figsize=(11, 3.2))
    for ax, t in zip(axes, (QUARTER, T), strict=True):
        state = frac.at(t)["state"].astype(int)
        seg = frac.points[frac.cells]
        for code, color in enumerate(STATE_COLORS):
            for a, b in seg[state == code]:
                ax.plot([a[0], b[0]], [a[1], b[1]], color=color, lw=2.5)
        ax.set_xlim(0, 2)
        ax.set_ylim(0, 1)
        ax.set_aspect("equal")
        ax.set_title(f"t = {t:g} s")
    handles = [plt.Line2D([], [], color=c, lw=3) for c in STATE_COLORS]
    fig.legend(handles, ["open", "stick", "slip"], loc="lower center", ncol=3)
    fig.suptitle(f"Contact state ({run})")
    _save(fig, "states.png")


def figure_overpressure(run: str) -> None:
    """Fig. 3: matrix overpressure at T/4 and T, drawn from flow.xdmf off-screen."""
    plt = _plt()
    from matplotlib.tri import Triangulation

    flow = _series(run, "flow")
    tri = Triangulation(flow.points[:, 0], flow.points[:, 1], flow.cells)
    fig, axes = plt.subplots(1, 2, figsize=(12, 3.4))
    for ax, t in zip(axes, (QUARTER, T), strict=True):
        op = flow.at(t)["overpressure"]
        pc = ax.tripcolor(tri, facecolors=op, cmap="viridis", shading="flat")
        ax.set_aspect("equal")
        ax.set_title(f"overpressure (Pa), t = {t:g} s")
        fig.colorbar(pc, ax=ax, shrink=0.8)
    _save(fig, "overpressure.png")


def figure_mean_aperture(runs: dict[str, list[str]], name: str = "mean_aperture.png") -> None:
    """Fig. 4: mean aperture against time, one panel per formulation, one line per mesh."""
    plt = _plt()
    fig, axes = plt.subplots(1, len(runs), figsize=(4.2 * len(runs), 3.4), sharey=True)
    for ax, (title, items) in zip(np.atleast_1d(axes), runs.items(), strict=True):
        for run in items:
            t, a = mean_aperture(run)
            ax.plot(t, a * 1e6, label=f"m = {parse(run)['m']}")
        ax.set_title(title)
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
        ax.legend()
    np.atleast_1d(axes)[0].set_ylabel("mean aperture (µm)")
    _save(fig, name)


def figure_jumps(runs: list[str], delta0: float = 1e-4) -> None:
    """Fig. 5: normal jump along fractures 1 and 6 at T (m = 0), scaled by δ₀."""
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.4))
    for ax, fracture in zip(axes, ("1", "6"), strict=True):
        for run in runs:
            s, jn, _ = jumps_at(run, T)[fracture]
            ax.plot(s, -jn / delta0, ".-", label=label(run))
        ax.set_title(f"fracture {fracture}, t = T")
        ax.set_xlabel("arc length s (m)")
        ax.set_ylabel("-[[u]]_n / δ₀")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    _save(fig, "jumps.png")


def figure_newton(runs: dict[str, list[str]]) -> None:
    """Fig. 6: contact Newton iterations per time step (all g evaluations of the step).

    A run with the condensed ``mixed`` solve is drawn dashed with its face Newton iterations
    (its regular Newton takes none: it only checks the condensed result).
    """
    plt = _plt()
    fig, axes = plt.subplots(1, len(runs), figsize=(5 * len(runs), 3.4), sharey=True)
    for ax, (title, items) in zip(np.atleast_1d(axes), runs.items(), strict=True):
        for run in items:
            s = summary(run)
            face = any(r.get("face_iterations") for r in s["solves"])
            ax.plot([r["time"] for r in s["solves"]],
                    [r["newton_iterations"] + r.get("face_iterations", 0) for r in s["solves"]],
                    "o--" if face else "o-", ms=3,
                    label=label(run) + (" (face Newton, condensed)" if face else ""))
        ax.set_title(title)
        ax.set_xlabel("t (s)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    np.atleast_1d(axes)[0].set_ylabel("Newton iterations per step")
    _save(fig, "newton.png")


def errors_against(run: str, ref: str) -> tuple[float, float]:
    """Relative L² errors of the mean aperture over time and of the jumps at T.

    The reference jumps are interpolated at the run's face midpoints by arc length.
    """
    t, a = mean_aperture(run)
    tr, ar = mean_aperture(ref)
    e_ap = np.sqrt(np.sum((a - np.interp(t, tr, ar)) ** 2) / np.sum(ar**2))
    length, names, _, _ = fracture_table(run)
    mine, theirs = jumps_at(run, T), jumps_at(ref, T)
    num = den = 0.0
    for n, (s, jn, jt) in mine.items():
        sr, jnr, jtr = theirs[n]
        o = np.argsort(sr)
        w = length[names == n]
        rn, rt = np.interp(s, sr[o], jnr[o]), np.interp(s, sr[o], jtr[o])
        num += np.sum(w * ((jn - rn) ** 2 + (jt - rt) ** 2))
        den += np.sum(w * (rn**2 + rt**2))
    return float(e_ap), float(np.sqrt(num / den))


# -- the reference -----------------------------------------------------------------------------
#: The error measures of the study, in table order: relative L² error of the mean aperture over
#: the output times, of the normal and tangential jumps along all fractures at T, of the
#: tangential jump along fracture 1 at T, and the relative error of the mean matrix overpressure
#: at T.
MEASURES = ("mean aperture", "jumps at T", "fracture-1 slip at T", "mean overpressure at T")
#: A sequence m = 2, 3, 4 is extrapolated (Richardson) only when its differences contract at an
#: observed order in this range and keep their shape (cosine of successive differences, for
#: arrays; the same sign, for scalars) above :data:`REGULAR_COSINE`.
REGULAR_ORDER = (0.5, 4.0)
REGULAR_COSINE = 0.9


@dataclass
class Solution:
    """What the error measures compare, for one run or for the reference.

    Attributes:
        name: Run name, or ``reference``.
        times: Output times (s).
        aperture: Length-weighted mean aperture over all fractures at each output time (m).
        jumps: Per fracture: arc length of the face midpoints (m), face lengths (m), normal and
            tangential jump at T (m).
        overpressure: Area-weighted mean matrix overpressure at T (Pa).
        slip1: Tangential jump along fracture 1 at T at the faces of ``jumps["1"]`` (m), when it
            is not that of ``jumps`` (a reference whose measures were estimated separately).
    """

    name: str
    times: np.ndarray
    aperture: np.ndarray
    jumps: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    overpressure: float
    slip1: np.ndarray | None = None

    def on(self, grid: Solution) -> Solution:
        """The same solution with its jumps interpolated (by arc length) on ``grid``'s faces."""
        jumps, slip1 = {}, None
        for n, (s, w, _, _) in grid.jumps.items():
            so, _, jn, jt = self.jumps[n]
            o = np.argsort(so)
            jumps[n] = (s, w, np.interp(s, so[o], jn[o]), np.interp(s, so[o], jt[o]))
            if n == "1" and self.slip1 is not None:
                slip1 = np.interp(s, so[o], self.slip1[o])
        return Solution(self.name, self.times, self.aperture, jumps, self.overpressure, slip1)

    def vectors(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each measure's values and weights (a scalar is a vector of one)."""
        names = sorted(self.jumps)
        w = np.concatenate([self.jumps[n][1] for n in names])
        jn = np.concatenate([self.jumps[n][2] for n in names])
        jt = np.concatenate([self.jumps[n][3] for n in names])
        s1 = self.jumps["1"]
        return {"mean aperture": (self.aperture, np.ones_like(self.aperture)),
                "jumps at T": (np.concatenate([jn, jt]), np.concatenate([w, w])),
                "fracture-1 slip at T": (s1[3] if self.slip1 is None else self.slip1, s1[1]),
                "mean overpressure at T": (np.array([self.overpressure]), np.ones(1))}

    def replaced(self, values: dict[str, np.ndarray], name: str) -> Solution:
        """A solution on the same faces with the measures' values replaced."""
        names = sorted(self.jumps)
        sizes = np.cumsum([0] + [len(self.jumps[n][0]) for n in names])
        both = values["jumps at T"]
        jumps = {}
        for k, n in enumerate(names):
            s, w, _, _ = self.jumps[n]
            jumps[n] = (s, w, both[sizes[k]:sizes[k + 1]],
                        both[sizes[-1] + sizes[k]:sizes[-1] + sizes[k + 1]])
        return Solution(name, self.times, values["mean aperture"], jumps,
                        float(values["mean overpressure at T"][0]),
                        values["fracture-1 slip at T"])


def _cell_areas(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    a, b, c = (points[cells[:, k]] for k in range(3))
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                        - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def mean_overpressure(run: str, t: float = T) -> float:
    """Area-weighted mean of the matrix overpressure at ``t`` (Pa)."""
    flow = _series(run, "flow")
    area = _cell_areas(flow.points, flow.cells)
    return float(area @ flow.at(t)["overpressure"] / area.sum())


def solution(run: str) -> Solution:
    """The compared quantities of a run."""
    t, a = mean_aperture(run)
    length, names, _, _ = fracture_table(run)
    jumps = {n: (s, length[names == n], jn, jt) for n, (s, jn, jt) in jumps_at(run, T).items()}
    return Solution(run, t, a, jumps, mean_overpressure(run))


def _norm(x: np.ndarray, w: np.ndarray) -> float:
    return float(np.sqrt(np.sum(w * x**2)))


def errors(sol: Solution, ref: Solution) -> dict[str, float]:
    """Relative errors of :data:`MEASURES` of ``sol`` against ``ref``, on ``sol``'s faces."""
    mine, theirs = sol.vectors(), ref.on(sol).vectors()
    assert np.allclose(sol.times, ref.times)
    return {k: _norm(mine[k][0] - theirs[k][0], mine[k][1]) / _norm(theirs[k][0], mine[k][1])
            for k in MEASURES}


def richardson(q: list[np.ndarray], w: np.ndarray) -> dict:
    """Richardson extrapolation of ``q = [q_m2, q_m3, q_m4]`` (same points) with observed order.

    Returns the observed order ``p`` (halving h), the cosine of the successive differences, the
    ratio of their norms, whether the sequence is regular (:data:`REGULAR_ORDER`,
    :data:`REGULAR_COSINE`), and the extrapolated values ``q4 + d2 / (2^p - 1)`` (None when
    not regular).
    """
    d1, d2 = q[1] - q[0], q[2] - q[1]
    n1, n2 = _norm(d1, w), _norm(d2, w)
    cos = float(np.sum(w * d1 * d2) / (n1 * n2)) if n1 > 0 and n2 > 0 else 0.0
    ratio = n1 / n2 if n2 > 0 else np.inf
    p = float(np.log2(ratio)) if 0 < ratio < np.inf else np.nan
    regular = bool(REGULAR_ORDER[0] <= p <= REGULAR_ORDER[1] and cos >= REGULAR_COSINE)
    return {"order": p, "cosine": cos, "ratio": ratio, "regular": regular,
            "extrapolated": q[2] + d2 / (ratio - 1.0) if regular else None}


def _ladder(f: str, ladder, ranks: int, done: set[str]) -> list[int]:
    """The meshes of ``ladder`` on which ``f`` P2 ran to the end (from the coarsest, no gap)."""
    ran = []
    for m in ladder:
        if tag(m, f, 2, ranks=ranks) not in done:
            break
        ran.append(m)
    return ran


@dataclass
class Reference:
    """The reference of the error study and how it was built.

    Attributes:
        solution: The reference values on the faces of the finest ``mixed`` run.
        rows: Per formulation and measure: meshes, observed order, cosine, extrapolated or not,
            last-refinement change, extrapolation change.
        spread: Per measure: relative differences between the formulations' finest solutions
            and between their estimates (the reference's own uncertainty).
        used: The formulations whose estimates were averaged (complete ladder).
        finest: Per formulation, the finest mesh it ran on.
    """

    solution: Solution
    rows: list[list]
    spread: list[list]
    used: list[str]
    finest: dict[str, int]


def build_reference(done: set[str], formulations=REFERENCE_FORMULATIONS,
                    ladder=REFERENCE_LADDER, ranks: int = 2) -> Reference | None:
    """The reference solution and the rows of its construction (see reference.md).

    For each formulation and measure, the solutions on the meshes of ``ladder`` (on the faces
    of the finest) are extrapolated where regular (:func:`richardson`), else the finest is
    taken. The reference is the mean of the estimates of the formulations that ran on the whole
    ladder; a formulation that stopped earlier (the m = 4 ``nitsche`` run needs more memory than
    the machine has) still gives its finest solution, compared with the reference in ``spread``
    (an upper bound of the reference's uncertainty: it includes that formulation's own error).
    """
    ladders = {f: _ladder(f, ladder, ranks, done) for f in formulations}
    used = [f for f in formulations if ladders[f] == list(ladder)]
    if not used:
        return None
    sols = {f: [solution(tag(m, f, 2, ranks=ranks)) for m in ladders[f]] for f in formulations}
    grid = sols[used[0]][-1]
    estimates: dict[str, dict[str, np.ndarray]] = {f: {} for f in formulations}
    rows = []
    for f in formulations:
        if not ladders[f]:
            continue
        seq = [s.on(grid).vectors() for s in sols[f]]
        for k in MEASURES:
            w = seq[-1][k][1]
            last = seq[-1][k][0]
            if len(seq) >= 3:
                r = richardson([v[k][0] for v in seq[-3:]], w)
            else:
                r = {"order": np.nan, "cosine": np.nan, "regular": False}
            estimates[f][k] = r["extrapolated"] if r["regular"] else last
            d2 = _norm(last - seq[-2][k][0], w) / _norm(last, w) if len(seq) >= 2 else np.nan
            change = _norm(estimates[f][k] - last, w) / _norm(last, w)
            meshes = "-".join(f"m{m}" for m in ladders[f])
            rows.append([f, meshes, k, r["order"], r["cosine"],
                         "yes" if r["regular"] else "no", d2, change])
    values = {k: np.mean([estimates[f][k] for f in used], axis=0) for k in MEASURES}
    ref = grid.replaced(values, "reference")
    spread = []
    others = [f for f in formulations if ladders[f]]
    a, b = others[0], others[1] if len(others) > 1 else others[0]
    for k in MEASURES:
        w = grid.vectors()[k][1]
        fa = sols[a][-1].on(grid).vectors()[k][0]
        fb = sols[b][-1].on(grid).vectors()[k][0]
        scale = _norm(values[k], w)
        spread.append([k, _norm(fa - fb, w) / scale,
                       _norm(estimates[a][k] - estimates[b][k], w) / scale,
                       _norm(estimates[a][k] - sols[a][-1].on(grid).vectors()[k][0], w) / scale])
    return Reference(ref, rows, spread, used, {f: ladders[f][-1] for f in others})


def least_error_per_budget(rows: list[list], budgets=(5, 10, 20, 50, 100, 200, 500, 1000)):
    """For each time budget and measure: the run with the least error within the budget.

    ``rows`` are ``[run, seconds, *errors in MEASURES order]``.
    """
    out = []
    for budget in budgets:
        row = [budget]
        for j, _ in enumerate(MEASURES):
            ok = [r for r in rows if r[1] <= budget]
            if not ok:
                row.append("–")
                continue
            best = min(ok, key=lambda r: r[2 + j])
            c = parse(best[0])
            row.append(f"{c['formulation']} P{c['degree']} m{c['m']} ({best[2 + j]:.2g}, "
                       f"{best[1]:.0f} s)")
        out.append(row)
    return out


# -- the studies -------------------------------------------------------------------------------
def paper(meshes=(0, 1), again: bool = False) -> None:
    for m in meshes:
        for f in FORMULATIONS:
            run_case(m, f, 2, again=again)


#: Finest mesh of the error table (the reference ladder's m = 4 runs are not contestants).
REFERENCE_MESH = 3


def accuracy(meshes=(0, 1, 2), again: bool = False) -> None:
    """Every formulation and degree on ``meshes``, and on m = 3 where affordable.

    m = 3: P1 of the three formulations that have it (2-3 min each), P2 ``mixed`` and
    ``nitsche`` (the reference ladder), P2 ``stabilized_mixed`` and ``mean_nitsche`` (about
    15 min each).
    """
    for m in meshes:
        for f in FORMULATIONS:
            for d in (1, 2):
                if (f, d) == ("mixed", 1):
                    continue  # P1-P0 is not inf-sup stable (docs/mechanics.md)
                run_case(m, f, d, ranks=2 if m >= 2 else 1, again=again)
    unit_costs(REFERENCE_MESH, 2, 2)  # the cost ratio on the finest mesh
    for f in FORMULATIONS:
        for d in (1, 2):
            if (f, d) != ("mixed", 1):
                run_case(REFERENCE_MESH, f, d, ranks=2, again=again)


def reference_runs(again: bool = False) -> None:
    """The runs of the reference: ``mixed`` and ``nitsche`` P2 on m = 2, 3, 4 (2 ranks).

    The m = 4 runs are measured with ``/usr/bin/time -v`` (peak memory per rank).
    """
    for m in REFERENCE_LADDER:
        for f in REFERENCE_FORMULATIONS:
            fine = m == max(REFERENCE_LADDER)
            run_case(m, f, 2, ranks=2, again=again, timeout=8 * 3600,
                     extra=FINE_SETS if fine else (), memory=fine)


#: Repeated timings: ``results/study_timing/<tag>_r<k>``.
TIMING = ROOT / "results" / "study_timing"


def timing(repeats: int = 2, meshes=(0, 1, 2), again: bool = False) -> None:
    """Run the configurations of :func:`accuracy` on ``meshes`` ``repeats`` more times.

    The machine is shared: the error table takes, per configuration, the least process time of
    the study run and these repeats (:func:`process_seconds`); their outputs are not used.
    """
    for k in range(repeats):
        for m in meshes:
            for f in FORMULATIONS:
                for d in (1, 2):
                    if (f, d) == ("mixed", 1):
                        continue
                    ranks = 2 if m >= 2 else 1
                    sets = [f"mesh.refinement={m}", f"contact.formulation={f}", f"degree={d}",
                            "coupling.method=anderson"]
                    run_cli(TIMING / f"{tag(m, f, d, ranks=ranks)}_r{k}", SCENE, sets, ranks,
                            again)


def process_seconds(run: str) -> float:
    """Least process time of a run and of its repeats (:func:`timing`), s."""
    times = [summary(run)["process_seconds"]]
    for p in TIMING.glob(f"{run}_r*/study.json"):
        s = json.loads(p.read_text())
        if s["status"] == "converged":
            times.append(s["process_seconds"])
    return min(times)


def performance(again: bool = False) -> None:
    for method in METHODS:  # the scene's formulation; anderson runs all four in ``paper``
        run_case(0, "nitsche", 2, method, again=again)
    for ranks in (1, 2):
        for f in FORMULATIONS:
            run_case(1, f, 2, "anderson", ranks, again=again)
        unit_costs(0, 2, ranks)
        unit_costs(1, 2, ranks)
    run_case(2, "mixed", 2, ranks=2, again=again)
    unit_costs(2, 2, 2)
    run_case(3, "mixed", 2, ranks=2, again=again)  # the fastest formulation on the finest mesh


def newtonkrylov(again: bool = False) -> None:
    """The paper's fixed-point method, matrix-free Newton-Krylov, against Anderson.

    Every formulation (P2) on m = 0 (1 rank) and m = 1 (2 ranks); writes
    ``newton_krylov.csv`` and ``newton_krylov.md``: ``g`` evaluations (the paper: 190 for the 20
    steps, the same for all methods), Newton iterations on ``p - g(p)``, contact Newton
    iterations, time, and the largest difference of the mean aperture from Anderson's run.
    """
    rows = []
    for m, ranks in ((0, 1), (1, 2)):
        for f in FORMULATIONS:
            runs = {k: tag(m, f, 2, k, ranks) for k in ("newtonkrylov", "anderson")}
            done = {k: run_case(m, f, 2, k, ranks, again=again) for k in runs}
            nk, an = done["newtonkrylov"], done["anderson"]
            row = [m, ranks, f, nk["status"]]
            if nk["status"] != "converged" or an["status"] != "converged":
                rows.append(row + [""] * 7)
                continue
            (t, a), (t2, b) = mean_aperture(runs["newtonkrylov"]), mean_aperture(runs["anderson"])
            assert np.allclose(t, t2)
            c, ca = nk["coupling"], an["coupling"]
            rows.append(row + [c["g_evaluations"], c["iterations"], c["newton_iterations"],
                               nk["process_seconds"], ca["g_evaluations"], an["process_seconds"],
                               float(np.abs(a - b).max() / np.abs(b).max())])
    header = ["m", "ranks", "formulation", "Newton-Krylov", "g evaluations", "Newton it on p",
              "contact Newton it", "process s", "Anderson g evaluations", "Anderson process s",
              "mean aperture difference"]
    DOCS.mkdir(parents=True, exist_ok=True)
    write_csv(DOCS / "newton_krylov.csv", header, rows, _provenance("newtonkrylov"))
    (DOCS / "newton_krylov.md").write_text(
        "# Matrix-free Newton-Krylov on the coupled six-fracture scene\n\n"
        f"{_provenance('newtonkrylov')}. 20 steps, P2, relative fixed-point tolerance 1e-5 "
        "(the paper: 190 `g` evaluations, the same for all methods). *mean aperture "
        "difference*: largest difference of the mean aperture over the 20 steps from the "
        "Anderson run, relative to its largest value.\n\n" + markdown_table(header, rows))


def report(partial: bool = False) -> None:
    """The tables and figures of docs/poromechanics from the study runs in results/study.

    Refused when runs of the committed runs.csv are missing there (five local runs rewrote
    its 24 rows with 5), unless ``partial``.
    """
    DOCS.mkdir(parents=True, exist_ok=True)
    done = {p.name for p in RUNS.glob("m*_*") if (p / "study.json").exists()
            and summary(p.name)["status"] == "converged"}
    if not done:
        raise SystemExit(f"no converged study run in {RUNS}: run the studies first (see the "
                         "module docstring); report only redraws from their results")
    if (DOCS / "runs.csv").exists() and not partial:
        with open(DOCS / "runs.csv") as fh:
            committed = {r["run"] for r in csv.DictReader(ln for ln in fh
                                                          if not ln.startswith("#"))}
        missing = sorted(committed - done)
        if missing:
            raise SystemExit(f"{len(missing)} runs of {DOCS / 'runs.csv'} are not in {RUNS} "
                             f"(e.g. {', '.join(missing[:3])}): run them first, or give "
                             f"--partial to write the tables of the {len(done)} present")
    ref = build_reference(done)
    # the figures' run: the finest mesh, nitsche, P2, fewest ranks, then by name (the key
    # missed degree and ranks: a set's hash order chose between P1 and P2)
    finest = max((r for r in done if parse(r)["method"] == "anderson"
                  and parse(r)["m"] <= REFERENCE_MESH),
                 key=lambda r: (parse(r)["m"], parse(r)["formulation"] == "nitsche",
                                parse(r)["degree"], -parse(r)["ranks"], r))
    figure_states(finest)
    figure_overpressure(finest)
    panels = {}
    for f in FORMULATIONS:
        per_mesh: dict[int, str] = {}  # one line per mesh (the same run on 1 or 2 ranks)
        for r in sorted(done, key=lambda r: (parse(r)["m"], parse(r)["ranks"])):
            c = parse(r)
            if (c["formulation"], c["degree"], c["method"]) == (f, 2, "anderson"):
                per_mesh.setdefault(c["m"], r)
        if per_mesh:
            panels[f] = list(per_mesh.values())
    figure_mean_aperture(panels)
    figure_jumps([tag(0, f, 2) for f in FORMULATIONS if tag(0, f, 2) in done])
    figure_newton({f"m = {m}": [tag(m, f, 2) for f in FORMULATIONS if tag(m, f, 2) in done]
                   for m in (0, 1)})
    _tables(done, ref)


def _factorizations(s: dict) -> int:
    """Factorizations of the contact problem, those of the condensed solve's set-up included."""
    return s["coupling"]["factorizations"] + (s.get("condensed") or {}).get("factorizations", 0)


def _tables(done: set[str], ref: Reference | None) -> None:
    """G evaluations, error against run time, cost of the coupled solver."""
    rows = []
    for run in sorted(done):
        s = summary(run)
        c = s["coupling"]
        rows.append([run, s["mesh"]["cells"], s["dofs"], c["g_evaluations"],
                     c["newton_iterations"], c.get("face_iterations", 0), _factorizations(s),
                     c["darcy_iterations"], process_seconds(run), s["wall_time"]["total"],
                     (s.get("peak_memory_gb") or [None, None])[1] or "",
                     "/".join(f"{x:.1f}" for x in s.get("load_average", []))])
    header = ["run", "cells", "dofs", "g evaluations", "Newton it", "face Newton it",
              "factorizations", "Darcy it", "process s", "run s", "peak memory GB",
              "load before/after"]
    write_csv(DOCS / "runs.csv", header, rows, _provenance("report"))
    text = [f"# Coupled six-fracture scene: runs\n\n{_provenance('report')}. *process s*: "
            "the least of the study run and its repeats (`timing`); *peak memory*: summed "
            "over the ranks (runs measured with `/usr/bin/time -v`); *load*: the machine's "
            "1-minute load average before and after the run (it is shared: 2 cores).\n\n",
            markdown_table(header, rows)]
    if ref is not None:
        text += ["\n## Error against run time\n\nAgainst the reference of "
                 "[reference.md](reference.md): [accuracy.md](accuracy.md).\n"]
        _accuracy_tables(done, ref)
    crows = _cost_rows(done)
    if not crows and (DOCS / "cost.csv").exists():
        print(f"no unit costs among the runs: {DOCS / 'cost.csv'} is left as it was, from an "
              "earlier report (it may not match runs.csv)", file=sys.stderr)
    if crows:
        ch = ["run", "ranks", "dofs", "g evaluations", "Newton it", "face Newton it",
              "factorizations", "mechanics s", "Darcy s", "run s", "elastic solve s",
              "Darcy solve s", "ratio run", "ratio solves"]
        write_csv(DOCS / "cost.csv", ch, crows, _provenance("report"))
        text += ["\n## Cost against one elastic and one Darcy solve\n\n",
                 "*ratio run* = run s / (steps × (elastic solve s + Darcy solve s)); *ratio "
                 "solves* the same with the seconds spent in the contact and Darcy solves of "
                 "the coupled run (no set-up, output or checkpoint). The unit solves are "
                 "measured on the same mesh and ranks by `unit_costs` (assembly, numeric "
                 "factorization and solve of linear elasticity; matrix values, set-up and "
                 "solve of Darcy). *face Newton it*: iterations of the condensed `mixed` "
                 "solve, whose regular Newton takes none; its *factorizations* are the two of "
                 "its set-up.\n\n", markdown_table(ch, crows)]
    (DOCS / "runs.md").write_text("".join(text))


def _cost_rows(done: set[str]) -> list[list]:
    """Coupled runs next to one elastic and one Darcy solve on the same mesh and ranks."""
    rows = []
    for run in sorted(done):
        c = parse(run)
        unit = RUNS / f"unit_m{c['m']}_P{c['degree']}_n{c['ranks']}.json"
        if c["method"] != "anderson" or not unit.exists():
            continue
        u, s = json.loads(unit.read_text()), summary(run)
        steps = len(s["solves"])
        per_step = steps * (u["elastic"] + u["darcy"])
        co = s["coupling"]
        rows.append([run, c["ranks"], s["dofs"], co["g_evaluations"], co["newton_iterations"],
                     co.get("face_iterations", 0), _factorizations(s),
                     co["mechanics_seconds"], co["darcy_seconds"],
                     s["wall_time"]["total"], u["elastic"], u["darcy"],
                     s["wall_time"]["total"] / per_step,
                     (co["mechanics_seconds"] + co["darcy_seconds"]) / per_step])
    return rows


def _accuracy_tables(done: set[str], reference: Reference) -> None:
    """accuracy.{csv,md,png}: errors against the reference, winners per budget, construction."""
    ref = reference.solution
    erows = []
    for run in sorted(done, key=lambda r: (parse(r)["m"], r)):
        c = parse(run)
        if c["method"] != "anderson" or c["m"] > REFERENCE_MESH:
            continue
        e = errors(solution(run), ref)
        erows.append([run, process_seconds(run), *[e[k] for k in MEASURES]])
    eh = ["run", "process s", *[f"{k} error" for k in MEASURES]]
    prov = _provenance("report")
    write_csv(DOCS / "accuracy.csv", eh, erows, prov + ", reference: reference.md")
    ch = ["formulation", "meshes", "measure", "observed order", "cosine", "extrapolated",
          "last refinement change", "extrapolation change"]
    write_csv(DOCS / "reference.csv", ch, reference.rows, prov)
    names = [f"{f} m{m}" for f, m in reference.finest.items()]
    sh = ["measure", " - ".join(names), "estimate " + " - estimate ".join(reference.finest),
          f"extrapolation correction of {next(iter(reference.finest))}"]
    write_csv(DOCS / "reference_spread.csv", sh, reference.spread, prov)
    fastest = _fastest(erows)
    bh = ["budget s", *MEASURES]
    brows = least_error_per_budget(fastest)
    write_csv(DOCS / "accuracy_budget.csv", bh, brows, prov)
    used = " and ".join(f"`{f}`" for f in reference.used)
    (DOCS / "accuracy.md").write_text(
        "# Coupled six-fracture scene: error against run time\n\n"
        f"{prov}. Reference: Richardson extrapolation of {used} P2 over "
        f"m = {', '.join(map(str, REFERENCE_LADDER))} where regular, else the m = "
        f"{max(REFERENCE_LADDER)} solution"
        + (", the mean of the formulations" if len(reference.used) > 1 else "")
        + " ([reference.md](reference.md)). Errors: relative L² over the output times (mean "
        "aperture), over all fracture faces (normal and tangential jumps at T, face lengths as "
        "weights), over fracture 1 (tangential jump at T); relative error of the area-weighted "
        "mean matrix overpressure at T. Time: the whole process.\n\n"
        "## Reference construction\n\n" + markdown_table(ch, reference.rows)
        + "\n*last refinement change*: relative change of the measure on the last refinement "
        "of the ladder; *extrapolation change*: relative change from the finest solution to "
        "the estimate.\n\n"
        "Spread of the reference (relative to it): the finest solutions of the two "
        "formulations, their estimates, and the extrapolation's correction:\n\n"
        + markdown_table(sh, reference.spread)
        + "\n## Errors\n\n" + markdown_table(eh, erows)
        + "\n## Least error within a time budget\n\nAmong the runs above (the faster of 1 "
        "and 2 ranks): formulation, degree, mesh (error, process s).\n\n"
        + markdown_table(bh, brows))
    _figure_accuracy(fastest, reference)


def _fastest(rows: list[list]) -> list[list]:
    """Per formulation, degree and mesh, the faster of the 1- and 2-rank runs."""
    best: dict[tuple[str, int], list] = {}
    for r in rows:
        key = (label(r[0]), parse(r[0])["m"])
        if key not in best or r[1] < best[key][1]:
            best[key] = r
    return sorted(best.values(), key=lambda r: (label(r[0]), parse(r[0])["m"]))


def _figure_accuracy(rows: list[list], reference: Reference) -> None:
    """Error against the process time, one panel per measure, one line per method."""
    plt = _plt()
    fig, axes = plt.subplots(2, 2, figsize=(11, 8))
    groups: dict[str, list] = {}
    for r in rows:
        groups.setdefault(label(r[0]), []).append(r)
    styles = {"P2": "o-", "P1": "s--"}
    colors = dict(zip(FORMULATIONS, ("tab:green", "tab:orange", "tab:blue", "tab:purple"),
                      strict=True))
    for key, pts in sorted(groups.items()):
        pts = sorted(pts, key=lambda r: r[1])
        for j, ax in enumerate(axes.flat):
            ax.loglog([p[1] for p in pts], [p[2 + j] for p in pts], styles[key[-2:]], ms=4,
                      color=colors[key.split()[0]], label=key)
            for p in pts:
                ax.annotate(str(parse(p[0])["m"]), (p[1], p[2 + j]), fontsize=6,
                            xytext=(2, 2), textcoords="offset points")
    for j, (ax, title) in enumerate(zip(axes.flat, MEASURES, strict=True)):
        ax.axhline(reference.spread[j][1], color="0.5", lw=1, ls=":",
                   label=" vs ".join(f"{f} m{m}" for f, m in reference.finest.items())
                   if j == 0 else None)
        ax.set_xlabel("process time (s), faster of 1 and 2 ranks; labels: m")
        ax.set_ylabel("relative error")
        ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    _save(fig, "accuracy.png")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("study", choices=("paper", "accuracy", "reference", "timing", "performance",
                                       "newtonkrylov", "report", "case"))
    p.add_argument("--again", action="store_true", help="repeat runs already done")
    p.add_argument("--case", nargs=5, metavar=("M", "FORMULATION", "DEGREE", "METHOD", "RANKS"))
    p.add_argument("--partial", action="store_true",
                   help="report: write the tables of the runs present even if committed rows go")
    args = p.parse_args()
    if args.study == "case" and args.case is None:
        p.error("the study 'case' needs --case M FORMULATION DEGREE METHOD RANKS")
    if args.study == "case":
        m, f, d, method, n = args.case
        run_case(int(m), f, int(d), method, int(n), again=args.again)
    elif args.study == "report":
        report(args.partial)
    elif args.study == "reference":
        reference_runs(again=args.again)
    elif args.study == "timing":
        timing(again=args.again)
    else:
        globals()[args.study](again=args.again)


if __name__ == "__main__":
    main()
