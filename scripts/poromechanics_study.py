"""The coupled six-fracture scene of Beaude et al. (2023, §3): runs, figures, costs.

The paper's figures, error against run time and the cost of the coupled solver.

Runs go through the command line exactly as a user runs them (``python -m poromech run
configs/six_fractures.yaml --set ...``, under ``mpirun -n R`` for R > 1) into
``results/study/<tag>``; a run whose ``summary.json`` says ``converged`` is not repeated (pass
``--again`` to repeat it). Then ``report`` reads the outputs back (XDMF series, summary.json) and
writes CSV, Markdown and PNG to ``docs/poromechanics/``::

    python scripts/poromechanics_study.py paper        # m = 0, 1: Figs. 2-6, g evaluations
    python scripts/poromechanics_study.py accuracy     # formulations x degrees, m = 0-2, ref m = 3
    python scripts/poromechanics_study.py performance  # accelerators, ranks, unit solve costs
    python scripts/poromechanics_study.py newtonkrylov # the paper's method against Anderson
    python scripts/poromechanics_study.py report       # all figures and tables from what was run

Wall times are those of the whole process (start-up, mesh, set-up, 20 steps, output), with the
forms already compiled (every configuration is run once beforehand on one step).
"""

from __future__ import annotations

import argparse
import datetime
import json
import re
import subprocess
import sys
import time
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


def _command(ranks: int, args: list[str]) -> list[str]:
    cmd = [sys.executable, "-m", "poromech", *args]
    return [_mpirun(), "-n", str(ranks), *cmd] if ranks > 1 else cmd


