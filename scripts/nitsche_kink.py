r"""What pointwise ``nitsche`` does at the corner of fracture 1 while the rock drains.

The coupled six-fracture scene (``configs/six_fractures.yaml``) and its mechanics-only
counterpart (``six_fractures_mechanics``, the top displacement ramped to T/4 = 500 s and then
held until 2000 s) run with variants of the contact discretization (:data:`EXPERIMENTS`), and the
quantities on which an independent code (PorePy) disagreed with ``nitsche``:

* the fraction of fracture 1 (by length) labelled ``slip`` at ``T``;
* the slip of fracture 1 after the loading, ``[[u]]_τ(T) - [[u]]_τ(T/4)`` (length-weighted mean
  and largest absolute value);
* the opening ``-[[u]]_n`` of the faces just after the corner (``s`` in ``(0.3, 0.35)`` m) at
  ``T/4`` and ``T``;
* the mean matrix overpressure at ``T`` (area-weighted; and peak and mean at ``T/4``);
* mechanics only: the slip after the load stops (``creep``), which rate-independent friction
  does not allow.

Runs go through the Python API (``run_scene``), one process per experiment, so that variants the
scene does not expose (the quadrature of the contact terms, ``β`` near the corner, the step
predictor) can be set by patching before the model is built::

    python scripts/nitsche_kink.py all                 # every experiment (about 25 min)
    python scripts/nitsche_kink.py report              # -> docs/poromechanics/kink.{csv,md}
    python scripts/nitsche_kink.py run m1_nitsche_mean # one experiment by name
    python scripts/nitsche_kink.py points results/kink/m0_nitsche_probe --time 2000

``points`` prints the record of a ``--probe`` run: the complementarity arguments ``P_n``,
``P_τ``, the friction bound ``S``, the traction ``T(u)`` of the ``+`` and ``-`` sides and
their mean, and the slip increment of the step, at every Gauss point of fracture 1.
"""

from __future__ import annotations

import argparse
import datetime
import json
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SCENES = {"coupled": ROOT / "configs" / "six_fractures.yaml",
          "mechanics": ROOT / "configs" / "six_fractures_mechanics.yaml"}
OUT = ROOT / "results" / "kink"
STUDY = ROOT / "results" / "study"
DOCS = ROOT / "docs" / "poromechanics"
T, QUARTER = 2000.0, 500.0
#: Arc length of the corner of fracture 1 (m) and the window "after the corner".
CORNER, AFTER = 0.3, 0.05
#: The corner of fracture 1 (m).
CORNER_POINT = (0.5, 0.7)
#: Mechanics-only runs: the load of the coupled scene, held from T/4 to T.
HELD = ["time.final=2000", "time.steps=20"]

#: name -> (scene, overrides, options). Options: ``quadrature`` (degree of the contact terms),
#: ``beta_faces`` ((factor, radius): β_n and β_τ times factor at the contact points within
#: radius of the corner), ``predictor`` (False: each step's Newton starts from the last step),
#: ``probe`` (record the Gauss points within this distance of the corner), ``memory`` (the
#: tangential memory of :func:`_patch_memory`, a remedy to try, not the paper's method).
EXPERIMENTS: dict[str, tuple[str, list[str], dict]] = {}


def _add(name: str, scene: str, sets: list[str], **options) -> None:
    EXPERIMENTS[name] = (scene, sets, options)


for _m in (0, 1):
    _r = [f"mesh.refinement={_m}"]
    _add(f"m{_m}_nitsche", "coupled", _r)
    _add(f"m{_m}_mixed", "coupled", _r + ["contact.formulation=mixed"])
    _add(f"m{_m}_mean_nitsche", "coupled", _r + ["contact.formulation=mean_nitsche"])
    _add(f"m{_m}_nitsche_mean", "coupled", _r + ["contact.traction_side=mean"])
    _add(f"m{_m}_nitsche_bt10", "coupled", _r + ["contact.beta_t=4e11"])
    _add(f"m{_m}_nitsche_bt01", "coupled", _r + ["contact.beta_t=4e9"])
    _add(f"m{_m}_nitsche_bn10", "coupled", _r + ["contact.beta_n=1e13"])
    _add(f"m{_m}_nitsche_bn01", "coupled", _r + ["contact.beta_n=1e11"])
    _add(f"m{_m}_nitsche_q8", "coupled", _r, quadrature=8)
    _add(f"m{_m}_nitsche_steps40", "coupled", _r + ["time.steps=40"])
    _add(f"m{_m}_mixed_steps40", "coupled", _r + ["time.steps=40", "contact.formulation=mixed"])
    _add(f"mech_m{_m}_nitsche", "mechanics", _r + HELD)
    _add(f"mech_m{_m}_mixed", "mechanics", _r + HELD + ["contact.formulation=mixed"])
