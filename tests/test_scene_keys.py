"""No scene key is accepted and ignored: a walk over the whole schema, physics by physics.

For every key of :class:`poromech.scene.schema.Scene` and every physics, a small scene is given
that key (with a value from :data:`VARIANTS`, next to the keys it needs) and must either be
refused with a message naming the key, or be run with a warning naming the key and results
equal to those without it, or be run with results that differ from those without it (the
fields written, the output files, the iteration counts). A key added to the schema without a
variant here fails :func:`test_every_schema_key_has_a_variant`.
"""

from __future__ import annotations

import copy
import dataclasses
import json
import logging
import re
import typing
from pathlib import Path

import numpy as np
import pytest

from poromech.errors import ConfigError, SolverError
from poromech.io.results import read_table
from poromech.run import run_scene
from poromech.scene.expressions import Expression
from poromech.scene.loading import scene_from_dict
from poromech.scene.schema import Scene
from poromech.scene.usage import _OTHER_PHYSICS as OTHER_PHYSICS
from poromech.scene.usage import given_keys

DELETE = object()

#: Keys left out of the walk, with the reason (each is covered where named).
NOT_WALKED = {
    "name": "names the output directory (tests/test_cli.py)",
    "physics": "selects the physics itself",
    "description": "free text by definition",
    "geometry.domain.polygon": "an alternative domain (tests/test_geometry.py)",
    "geometry.domain.boundary_names": "names a polygon's edges (tests/test_geometry.py)",
    "geometry.domain.box": "the 3D domain: walked by tests/test_mechanics3d.py (validation, "
                           "the penny crack, the slab)",
    "geometry.fractures.0.polygon": "a 3D fracture (tests/test_mechanics3d.py)",
    "geometry.fractures.0.disc.center": "a 3D disc fracture (configs/penny.yaml, "
                                        "tests/test_mechanics3d.py)",
    "geometry.fractures.0.disc.normal": "a 3D disc fracture (tests/test_mechanics3d.py)",
    "geometry.fractures.0.disc.radius": "a 3D disc fracture (tests/test_mechanics3d.py)",
    "geometry.fractures.0.name": "a label: names the fracture in fractures.csv and flow.fractures",
    "geometry.surfaces.0.polygon": "3D mesh conformity (tests/test_mesh3d.py, configs/berre_*)",
    "geometry.surfaces.0.name": "a label for messages",
    "geometry.fracture_file": "an alternative fracture source (tests/test_mesh_import.py)",
    "geometry.mesh.file": "an alternative geometry source (tests/test_mesh_import.py)",
    "geometry.mesh.fractures": "part of geometry.mesh (tests/test_mesh_import.py)",
    "geometry.mesh.boundaries": "part of geometry.mesh (tests/test_mesh_import.py)",
    "geometry.mesh.starts": "part of geometry.mesh (tests/test_mesh_import.py)",
    "solver.stale_factorization": "acts after small active-set changes on systems of 100,000 "
                                  "unknowns or more (tests/test_newton.py, stale factorization)",
}