def run_cli(out: Path, scene: Path, sets: list[str], ranks: int = 1, again: bool = False,
            timeout: float = 7200, warm: bool = True) -> dict:
    """Run ``poromech run scene --set ...`` into ``out`` (unless done); summary + process time.

    With ``warm``, the configuration is first run for one short step so that the forms are
    compiled before the timed run.
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
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(_command(ranks, args), cwd=ROOT, capture_output=True, text=True,
                              timeout=timeout)
        code, err = proc.returncode, proc.stderr
    except subprocess.TimeoutExpired:
        code, err = -1, f"timed out after {timeout:g} s"
    wall = time.perf_counter() - t0
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() \
        else {"status": f"failed: {err.strip()[-300:]}"}
    summary["process_seconds"] = wall
    summary["exit_status"] = code
    summary["stderr"] = err.strip()[-2000:]
    out.mkdir(parents=True, exist_ok=True)
    record.write_text(json.dumps(summary))
    print(f"{out.name}: {summary['status'][:70]}, {wall:.1f} s, "
          f"{summary.get('coupling', {}).get('g_evaluations')} g evaluations", flush=True)
    return summary


def run_case(m: int, formulation: str, degree: int, method: str = "anderson", ranks: int = 1,
             again: bool = False, timeout: float = 7200) -> dict:
    """Run one configuration of the six-fracture scene (if not done yet)."""
    sets = [f"mesh.refinement={m}", f"contact.formulation={formulation}", f"degree={degree}",
            f"coupling.method={method}"]
    return run_cli(RUNS / tag(m, formulation, degree, method, ranks), SCENE, sets, ranks, again,
                   timeout)


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


# -- the studies -------------------------------------------------------------------------------
def paper(meshes=(0, 1), again: bool = False) -> None:
    for m in meshes:
        for f in FORMULATIONS:
            run_case(m, f, 2, again=again)


#: Mesh of the reference run (nitsche P2, 2 ranks); ``report`` falls back to m = 2 without it.
REFERENCE_MESH = 3


def accuracy(meshes=(0, 1, 2), again: bool = False) -> None:
    run_case(REFERENCE_MESH, "nitsche", 2, ranks=2, again=again)
    unit_costs(REFERENCE_MESH, 2, 2)  # the cost ratio on the finest mesh
    for m in meshes:
        for f in FORMULATIONS:
            for d in (1, 2):
                if (f, d) == ("mixed", 1):
                    continue  # P1-P0 is not inf-sup stable (docs/mechanics.md)
                run_case(m, f, d, ranks=2 if m >= 2 else 1, again=again)


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


def report() -> None:
    DOCS.mkdir(parents=True, exist_ok=True)
    done = {p.name for p in RUNS.glob("m*_*") if (p / "study.json").exists()
            and summary(p.name)["status"] == "converged"}
    refs = [tag(m, "nitsche", 2, ranks=2) for m in (REFERENCE_MESH, 2)]
    ref = next((r for r in refs if r in done), None)
    finest = ref or max((r for r in done if parse(r)["method"] == "anderson"),
                        key=lambda r: parse(r)["m"])
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


def _tables(done: set[str], ref: str | None) -> None:
    """G evaluations, error against run time, cost of the coupled solver."""
    rows = []
    for run in sorted(done):
        s = summary(run)
        c = s["coupling"]
        rows.append([run, s["mesh"]["cells"], s["dofs"], c["g_evaluations"],
                     c["newton_iterations"], c.get("face_iterations", 0), _factorizations(s),
                     c["darcy_iterations"], s["process_seconds"], s["wall_time"]["total"]])
    header = ["run", "cells", "dofs", "g evaluations", "Newton it", "face Newton it",
              "factorizations", "Darcy it", "process s", "run s"]
    write_csv(DOCS / "runs.csv", header, rows, _provenance("report"))
    text = [f"# Coupled six-fracture scene: runs\n\n{_provenance('report')}.\n\n",
            markdown_table(header, rows)]
    if ref is not None:
        erows = []
        for run in sorted(done - {ref}):
            if parse(run)["method"] != "anderson":
                continue
            e_ap, e_jump = errors_against(run, ref)
            erows.append([run, summary(run)["process_seconds"], e_ap, e_jump])
        eh = ["run", "process s", "mean aperture error", "jump error at T"]
        write_csv(DOCS / "accuracy.csv", eh, erows, _provenance("report") + f", reference {ref}")
        text += [f"\n## Error against run time (reference {ref})\n\n", markdown_table(eh, erows)]
        _figure_accuracy(erows)
    crows = _cost_rows(done)
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


def _figure_accuracy(rows: list[list]) -> None:
    plt = _plt()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    fastest: dict[tuple[str, int], tuple] = {}  # per formulation, degree and mesh: 1 or 2 ranks
    for run, secs, e_ap, e_j in rows:
        key = (label(run), parse(run)["m"])
        if key not in fastest or secs < fastest[key][0]:
            fastest[key] = (secs, e_ap, e_j)
    groups: dict[str, list] = {}
    for (key, _), point in fastest.items():
        groups.setdefault(key, []).append(point)
    for key, pts in sorted(groups.items()):
        pts = sorted(pts)
        for ax, k in zip(axes, (1, 2), strict=True):
            ax.loglog([p[0] for p in pts], [p[k] for p in pts], "o-", label=key)
    for ax, title in zip(axes, ("mean aperture over time", "jumps at T"), strict=True):
        ax.set_xlabel("wall time of the whole run (s), fastest of 1 and 2 ranks")
        ax.set_ylabel("relative L² error")
        ax.set_title(title)
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7)
    _save(fig, "accuracy.png")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("study", choices=("paper", "accuracy", "performance", "newtonkrylov", "report",
                                       "case"))
    p.add_argument("--again", action="store_true", help="repeat runs already done")
    p.add_argument("--case", nargs=5, metavar=("M", "FORMULATION", "DEGREE", "METHOD", "RANKS"))
    args = p.parse_args()
    if args.study == "case":
        m, f, d, method, n = args.case
        run_case(int(m), f, int(d), method, int(n), again=args.again)
    elif args.study == "report":
        report()
    else:
        globals()[args.study](again=args.again)


if __name__ == "__main__":
    main()