_add("m0_nitsche_theta0", "coupled", ["contact.theta=0"])
_add("m0_nitsche_theta1", "coupled", ["contact.theta=1"])
_add("m0_nitsche_bt100", "coupled", ["contact.beta_t=4e12"])
_add("m0_nitsche_mean_bt10", "coupled", ["contact.beta_t=4e11", "contact.traction_side=mean"])
_add("m0_nitsche_kinkbeta10", "coupled", [], beta_faces=(10.0, 0.06))
_add("m0_nitsche_kinkbeta01", "coupled", [], beta_faces=(0.1, 0.06))
_add("m0_nitsche_nopred", "coupled", [], predictor=False)
_add("m0_nitsche_steps80", "coupled", ["time.steps=80"])
_add("m0_mixed_steps80", "coupled", ["time.steps=80", "contact.formulation=mixed"])
_add("m0_nitsche_probe", "coupled", [], probe=0.35)
_add("m0_mixed_probe", "coupled", ["contact.formulation=mixed"], probe=0.35)
_add("mech_m0_nitsche_mean", "mechanics", HELD + ["contact.traction_side=mean"])
_add("mech_m0_nitsche_bt10", "mechanics", HELD + ["contact.beta_t=4e11"])
_add("mech_m0_nitsche_q8", "mechanics", HELD, quadrature=8)
_add("mech_m0_nitsche_steps40", "mechanics", ["time.final=2000", "time.steps=40"])
_add("mech_m0_mean_nitsche", "mechanics", HELD + ["contact.formulation=mean_nitsche"])
_add("mech_m0_stabilized_mixed", "mechanics", HELD + ["contact.formulation=stabilized_mixed"])
for _m in (0, 1):
    _r = [f"mesh.refinement={_m}"]
    _add(f"mech_m{_m}_nitsche_memory", "mechanics", _r + HELD, memory=True)
    _add(f"m{_m}_nitsche_memory", "coupled", _r, memory=True)
_add("m0_nitsche_memory_steps40", "coupled", ["time.steps=40"], memory=True)
_add("m2_nitsche_memory", "coupled", ["mesh.refinement=2"], memory=True)


# -- metrics of a run --------------------------------------------------------------------------
def _cell_areas(points: np.ndarray, cells: np.ndarray) -> np.ndarray:
    a, b, c = (points[cells[:, k]] for k in range(3))
    return 0.5 * np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                        - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))


def face_lengths(res) -> np.ndarray:
    """Lengths of the fracture faces in the order of ``fractures.csv`` (m)."""
    frac = res.series("fractures")
    seg = frac.points[frac.cells]
    return np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1)


def overpressure(res, t: float) -> tuple[float, float]:
    """Area-weighted mean and the peak of the matrix overpressure at ``t`` (Pa)."""
    flow = res.series("flow")
    area = _cell_areas(flow.points, flow.cells)
    op = flow.at(t)["overpressure"]
    return float(area @ op / area.sum()), float(op.max())