#: A value for every walked key, and the keys it needs next to it (DELETE removes one).
VARIANTS: dict[str, tuple[object, dict]] = {
    "parameters": ({"sigma": 1.0e6, "unused_q": 1.0}, {}),
    "geometry.domain.rectangle": ([0.0, 0.0, 1.2, 1.0], {}),
    "geometry.fractures.0.points": ([[0.3, 0.45], [0.7, 0.55]], {}),
    "mesh.size": (0.2, {}),
    "mesh.fracture_size": (0.08, {}),
    "mesh.tip_size": (0.05, {}),
    "mesh.transition": (0.5, {}),
    "mesh.refinement": (1, {}),
    "mesh.zones.0.center": ([0.4, 0.45], {}),
    "mesh.zones.0.radius": (0.2, {}),
    "mesh.zones.0.size": (0.03, {}),
    "mesh.zones.0.transition": (0.1, {}),
    "mesh.zones.0.region": ("ball", {}),
    "degree": (1, {}),
    "material.young": (2.0e9, {}),
    "material.poisson": (0.3, {}),
    "material.body_force": ([0.0, -1.0e4], {}),
    "material.biot": (0.5, {}),
    "material.density": (2500.0, {"gravity": [0.0, -9.81], "flow.fluid_density": 1000.0}),
    "material.initial_stress": ([-2.0e5, "-sigma", 0.0], {}),
    "contact.formulation": ("mixed", {}),
    "contact.friction": ("tresca", {"contact.slip_bound": 1.0e5}),
    "contact.friction_coefficient": (0.3, {}),
    "contact.slip_bound": (2.0e5, {"contact.friction": "tresca"}),
    "contact.theta": (1.0, {}),
    "contact.beta_n": (1.0e12, {}),
    "contact.beta_t": (1.0e12, {}),
    "contact.beta_sm_n": (1.0e11, {"contact.formulation": "mixed"}),
    "contact.beta_sm_t": (1.0e11, {"contact.formulation": "mixed"}),
    "contact.traction_side": ("mean", {}),
    "contact.beta_scaling": ("local", {"material.young": "1e9 * (1 + 10 * y)"}),
    "fracture_pressure": ("2e5", {}),
    "gravity": ([0.0, -9.81], {"material.density": 2500.0, "flow.fluid_density": 1000.0}),
    "boundary_conditions.3.boundary": ("left", {}),
    "boundary_conditions.0.displacement": ([0.0, 1.0e-5], {}),
    "boundary_conditions.1.traction": ([0.0, -2.0e6], {}),
    "time.final": (150.0, {}),
    "time.steps": (3, {}),
    "time.times": ([50.0, 200.0], {"time.final": DELETE, "time.steps": DELETE}),
    "time.max_cuts": (0, {"coupling.max_it": 1, "coupling.fallback": "none",
                          "solver.petsc": {"snes_max_it": 1}, "flow.linear_solver": "iterative",
                          "flow.petsc": {"ksp_max_it": 1}}),
    "solver.linear_solver": ("iterative", {}),
    "solver.line_search": ("basic", {}),
    "solver.predictor": ("last", {}),
    "solver.reuse_jacobian": (False, {}),
    "solver.condensation": (False, {"contact.formulation": "mixed"}),
    "solver.petsc": ({"snes_max_it": 1}, {}),
    "flow.permeability": ([2.0e-15], {}),
    "flow.viscosity": (2.0e-3, {}),
    "flow.fluid_density": (1000.0, {"gravity": [0.0, -9.81], "material.density": 2500.0}),
    "flow.aperture": (2.0e-5, {"flow.fractures": DELETE}),
    "flow.fracture_permeability": (1.0e-12, {}),
    "flow.fracture_normal_permeability": (1.0e-14, {}),
    "flow.fracture_conductivity": (1.0e-15, {}),
    "flow.fractures.0.fracture": ("frac", {"flow.fractures.0.aperture": DELETE}),
    "flow.fractures.0.aperture": (3.0e-5, {}),
    "flow.fractures.0.permeability": (1.0e-12, {}),
    "flow.fractures.0.normal_permeability": (1.0e-14, {}),
    "flow.fractures.0.conductivity": (1.0e-15, {}),
    "flow.source": (1.0e-6, {}),
    "flow.fracture_source": ("2e-5", {}),
    "flow.boundary_conditions.0.boundary": ("top", {}),
    "flow.boundary_conditions.0.pressure": (1.0e4, {}),
    "flow.boundary_conditions.0.flux": (1.0e-7, {"flow.boundary_conditions.0.pressure": DELETE}),
    "flow.boundary_conditions.0.where": ("y > 0.3", {}),
    "flow.boundary_conditions.0.fracture_ends": (
        "no_flow", {"geometry.fractures.0.points": [[0.0, 0.38], [0.7, 0.62]]}),
    "flow.initial_pressure": (1.0e4, {}),
    "flow.porosity": (0.2, {}),
    "flow.biot_modulus": (5.0e9, {}),
    "flow.stabilization": (2.0, {}),
    "flow.linear_solver": ("iterative", {}),
    "flow.petsc": ({"ksp_type": "gmres", "pc_type": "jacobi", "ksp_rtol": 1e-3}, {}),
    "coupling.method": ("ngmres", {}),
    "coupling.fallback": ("none", {"coupling.max_it": 2}),
    "coupling.rtol": (1e-8, {}),
    "coupling.atol": (1.0, {}),
    "coupling.max_it": (2, {}),
    "coupling.memory": (1, {}),
    "coupling.stabilization": (0.0, {}),
    "coupling.fracture_stabilization": (1.0, {}),
    "coupling.extrapolate": (False, {}),
    "coupling.petsc": ({"snes_anderson_beta": 0.5}, {}),
    "probes.0.name": ("renamed", {}),
    "probes.0.start": ([0.5, 0.1], {}),
    "probes.0.end": ([0.5, 0.8], {}),
    "probes.0.samples": (7, {}),
    "probes.0.interpolation": ("constant", {}),
    "output.xdmf": (True, {}),
    "output.checkpoint": (False, {}),
    "output.fractures_csv": (False, {}),
    "output.every": (2, {}),
}

