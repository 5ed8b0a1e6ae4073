"""Scene validation: every bad input is one clear line naming the key, value and what is allowed."""

import logging
import subprocess
import sys

import numpy as np
import pytest
import yaml
from conftest import (
    ROOT,
    config_error,
    is_flow_3d_scene,
    load_script,
    mechanics_scene,
    needs_flow_3d,
)

from poromech.errors import ConfigError
from poromech.scene.expressions import ExpressionError, compile_expression
from poromech.scene.loading import apply_overrides, load_scene, scene_from_dict, shipped_scenes


def _error(raw) -> str:
    return config_error(raw)


@pytest.mark.parametrize(
    ("overrides", "fragments"),
    [
        ({"contact__formulaton": "mixed"}, ["contact.formulaton", "unknown", "formulation"]),
        ({"material__young": -1.0}, ["material.young", "-1.0", "> 0"]),
        ({"material__poisson": 0.5}, ["material.poisson", "0.5", "< 0.5"]),
        ({"material__poisson": -1.0}, ["material.poisson", "> -1"]),
        ({"material__young": "where(x < 1, 1e9, -5)"}, ["material.young", "> 0", "x="]),
        ({"material__young": "foo * 2"}, ["material.young", "unknown name 'foo'"]),
        ({"material__young": "__import__('os')"}, ["material.young", "not allowed"]),
        ({"degree": 3}, ["degree", "3", "1, 2"]),
        ({"degree": "two"}, ["degree", "integer"]),
        ({"contact__formulation": "lagrange"}, ["contact.formulation", "lagrange", "nitsche"]),
        ({"contact__theta": 0.5}, ["contact.theta", "-1, 0, 1"]),
        ({"contact__beta_n": 0}, ["contact.beta_n", "> 0"]),
        ({"contact__friction_coefficient": -0.1}, ["friction_coefficient", ">= 0"]),
        ({"contact__friction": "tresca"}, ["contact.slip_bound", "tresca"]),
        ({"contact__friction": "tresca", "contact__slip_bound": "1e5*(1 + y)"},
         ["contact.slip_bound", "must not depend on x or y (a number"]),
        ({"mesh__size": 0}, ["mesh.size", "> 0"]),
        ({"mesh__refinement": -1}, ["mesh.refinement", ">= 0"]),
        ({"time": {"final": 1.0, "steps": 10**9}}, ["time.steps", "1000000000", "<= 1000000"]),
        ({"boundary_conditions": [{"boundary": "top", "displacement": [0, 0]},
                                  {"boundary": "roof", "displacement": [0, 0]}]},
         ["boundary_conditions.1.boundary", "roof", "bottom"]),
        ({"boundary_conditions": [{"boundary": "top", "traction": [0, -1]}]},
         ["boundary_conditions", "rigid body"]),
        ({"boundary_conditions": {"boundary": "top", "displacement": [0, 0]}},
         ["'boundary_conditions' = {", "must be a list: mechanical boundary conditions"]),
        ({"boundary_conditions": [{"boundary": "top", "displacement": [0, 0],
                                   "traction": [0, 0]}]}, ["exactly one"]),
        # the last displacement won; a traction on an imposed component was ignored
        ({"boundary_conditions": [{"boundary": "bottom", "displacement": [0, 0]},
                                  {"boundary": "top", "displacement": [None, -1e-3]},
                                  {"boundary": "top", "displacement": [0, -2e-3]}]},
         ["'boundary_conditions.2' imposes u_y (displacement.1) on boundary 'top'",
          "boundary_conditions.1 already imposes"]),
        ({"boundary_conditions": [{"boundary": "bottom", "displacement": [0, 0]},
                                  {"boundary": "top", "displacement": [None, -1e-3]},
                                  {"boundary": "top", "traction": ["1e6*x", "1e6"]}]},
         ["'boundary_conditions.2' gives traction.1 = '1e6' on boundary 'top'",
          "boundary_conditions.1 imposes u_y: it would have no effect"]),
    ],
)
def test_invalid_values(overrides, fragments):
    msg = _error(mechanics_scene(**overrides))
    for f in fragments:
        assert f in msg, (f, msg)