def metrics(path: str | Path) -> dict:
    """The corner and drainage quantities of one run (see the module docstring)."""
    import poromech  # noqa: F401
    from poromech.io.results import open_results

    res = open_results(path)
    summary = res.summary
    out = {"run": Path(path).name, "status": summary["status"]}
    if summary["status"] != "converged":
        return out
    length = face_lengths(res)
    q, e = res.fractures(QUARTER), res.fractures(T)
    assert abs(float(q["time"][0]) - QUARTER) < 1e-9 and abs(float(e["time"][0]) - T) < 1e-9
    f1 = q["fracture"] == "1"
    w = length[f1]
    s = q["s"][f1]
    after = (s > CORNER) & (s < CORNER + AFTER)
    late = e["jump_t"] - q["jump_t"]
    out.update({
        "slip_fraction_f1_T": float(w @ (e["state"][f1] == "slip") / w.sum()),
        "late_slip_f1_mean_um": float(w @ np.abs(late[f1]) / w.sum() * 1e6),
        "late_slip_f1_max_um": float(np.abs(late[f1]).max() * 1e6),
        "late_slip_all_mean_um": float(length @ np.abs(late) / length.sum() * 1e6),
        "corner_opening_Q_um": float(-q["jump_n"][f1][after].min() * 1e6),
        "corner_opening_T_um": float(-e["jump_n"][f1][after].min() * 1e6),
        "newton_iterations": summary["coupling"]["newton_iterations"]
        if "coupling" in summary else sum(r["iterations"] for r in summary["solves"]),
        "seconds": summary["wall_time"]["total"],
    })
    if "flow" in res.series_names:
        mean_q, peak_q = overpressure(res, QUARTER)
        out.update({"peak_overpressure_Q": peak_q, "mean_overpressure_Q": mean_q,
                    "mean_overpressure_T": overpressure(res, T)[0]})
    return out


# -- running variants --------------------------------------------------------------------------
def run(name: str, outdir: Path = OUT) -> dict:
    """Run one experiment of :data:`EXPERIMENTS` in this process; returns its metrics."""
    import poromech  # noqa: F401
    from poromech.forms import contact as cforms
    from poromech.run import run_scene
    from poromech.scene.loading import load_scene_and_raw

    scene_name, sets, options = EXPERIMENTS[name]
    if "quadrature" in options:
        degree = options["quadrature"]
        cforms.quadrature_degree = lambda k: degree
    if "beta_faces" in options:
        _patch_beta(*options["beta_faces"])
    if options.get("predictor") is False:
        _patch_predictor()
    if options.get("memory"):
        _patch_memory()
    record: dict = {}
    if "probe" in options:
        _patch_probe(options["probe"], record)
    out = outdir / name
    # the experiments are variants of nitsche unless they name a formulation (the coupled
    # scene's default is mixed)
    base = [] if any(s.startswith("contact.formulation=") for s in sets) \
        else ["contact.formulation=nitsche"]
    scene, raw = load_scene_and_raw(str(SCENES[scene_name]), [*base, *sets])
    try:
        run_scene(scene, out, raw=raw)
    except Exception as exc:  # a failed run is a result too (β_τ = 1000 E)
        print(f"{name}: {exc}", file=sys.stderr)
    m = metrics(out)
    m.update(scene=scene_name, sets=sets, options=options)
    (out / "kink.json").write_text(json.dumps(m, indent=1))
    if record:
        (out / "kink_points.json").write_text(json.dumps(record))
    return m


def _patch_beta(factor: float, radius: float) -> None:
    """Multiply ``β_n`` and ``β_τ`` by ``factor`` at the contact points near the corner."""
    from dataclasses import replace

    import ufl
    from dolfinx import fem

    from poromech.mechanics import model as mmodel

    original = mmodel.MechanicsModel._contact_parameters

    def patched(self):
        p = original(self)
        x = ufl.SpatialCoordinate(self.fm.msh)
        near = ufl.lt((x[0] - CORNER_POINT[0]) ** 2 + (x[1] - CORNER_POINT[1]) ** 2, radius**2)
        scale = ufl.conditional(near, fem.Constant(self.fm.msh, factor), 1.0)
        return replace(p, beta_n=p.beta_n * scale, beta_t=p.beta_t * scale)

    mmodel.MechanicsModel._contact_parameters = patched