#: A small coupled scene (one fracture, injection, two steps) from which every physics' base
#: scene is cut.
COUPLED = {
    "name": "keys",
    "physics": "poromechanics",
    "parameters": {"sigma": 1.0e6},
    "geometry": {"domain": {"rectangle": [0.0, 0.0, 1.0, 1.0]},
                 "fractures": [{"name": "frac", "points": [[0.3, 0.38], [0.7, 0.62]]}]},
    "mesh": {"size": 0.25, "fracture_size": 0.1, "tip_size": 0.1, "transition": 0.3,
             "zones": [{"center": [0.5, 0.5], "radius": 0.1, "size": 0.05}]},
    "degree": 2,
    "material": {"young": 1.0e9, "poisson": 0.25, "biot": 0.8},
    "contact": {"formulation": "nitsche", "friction_coefficient": 0.5},
    "boundary_conditions": [
        {"boundary": "bottom", "displacement": [0.0, 0.0]},
        {"boundary": "top", "traction": [0.0, "-sigma"]},
        {"boundary": "left", "displacement": [0.0, None]},
        {"boundary": "right", "displacement": [0.0, None]}],
    "time": {"final": 200.0, "steps": 2},
    "flow": {"permeability": [1.0e-15], "biot_modulus": 1.0e10, "porosity": 0.1,
             "aperture": 1.0e-5, "fracture_source": "1e-5*min(t/100, 1)",
             "fractures": [{"fracture": "frac", "aperture": 1.5e-5}],
             "boundary_conditions": [{"boundary": "left", "pressure": 0.0},
                                     {"boundary": "right", "pressure": 0.0}],
             "linear_solver": "direct"},
    "probes": [{"name": "line", "start": [0.1, 0.5], "end": [0.9, 0.5], "samples": 5}],
    "output": {"xdmf": False},
}


def base(physics: str) -> dict:
    raw = copy.deepcopy(COUPLED)
    raw["physics"] = physics
    if physics == "mechanics":
        del raw["flow"], raw["material"]["biot"]
        raw["fracture_pressure"] = "2e5*t/200"
    if physics == "flow":
        for key in ("material", "contact", "boundary_conditions", "degree"):
            del raw[key]
        del raw["flow"]["porosity"]  # the porosity is an output of a coupled run
    return raw


def walked_keys() -> list[str]:
    """Every leaf key of the schema (expressions are leaves; list entries as index 0)."""
    def walk(cls, prefix):
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            tp = hints[f.name]
            inner = None
            for a in (tp, *typing.get_args(tp)):
                if dataclasses.is_dataclass(a) and a is not Expression:
                    inner = inner or (a, "")
                if typing.get_origin(a) is tuple:
                    b = typing.get_args(a)[0]
                    if dataclasses.is_dataclass(b) and b is not Expression:
                        inner = (b, ".0")
            if inner:
                yield from walk(inner[0], f"{prefix}{f.name}{inner[1]}.")
            else:
                yield prefix + f.name
    return list(walk(Scene, ""))