@pytest.mark.parametrize(
    ("fractures", "fragments"),
    [
        ([{"points": [[0.5, 0.5], [3.0, 0.5]]}], ["outside the domain"]),
        ([{"points": [[0.5, 0.5], [0.5, 0.5], [0.8, 0.5]]}], ["zero-length segment"]),
        ([{"points": [[0.2, 0.2], [0.8, 0.8], [0.8, 0.2], [0.2, 0.8]]}], ["crosses or folds"]),
        ([{"points": [[0.2, 0.5], [0.8, 0.5], [0.4, 0.5]]}], ["crosses or folds"]),
        ([{"points": [[0.2, 0.5], [0.6, 0.5]]}, {"points": [[0.4, 0.5], [0.9, 0.5]]}],
         ["overlap"]),
        ([{"points": [[0.0, 0.0], [1.0, 0.0]]}], ["runs along domain edge"]),
        ([{"points": [[0.2, 0.5]]}], ["at least 2"]),
        # said "crosses or folds onto itself (segments 0, 2)"
        ([{"points": [[0.2, 0.2], [0.5, 0.8], [0.8, 0.2], [0.2, 0.2]]}],
         ["is a closed loop: its last point is its first, (0.2, 0.2)"]),
        # an empty name was renamed to the fracture's number
        ([{"points": [[0.2, 0.5], [0.8, 0.5]], "name": " "}],
         ["'geometry.fractures.0.name' = ' ' is empty", "no key for the 1-based number"]),
        # an unnamed fracture took the number another one was named by: two fractures '2'
        ([{"points": [[0.2, 0.5], [0.8, 0.5]], "name": "2"}, {"points": [[0.2, 0.3], [0.8, 0.3]]}],
         ["'geometry.fractures': names repeat: ['2']", "names: ['2', '2']"]),
    ],
)
def test_invalid_geometry(fractures, fragments):
    raw = mechanics_scene()
    raw["geometry"]["fractures"] = fractures
    msg = _error(raw)
    for f in fragments:
        assert f in msg, (f, msg)


def test_valid_network_and_string_numbers():
    raw = mechanics_scene(material={"young": "4e9", "poisson": 0.2})  # YAML reads 4e9 as str
    scene = scene_from_dict(raw)
    assert scene.material.young.value() == 4e9
    assert [f.name for f in scene.geometry.fractures][:2] == ["corner", "bar"]


def test_overrides():
    raw = mechanics_scene()
    out = apply_overrides(raw, ["contact.formulation=mixed",
                                "boundary_conditions.1.displacement=[0.001, 0]",
                                "mesh.refinement=2", "solver.petsc.snes_max_it=7"])
    scene = scene_from_dict(out)
    assert scene.contact.formulation == "mixed"
    assert scene.boundary_conditions[1].displacement[0].value() == 0.001
    assert scene.mesh.refinement == 2 and scene.solver.petsc["snes_max_it"] == 7
    assert raw["contact"]["formulation"] == "nitsche"  # the input is not modified
    with pytest.raises(ConfigError, match="out of range"):
        apply_overrides(raw, ["boundary_conditions.7.boundary=top"])
    with pytest.raises(ConfigError, match="dotted.key=value"):
        apply_overrides(raw, ["degree"])
    # a key that is not an index was "out of range"; an empty key was "scene key '' unknown"
    with pytest.raises(ConfigError, match=r"'x' is not an index of a list of \d+ \(allowed"):
        apply_overrides(raw, ["boundary_conditions.x.boundary=top"])
    for item in ("=1", "mesh..size=1", "mesh.=1"):
        with pytest.raises(ConfigError, match="the key has an empty part"):
            apply_overrides(raw, [item])


def test_geometry_by_name_and_default_scene():
    scene = load_scene(None)
    assert len(scene.geometry.fractures) == 6
    scene = load_scene(None, ["geometry=six_fractures", "time.steps=2"])
    assert scene.time.steps == 2
    with pytest.raises(ConfigError, match="not a known geometry"):
        load_scene(None, ["geometry=nowhere"])


@pytest.mark.parametrize("name", [
    pytest.param(name, marks=needs_flow_3d) if is_flow_3d_scene(path) else name
    for name, path in sorted(shipped_scenes().items())])
def test_shipped_scenes_are_valid(name, caplog):
    """Every shipped scene loads, by name as from its file, and has no key without effect."""
    with caplog.at_level(logging.WARNING, logger="poromech"):
        assert load_scene(name) == load_scene(ROOT / "configs" / f"{name}.yaml")
    assert "has no effect" not in caplog.text