def _patch_memory() -> None:
    """Pointwise ``nitsche`` with a tangential memory: a remedy to try, not the paper's method.

    The paper's quasi-static law takes ``P_τ = T_τ(u) - β_τ ([[u]]_τ - [[u_prev]]_τ)``: the part
    ``β_τ Δ`` of the traction is forgotten at the next step, so wherever the discrete traction
    ``T_τ(u_h)`` differs from the contact traction ``[P_τ]_S`` the next step slides again, by
    ``(T_τ(u_h) - [P_τ]_S) / β_τ``, even under a constant load. Here the reference of the slip is
    a field ``ξ`` at the contact points instead: ``P_τ = T_τ(u) - β_τ ([[u]]_τ - ξ)``, updated
    after each step to ``ξ = [[u]]_τ - (T_τ(u) - [P_τ]_S) / β_τ``, which leaves ``ξ`` unchanged
    at sticking points and makes the last step's state an equilibrium of the next one at an
    unchanged load. For the exact solution ``T_τ(u) = [P_τ]_S`` and ``ξ = [[u]]_τ``: the law is
    the paper's (consistent). ``ξ`` lives in the Lagrange space with its nodes at the Gauss
    points (as the active-set collocation of the model). Serial only.
    """
    import basix
    import basix.ufl
    import ufl
    from dolfinx import fem

    from poromech.forms import contact as cforms
    from poromech.forms.fracture import slip, tangent
    from poromech.mechanics import model as mmodel

    build, accept = mmodel.MechanicsModel._build_forms, mmodel.MechanicsModel.accept_step
    original_args = cforms.complementarity_arguments
    state: dict = {}

    def arguments(fk, p, u, lam=None, avg=None):
        if p.formulation != "nitsche" or "xi" not in state:
            return original_args(fk, p, u, lam, avg)
        pn = fk.normal_traction(u) - p.beta_n * ufl.dot(u("+") - u("-"), fk.n)
        pt = fk.tangential_traction(u) - p.beta_t * (slip(u, fk.n) - state["xi"]("+"))
        return pn, pt, cforms.slip_threshold(p, pn)

    def built(self):
        k = self.params.quadrature_degree // 2
        element = basix.ufl.element("DG", "interval", k,
                                    lagrange_variant=basix.LagrangeVariant.gl_warped)
        state["xi"] = fem.Function(fem.functionspace(self.submesh, element), name="xi")
        build(self)

    def accepted(self):
        xi, c, fk, u = state["xi"], self.params, self.kinematics, self.u
        pn, pt, s = arguments(fk, c, u)
        target = slip(u, fk.n) - (ufl.dot(fk.traction(u), tangent(fk.n))
                                  - cforms.ball_projection(pt, s)) / c.beta_t
        r = ufl.TestFunction(xi.function_space)("+")
        dG = cforms.contact_measure(c, self.dG)
        em = self.entity_maps or None
        moments = fem.assemble_vector(fem.form(target * r * dG, entity_maps=em)).array
        weights = fem.assemble_vector(fem.form(r * dG, entity_maps=em)).array
        xi.x.array[:] = np.where(weights != 0, moments / np.where(weights != 0, weights, 1), 0)
        accept(self)

    cforms.complementarity_arguments = arguments
    mmodel.MechanicsModel._build_forms = built
    mmodel.MechanicsModel.accept_step = accepted


def _patch_predictor() -> None:
    """Start each step's contact Newton from the last step's unknowns (no extrapolation)."""
    from poromech.mechanics import predictor as mpred

    init = mpred.StepPredictor.__init__
    mpred.StepPredictor.__init__ = lambda self, u, comm, extrapolate=True: init(
        self, u, comm, False)