def _plain(key: str) -> str:
    return ".".join(p if not p.isdigit() else "0" for p in key.split("."))


def test_every_schema_key_has_a_variant():
    walked = {_plain(k) for k in VARIANTS} | set(NOT_WALKED)
    missing = [k for k in walked_keys() if k not in walked]
    assert not missing, f"schema keys without a variant in VARIANTS: {missing}"
    unknown = [k for k in walked if k not in set(walked_keys())]
    assert not unknown, f"VARIANTS names keys the schema does not have: {unknown}"


def _set(raw: dict, key: str, value) -> None:
    """Give ``key`` the value (DELETE removes it); missing sections are those of COUPLED."""
    parts = key.split(".")
    node, model = raw, COUPLED
    for p in parts[:-1]:
        i = int(p) if p.isdigit() else p
        model = model[i] if model is not None and _has(model, i) else None
        if not _has(node, i):
            node[i] = copy.deepcopy(model) if model is not None else {}
        node = node[i]
    last = int(parts[-1]) if parts[-1].isdigit() else parts[-1]
    if value is DELETE:
        node.pop(last, None)
    else:
        node[last] = value


def _has(node, i) -> bool:
    return i < len(node) if isinstance(node, list) else i in node


def _scene(raw: dict, caplog) -> tuple[object, list[str]]:
    """The scene (or the ConfigError) and the warning lines of loading it."""
    caplog.clear()
    try:
        scene = scene_from_dict(copy.deepcopy(raw))
    except ConfigError as err:
        return err, []
    return scene, [r.getMessage() for r in caplog.records if r.levelno >= logging.WARNING]


def _results(scene, tmp: Path, caplog) -> dict:
    """What a run produces: output files, every CSV, the iteration history (no timings), the
    warnings of failed attempts, or how it failed."""
    caplog.clear()
    try:
        summary = run_scene(scene, tmp)
    except SolverError as err:
        return {"failed": str(err), "attempts": _attempts(caplog)}
    files = sorted(p.name for p in tmp.iterdir())
    tables = {p.name: read_table(p) for p in sorted(tmp.glob("*.csv"))}
    history = [{k: v for k, v in s.items() if not _timing(k)} for s in summary.get("solves", [])]
    history.append(_counters(summary))
    history.append(_attempts(caplog))
    return {"files": files, "tables": tables, "history": json.dumps(history, default=str),
            "steps": summary.get("completed_steps")}


def _timing(key: str) -> bool:
    return key.endswith("seconds") or key.startswith("time_") or key == "wall_time"


def _attempts(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records
            if r.levelno >= logging.WARNING and "failed" in r.getMessage()]


def _counters(summary: dict, prefix: str = "") -> dict:
    """The run's totals of iterations, evaluations, factorizations and solves (flattened)."""
    out = {}
    for k, v in summary.items():
        if isinstance(v, dict):
            out.update(_counters(v, f"{prefix}{k}."))
        elif isinstance(v, int) and re.search("iterations|evaluations|factorizations|solves", k):
            out[prefix + k] = v
    return out


def _differ(a: dict, b: dict) -> list[str]:
    """Names of the results that differ (numbers beyond 1e-10 of their column's scale)."""
    if "failed" in a or "failed" in b:
        return [] if a == b else ["outcome"]
    out = [k for k in ("files", "steps") if a[k] != b[k]]
    if _history_numbers(a["history"]) != _history_numbers(b["history"]):
        out.append("history")
    for name in set(a["tables"]) & set(b["tables"]):
        ta, tb = a["tables"][name], b["tables"][name]
        if set(ta) != set(tb):
            out.append(name)
            continue
        for col in ta:
            x, y = np.asarray(ta[col]), np.asarray(tb[col])
            if x.shape != y.shape:
                out.append(f"{name}:{col}")
            elif x.dtype.kind in "fi":
                scale = max(np.nanmax(np.abs(x), initial=0.0), 1e-300)
                if not np.allclose(x, y, rtol=0.0, atol=1e-10 * scale, equal_nan=True):
                    out.append(f"{name}:{col}")
            elif not np.array_equal(x, y):
                out.append(f"{name}:{col}")
    return out