def test_cli_validate_exit_codes(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(mechanics_scene(material={"young": 1e9, "poisson": 0.7})))
    proc = subprocess.run([sys.executable, "-m", "poromech", "validate", str(bad)],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1 and "material.poisson" in lines[0] and "0.7" in lines[0]
    good = tmp_path / "good.yaml"
    good.write_text(yaml.safe_dump(mechanics_scene()))
    proc = subprocess.run([sys.executable, "-m", "poromech", "validate", str(good)],
                          capture_output=True, text=True)
    assert proc.returncode == 0
    broken = tmp_path / "broken.yaml"
    broken.write_text("name: [unclosed\n")
    proc = subprocess.run([sys.executable, "-m", "poromech", "run", str(broken)],
                          capture_output=True, text=True)
    assert proc.returncode == 2 and "not valid YAML" in proc.stderr


def test_expressions():
    e = compile_expression("0.005*min(4*t/T, 1)", {"T": 2000.0})
    assert e.depends_on_time and e.is_uniform and not e.is_constant
    assert e.value(250.0) == pytest.approx(0.0025) and e.value(3000.0) == pytest.approx(0.005)
    f = compile_expression("where(x < 1, 1e3, 1e11)")
    assert np.allclose(f(np.array([[0.5, 0.0], [1.5, 0.0]])), [1e3, 1e11])
    g = compile_expression("x + 10*y + 100*z")  # z is a coordinate; 0 where points are 2D
    assert np.array_equal(g(np.array([[1.0, 2.0, 3.0]])), [321.0])
    assert np.array_equal(g(np.array([[1.0, 2.0]])), [21.0]) and not g.is_uniform
    assert compile_expression(3).value() == 3.0
    for bad in ["x.__class__", "open('f')", "lambda: 1", "[1, 2]", "x if y else 1", "'text'"]:
        with pytest.raises(ExpressionError):
            compile_expression(bad)


def _doc_script():
    return load_script("make_scene_doc")


def test_scene_reference_is_up_to_date():
    assert (ROOT / "docs" / "scene_schema.md").read_text() == _doc_script().render(), \
        "docs/scene_schema.md is stale: run python scripts/make_scene_doc.py"


def test_one_permeability_is_the_isotropic_list():
    """``permeability: k`` is ``[k]``: one value where a list of expressions is asked."""
    base = mechanics_scene(time={"final": 1.0, "steps": 1}, physics="poromechanics")
    base["flow"] = {"permeability": 1e-12, "boundary_conditions": [{"boundary": "left",
                                                                    "pressure": 0.0}]}
    perm = scene_from_dict(base).flow.permeability
    assert len(perm) == 1 and perm[0].value() == 1e-12
    base["flow"]["permeability"] = "2e-12 * (1 + x)"
    assert scene_from_dict(base).flow.permeability[0](np.array([[1.0, 0.0]]), 0.0) \
        == pytest.approx(4e-12)
    base["flow"]["permeability"] = {"k": 1}
    assert "'flow.permeability' = {" in _error(base) and "must be a list: matrix" in _error(base)


def test_every_documented_key_is_accepted():
    """Each key of docs/scene_schema.md, set in a scene, is known to the loader."""
    import re

    text = (ROOT / "docs" / "scene_schema.md").read_text()
    keys, section = [], None
    for line in text.splitlines():
        if m := re.match(r"## `(.+)`", line):
            section = "" if m.group(1) == "top level" else m.group(1).replace("[i]", ".0")
        elif (m := re.match(r"\| `(\w+)` \|", line)) and section is not None:
            keys.append(f"{section}.{m.group(1)}" if section else m.group(1))
    assert len(keys) > 60 and "fracture_pressure.source" not in keys
    base = mechanics_scene(time={"final": 1.0, "steps": 1})
    base["flow"] = {"permeability": [1e-12], "fractures": [{"fracture": "bar"}],
                    "boundary_conditions": [{"boundary": "left", "pressure": 0.0}]}
    base["probes"] = [{"name": "p", "start": [0, 0.5], "end": [1, 0.5]}]

    def accepted(key: str) -> bool:
        """The loader takes the key as a key (not unknown, not a mapping given to a value)."""
        try:
            scene_from_dict(apply_overrides(base, [f"{key}=null"]))
        except ConfigError as err:
            parents = [key[:i] for i, c in enumerate(key) if c == "."]
            return "is unknown" not in str(err) and not any(f"'{p}' = {{" in str(err)
                                                            for p in parents)
        return True

    assert not accepted("fracture_pressure.source") and not accepted("contact.nonsense")
    assert [k for k in keys if not accepted(k)] == []


def test_conditions_that_share_a_boundary_on_other_components():
    """A roller loaded along its free direction, and two tractions on one boundary (they add)."""
    raw = mechanics_scene(boundary_conditions=[
        {"boundary": "bottom", "displacement": [0, 0]},
        {"boundary": "top", "displacement": [None, -1e-3]},
        {"boundary": "top", "traction": ["1e6*x", 0]},
        {"boundary": "right", "traction": [-1e6, 0]},
        {"boundary": "right", "traction": [-2e6, 0]}])
    bcs = scene_from_dict(raw).boundary_conditions
    assert [bc.boundary for bc in bcs] == ["bottom", "top", "top", "right", "right"]