def _patch_probe(window: float, store: dict) -> None:
    """Record the contact arguments at the Gauss points next to the corner at every step.

    ``MechanicsModel.accept_step`` is wrapped: before the solved displacement becomes the slip
    reference, the complementarity arguments of the scene's formulation and the tractions of
    both sides are collocated at the contact points of the fracture faces within ``window`` of
    the corner and stored under the step's time (serial runs only).
    """
    from dataclasses import replace

    import dolfinx
    import ufl

    from poromech.forms import contact as cforms
    from poromech.forms.elasticity import sigma
    from poromech.forms.fracture import normal_jump, slip, tangent
    from poromech.mechanics import model as mmodel

    set_time, accept = mmodel.MechanicsModel.set_time, mmodel.MechanicsModel.accept_step

    def timed(self, t):
        self._probe_time = t
        set_time(self, t)

    def probed(self):
        c, fk, u = self.params, self.kinematics, self.u
        x = ufl.SpatialCoordinate(self.fm.msh)
        exprs = {"x": x[0], "y": x[1], "jump_n": normal_jump(u, fk.n),
                 "jump_t": slip(u, fk.n), "dslip": slip(u, fk.n, self.u_prev)}
        for side in ("plus", "mean"):
            k = replace(fk, side=side)
            exprs[f"Tn_{side}"] = k.normal_traction(u)
            exprs[f"Tt_{side}"] = k.tangential_traction(u)
        # the '-' side's stress on n+ (the same sign convention as the '+' traction)
        sm = ufl.dot(sigma(u, fk.young, fk.poisson)("-"), fk.n)
        pm = fk.biot * fk.matrix_pressure("-") if fk.matrix_pressure is not None else 0.0
        pf = fk.fracture_pressure if fk.fracture_pressure is not None else 0.0
        exprs["Tn_minus"] = ufl.dot(sm, fk.n) - pm + pf
        exprs["Tt_minus"] = ufl.dot(sm, tangent(fk.n))
        lam = self.lam("+") if self.lam is not None else None
        avg = self.avg("+") if self.avg is not None else None
        pn, pt, s = cforms.complementarity_arguments(fk, c, u, lam, avg)
        exprs.update({"P_n": pn, "P_t": pt, "S": s})
        vals = {k: self.collocate(e) for k, e in exprs.items()}
        n = self.submesh.topology.index_map(1).size_local
        mid = dolfinx.mesh.compute_midpoints(self.submesh, 1, np.arange(n, dtype=np.int32))
        near = np.hypot(mid[:, 0] - CORNER_POINT[0], mid[:, 1] - CORNER_POINT[1]) < window
        store[getattr(self, "_probe_time", None)] = {k: v[near].tolist()
                                                     for k, v in vals.items()}
        accept(self)

    mmodel.MechanicsModel.set_time = timed
    mmodel.MechanicsModel.accept_step = probed


def points(path: str | Path, t: float, smin: float = 0.0, smax: float = 1.0) -> list[dict]:
    """Gauss-point record of a ``probe`` run at time ``t``, by arc length along fracture 1."""
    rec = json.loads((Path(path) / "kink_points.json").read_text())
    key = min(rec, key=lambda k: abs(float(k) - t))
    d = {k: np.asarray(v).ravel() for k, v in rec[key].items()}
    x, y = d["x"], d["y"]
    s = np.where(x <= CORNER_POINT[0], x - 0.2, CORNER + np.hypot(x - CORNER_POINT[0],
                                                                 y - CORNER_POINT[1]))
    rows = []
    for i in np.argsort(s):
        if not smin <= s[i] <= smax:
            continue
        row = {"s": float(s[i]), **{k: float(v[i]) for k, v in d.items() if k not in "xy"}}
        pn, pt, sv = row["P_n"], row["P_t"], row["S"]
        row["state"] = "open" if pn >= 0 else ("slip" if abs(pt) > sv else "stick")
        rows.append(row)
    return rows


# -- report ------------------------------------------------------------------------------------
COLUMNS = [("slip_fraction_f1_T", "f1 slip at T", ".2f"),
           ("late_slip_f1_mean_um", "f1 slip T/4→T mean µm", ".3g"),
           ("late_slip_f1_max_um", "max µm", ".3g"),
           ("corner_opening_Q_um", "corner opening T/4 µm", ".3g"),
           ("corner_opening_T_um", "at T µm", ".3g"),
           ("mean_overpressure_T", "mean overpressure T Pa", ".4g"),
           ("newton_iterations", "Newton it", "d")]


def _cell(m: dict, key: str, fmt: str) -> str:
    v = m.get(key)
    return "–" if v is None else format(v, fmt)


