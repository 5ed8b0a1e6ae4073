"""The six-fracture mechanics scene as a one-layer 3D slab reproduces the 2D results.

The slab (``poromech.verification.slab``) is the plane-strain problem of the 2D scene: a kinked
fracture, a fracture reaching the boundary, Coulomb contact and load steps. On the coarse mesh
(``scripts/contact3d_slab.py``, ``docs/mechanics3d/slab.md``, 5 steps) the mean jumps per
fracture of slab and 2D differ by at most 0.13 % of the largest mean slip ``J`` for every
formulation and degree, while the 2D discretization error (the refined 2D mesh against the
coarse one) is 1.1-1.3 % of ``J``; the contact states differ on at most 10 % of a fracture
(nitsche, pointwise states at the triangles' Gauss points; 3 % with face averages), as much as
between the two 2D meshes. The tolerances below sit between the two: 0.5 % of ``J`` for the
jumps, the out-of-plane slip below 0.2 % of ``J``, states agreeing on 85 % of every fracture.
"""

from __future__ import annotations

import dolfinx_solver  # noqa: F401

import numpy as np
import pytest
from conftest import ROOT

from poromech.errors import ConfigError
from poromech.run import Run
from poromech.scene.geometry import mesh_sizes, scene_geometry
from poromech.scene.loading import load_scene_and_raw
from poromech.verification.slab import (
    fracture_summary,
    slab_geometry,
    slab_mesh,
    slab_scene,
)

SCENE = ROOT / "configs" / "six_fractures_mechanics.yaml"
#: Two load steps (the same in 2D and in the slab) keep the test fast.
FAST = ["time.steps=2", "output.xdmf=false"]


def two_runs(overrides):
    """Per-fracture summaries of the 2D scene and of its slab."""
    scene, raw = load_scene_and_raw(SCENE, FAST + overrides)
    out = []
    thickness = 0.5 * mesh_sizes(scene).fracture_size
    for slab in (False, True):
        fm = slab_mesh(scene, thickness) if slab else None
        case = (slab_scene(raw, slab_geometry(scene_geometry(scene), thickness)) if slab
                else scene)
        with Run(case, mesh=fm) as run:
            run.execute()
            assert run.physics.solver.record.converged
            out.append(fracture_summary(run.physics.model, run.physics.fm))
    return out


@pytest.mark.parametrize("overrides", [["contact.formulation=nitsche", "degree=2"],
                                       ["contact.formulation=mixed", "degree=1"]])
def test_slab_reproduces_the_six_fractures(overrides):
    two, three = two_runs(overrides)
    scale = np.max(np.abs(two["jump_t"]))
    assert scale > 5e-4  # the fractures slip (about 1 mm)
    assert np.count_nonzero(two["slip"] > 0.05) >= 3 and np.any(two["open"] > 0.9)
    np.testing.assert_allclose(three["jump_n"], two["jump_n"], rtol=0, atol=5e-3 * scale)
    np.testing.assert_allclose(three["jump_t"], two["jump_t"], rtol=0, atol=5e-3 * scale)
    assert np.all(two["jump_y"] == 0.0) and np.max(three["jump_y"]) < 2e-3 * scale
    differ = 0.5 * sum(np.abs(three[s] - two[s]) for s in ("open", "stick", "slip"))
    assert np.max(differ) < 0.15


def test_slab_geometry_of_a_kinked_fracture():
    """A kinked fracture is one fracture of two planar pieces, each with its segment's frame:
    ``n⁺`` and ``τ_1`` the 2D ones in the (x, z) plane and ``τ_2 = e_y``."""
    scene, _ = load_scene_and_raw(SCENE, FAST)
    geo = scene_geometry(scene)
    slab = slab_geometry(geo, 0.02)
    assert slab.fracture_names == geo.fracture_names and len(slab.fractures[0].points) == 6
    fracture, segment = np.array([0, 0]), np.array([0, 1])
    n2, t2 = geo.face_frames(fracture, segment)
    n3, t3 = slab.face_frames(fracture, segment)
    np.testing.assert_allclose(n3[:, [0, 2]], n2)
    np.testing.assert_allclose(n3[:, 1], 0.0)
    np.testing.assert_allclose(t3[:, 0, [0, 2]], t2[:, 0])
    np.testing.assert_allclose(t3[:, 1], [[0, 1, 0], [0, 1, 0]], atol=1e-15)
    assert not np.allclose(n3[0], n3[1])


def test_slab_scene_maps_the_conditions():
    """Boundary conditions go to the faces of their edges, y becomes z, u_y = 0 front and
    back; a key the slab cannot map is refused."""
    scene, raw = load_scene_and_raw(SCENE, FAST)
    raw["boundary_conditions"][1]["displacement"][1] = "-0.002*y*min(4*t/T, 1)"
    slab = slab_geometry(scene_geometry(scene), 0.02)
    s3 = slab_scene(raw, slab)
    bcs = {(bc.boundary, k): c.source for bc in s3.boundary_conditions
           for k, c in enumerate(bc.displacement) if c is not None}
    assert bcs[("top", 2)] == "-0.002*z*min(4*t/T, 1)" and bcs[("top", 0)] == raw[
        "boundary_conditions"][1]["displacement"][0]
    assert bcs[("front", 1)] == bcs[("back", 1)] == 0.0 and ("top", 1) not in bcs
    assert s3.solver.linear_solver == "direct"
    assert len(s3.geometry.fractures[0].polygon) == 6  # the kinked polyline, not its chord
    with pytest.raises(ValueError, match="gravity"):
        slab_scene({**raw, "gravity": [0.0, -9.81]}, slab)
    raw["contact"]["formulation"] = "nope"
    with pytest.raises(ConfigError):
        slab_scene(raw, slab)