def _history_numbers(text: str):
    """The iteration history with its floats rounded to 10 significant digits."""
    def walk(v):
        if isinstance(v, float):
            return float(f"{v:.10g}")
        if isinstance(v, list):
            return [walk(x) for x in v]
        if isinstance(v, dict):
            return {k: walk(x) for k, x in v.items()}
        return v
    return walk(json.loads(text))


def _names(message: str, key: str) -> bool:
    """True when ``message`` is about ``key``: it names the key, a section holding it, or a key
    below it (``scene key '<name>' ...``)."""
    m = re.search(r"scene key '([^']+)'", message)
    if m is None:
        return False
    named = m.group(1)
    return named == key or key.startswith(named + ".") or named.startswith(key + ".")


@pytest.mark.parametrize("physics", ["mechanics", "flow", "poromechanics"])
def test_every_key_is_used_refused_or_reported(physics, tmp_path, caplog):
    """Each key given changes the results, or is refused, or is reported and changes nothing."""
    caplog.set_level(logging.WARNING, logger="poromech")
    runs: dict[str, dict] = {}

    def results(raw: dict, label: str) -> dict:
        text = json.dumps(raw, sort_keys=True, default=str)
        if text not in runs:
            scene, _ = _scene(raw, caplog)
            assert not isinstance(scene, ConfigError), f"{label}: {scene}"
            runs[text] = _results(scene, tmp_path / f"run{len(runs)}", caplog)
        return runs[text]

    reference0 = base(physics)
    verdicts, failures = {}, []
    for key, (value, needs) in VARIANTS.items():
        raw = copy.deepcopy(reference0)
        for k, v in needs.items():
            if k.split(".")[0] not in OTHER_PHYSICS[physics][0]:
                _set(raw, k, v)
        context = copy.deepcopy(raw)
        _set(raw, key, value)
        scene, warnings = _scene(raw, caplog)
        if isinstance(scene, ConfigError):
            if _names(str(scene), key):
                verdicts[key] = "refused"
            else:
                failures.append(f"{key}: refused without naming it: {scene}")
            continue
        ctx_scene, _ = _scene(context, caplog)
        ref = context if not isinstance(ctx_scene, ConfigError) else reference0
        changed = _differ(results(raw, key), results(ref, f"{key} (without it)"))
        reported = [w for w in warnings if _names(w, key) and "no effect" in w]
        if reported:
            verdicts[key] = "reported"
            if changed:
                failures.append(f"{key}: reported as without effect, but changes {changed}")
        elif changed:
            verdicts[key] = "used"
        else:
            failures.append(f"{key} = {value!r}: accepted, not reported, and changes nothing")
    assert not failures, "\n".join(failures)
    print(physics, verdicts)


def test_given_keys_walks_mappings_and_lists_of_mappings():
    raw = {"a": 1, "b": {"c": [1, 2], "d": {}}, "e": [{"f": 1}, {"g": {"h": 2}}]}
    assert given_keys(raw) == ["a", "b.c", "b.d", "e.0.f", "e.1.g.h"]
    # null is the default of every optional key: not given, at any depth (a nested null was
    # reported as a key without effect); a list holding null is a value
    raw = {"a": None, "b": {"c": None, "d": [0.0, None]}, "e": [{"f": None, "g": 1}]}
    assert given_keys(raw) == ["b.d", "e.0.g"]


def test_a_null_key_is_not_reported_as_without_effect(capsys):
    """``--set contact.beta_t=null`` (the default) in a frictionless scene warned that the key
    has no effect."""
    from poromech.cli import main

    assert main(["validate", "six_fractures_mechanics", "--set", "contact.friction=frictionless",
                 "--set", "contact.beta_t=null"]) == 0
    out = capsys.readouterr().out
    assert "'contact.friction_coefficient' has no effect" in out  # given in the file
    assert "'contact.beta_t' has no effect" not in out