def report(partial: bool = False) -> None:
    """kink.csv and kink.md from the experiments and the study runs (results/).

    Refused when runs of the committed table are missing from results/ (a fresh clone has
    none: the table went from 61 rows to 3), unless ``partial``.
    """
    import csv

    rows = [metrics(OUT / name) for name in EXPERIMENTS if (OUT / name / "summary.json").exists()]
    study = sorted(p for p in STUDY.glob("m*_P2_anderson_n*") if (p / "summary.json").exists()
                   and "stabilized" not in p.name)
    rows += [metrics(p) for p in study]
    if (DOCS / "kink.csv").exists() and not partial:
        with open(DOCS / "kink.csv") as fh:
            committed = {r["run"] for r in csv.DictReader(ln for ln in fh
                                                          if not ln.startswith("#"))}
        missing = sorted(committed - {m["run"] for m in rows})
        if missing:
            raise SystemExit(f"{len(missing)} runs of {DOCS / 'kink.csv'} are not in results/ "
                             f"(e.g. {', '.join(missing[:3])}): run them first (`all`, and "
                             "the study runs), or give --partial to write a table of the "
                             f"{len(rows)} present")
    date = datetime.date.today()
    DOCS.mkdir(parents=True, exist_ok=True)
    keys = ["run", "status"] + [c[0] for c in COLUMNS] + ["late_slip_all_mean_um",
                                                          "mean_overpressure_Q", "seconds"]
    with open(DOCS / "kink.csv", "w", newline="") as fh:
        fh.write(f"# Generated {date} by `python scripts/nitsche_kink.py report`\n")
        w = csv.writer(fh)
        w.writerow(keys)
        for m in rows:
            w.writerow([m.get(k, "") if not isinstance(m.get(k), float) else f"{m[k]:.6g}"
                        for k in keys])
    head = "| run | " + " | ".join(c[1] for c in COLUMNS) + " |\n|---|" + "---|" * len(COLUMNS)
    lines = [head] + [f"| {m['run']} | " + " | ".join(_cell(m, *c[::2]) for c in COLUMNS) + " |"
                      if m["status"] == "converged"
                      else f"| {m['run']} | {m['status'].split(';')[0]} |"
                      for m in rows]
    (DOCS / "kink.md").write_text(
        "# The corner of fracture 1: experiments\n\n"
        f"Generated {date} by `python scripts/nitsche_kink.py report` (runs: `python "
        "scripts/nitsche_kink.py all`, and the study runs `m*_P2_anderson_n*` of "
        "`scripts/poromechanics_study.py`). `mech_*`: mechanics only, the load held from "
        "T/4 to T (the f1 slip columns are then the creep under constant load). Names: "
        "`mN` mesh, `mean` traction side mean, `btX`/`bnX` β_τ⁰/β_n⁰ times X (`01` = 0.1), "
        "`q8` quadrature degree 8 (5 Gauss points per face), `kinkbetaX` β_n, β_τ times X at "
        "the contact points within 6 cm of the corner, `stepsN` N time steps, `nopred` no "
        "step predictor, `thetaX` θ = X. See [reference.md](reference.md).\n\n"
        + "\n".join(lines) + "\n")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("run", help="one experiment")
    r.add_argument("name", choices=sorted(EXPERIMENTS))
    a = sub.add_parser("all", help="every experiment not yet run (--again: all)")
    a.add_argument("--again", action="store_true")
    rp = sub.add_parser("report")
    rp.add_argument("--partial", action="store_true",
                    help="write the table of the runs present even if committed rows go")
    pt = sub.add_parser("points")
    pt.add_argument("path")
    pt.add_argument("--time", type=float, default=T)
    pt.add_argument("--smin", type=float, default=0.0)
    pt.add_argument("--smax", type=float, default=1.0)
    args = p.parse_args()
    if args.cmd == "run":
        print(json.dumps(run(args.name), indent=1))
    elif args.cmd == "all":
        for name in EXPERIMENTS:
            if args.again or not (OUT / name / "kink.json").exists():
                subprocess.run([sys.executable, __file__, "run", name], cwd=ROOT, check=False)
    elif args.cmd == "report":
        report(args.partial)
    elif args.cmd == "points":
        cols = ["jump_n", "jump_t", "dslip", "Tn_plus", "Tn_minus", "Tn_mean", "Tt_plus",
                "Tt_minus", "Tt_mean", "P_n", "P_t", "S"]
        print("s        " + " ".join(f"{c:>10}" for c in cols) + "  state")
        for row in points(args.path, args.time, args.smin, args.smax):
            print(f"{row['s']:.5f}  " + " ".join(f"{row[c]:10.3e}" for c in cols)
                  + f"  {row['state']}")


if __name__ == "__main__":
    sys.exit(main())
