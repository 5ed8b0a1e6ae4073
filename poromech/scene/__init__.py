"""The scene: what to simulate, read from YAML, validated before anything is meshed.

* :mod:`~poromech.scene.schema`: the frozen dataclasses (units, defaults, ranges per field);
* :mod:`~poromech.scene.expressions`: numbers or formulas in ``x, y, z, t`` and parameters;
* :mod:`~poromech.scene.loading`: YAML files, shipped scenes, ``--set`` overrides;
* :mod:`~poromech.scene.builder`: mapping → dataclasses with type and range checks;
* :mod:`~poromech.scene.geometry`: the geometry and mesh sizes a scene describes;
* :mod:`~poromech.scene.checks`, :mod:`~poromech.scene.values`: per-physics checks before
  meshing; :mod:`~poromech.scene.fields`: every expression checked on the mesh;
* :mod:`~poromech.scene.resources`: cells, unknowns and memory estimated before meshing.

The names below are the scripting API (docs/api.md).
"""

from poromech.errors import ConfigError
from poromech.scene.geometry import mesh_sizes, scene_geometry
from poromech.scene.loading import (
    apply_overrides,
    load_scene,
    load_scene_and_raw,
    scene_from_dict,
    scene_path,
    scene_text,
    shipped_scenes,
)
from poromech.scene.schema import Scene, step_times

__all__ = [
    "ConfigError",
    "Scene",
    "apply_overrides",
    "load_scene",
    "load_scene_and_raw",
    "mesh_sizes",
    "scene_geometry",
    "scene_from_dict",
    "scene_path",
    "scene_text",
    "shipped_scenes",
    "step_times",
]