#: Keys given where the scene's other choices leave them without effect: each must be reported
#: by a warning naming it, and the results must equal those without it.
REPORTED = [
    ("mechanics", "contact.theta", 1.0, {"contact.formulation": "mixed"}),
    ("mechanics", "contact.beta_n", 1.0e12, {"contact.formulation": "mixed"}),
    ("mechanics", "contact.traction_side", "mean", {"contact.formulation": "mixed"}),
    ("mechanics", "contact.beta_scaling", "local", {}),
    ("mechanics", "contact.beta_sm_n", 1.0e11, {}),
    ("mechanics", "contact.beta_t", 1.0e12, {"contact.friction": "frictionless"}),
    ("mechanics", "contact.friction_coefficient", 0.3, {"contact.friction": "tresca",
                                                        "contact.slip_bound": 1.0e5}),
    ("mechanics", "contact.slip_bound", 1.0e5, {}),
    ("mechanics", "contact.friction", "tresca", {"contact.formulation": "none",
                                                 "contact.slip_bound": 1.0e5}),
    ("mechanics", "contact.beta_n", 1.0e12, {"geometry.fractures": DELETE}),
    ("mechanics", "mesh.tip_size", 0.05, {"geometry.fractures": DELETE}),
    ("mechanics", "mesh.zones.0.size", 0.03, {"geometry.fractures": DELETE}),
    # a zone inside a zone at least as fine (the finest size asked is meshed)
    ("mechanics", "mesh.zones.1.size", 0.06,
     {"mesh.zones": [{"center": [0.5, 0.5], "radius": 0.2, "size": 0.04},
                     {"center": [0.55, 0.5], "radius": 0.1, "size": 0.05}]}),
    ("mechanics", "fracture_pressure", "1e5", {"geometry.fractures": DELETE}),
    ("mechanics", "output.fractures_csv", False, {"geometry.fractures": DELETE}),
    ("mechanics", "solver.condensation", False, {}),
    ("mechanics", "solver.condensation", False, {"contact.formulation": "none"}),
    ("mechanics", "output.every", 2, {"time": DELETE, "fracture_pressure": "1e5"}),
    ("mechanics", "output.checkpoint", False, {"time": DELETE, "fracture_pressure": "1e5"}),
    ("mechanics", "solver.predictor", "last", {"time": DELETE, "fracture_pressure": "1e5"}),
    ("flow", "flow.biot_modulus", 5.0e9, {"time": DELETE, "flow.fracture_source": "1e-5"}),
    ("flow", "flow.initial_pressure", 1.0e4, {"time": DELETE,
                                             "flow.fracture_source": "1e-5"}),
    ("flow", "flow.fracture_conductivity", 1.0e-15, {"geometry.fractures": DELETE,
                                                    "flow.fractures": DELETE,
                                                    "flow.fracture_source": DELETE}),
    ("poromechanics", "coupling.memory", 3, {"coupling.method": "picard",
                                             "coupling.fallback": "newtonkrylov"}),
    # one solve: no storage term to stabilize, no earlier step (both changed nothing, unsaid)
    ("poromechanics", "coupling.stabilization", 2.0, {"time": DELETE,
                                                     "flow.fracture_source": "1e-5"}),
    ("poromechanics", "coupling.extrapolate", False, {"time": DELETE,
                                                     "flow.fracture_source": "1e-5"}),
    ("poromechanics", "coupling.stabilization", 2.0, {"material.biot": 0.0}),
]


@pytest.mark.parametrize(("physics", "key", "value", "needs"), REPORTED,
                         ids=[f"{c[0]}-{c[1]}-{i}" for i, c in enumerate(REPORTED)])
def test_reported_keys_change_nothing(physics, key, value, needs, tmp_path, caplog):
    caplog.set_level(logging.WARNING, logger="poromech")
    raw = base(physics)
    for k, v in needs.items():
        _set(raw, k, v)
    context = copy.deepcopy(raw)
    _set(raw, key, value)
    scene, warnings = _scene(raw, caplog)
    assert not isinstance(scene, ConfigError), scene
    assert any(_names(w, key) and "no effect" in w for w in warnings), warnings
    ref, _ = _scene(context, caplog)
    assert _differ(_results(scene, tmp_path / "a", caplog),
                   _results(ref, tmp_path / "b", caplog)) == []
