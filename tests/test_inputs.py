"""Bad input is refused in one line (exit 2) before meshing, by class; and once under MPI.

Most cases call ``poromech.cli.main`` in this process (it stops before meshing); the MPI class
runs them all in one ``mpirun -n 2`` script and checks that each prints one line in total and
ends both ranks with the same status.
"""

import dataclasses
import datetime
import json
import re
import subprocess
import sys
import time

import pytest
import yaml
from conftest import ROOT, mechanics_scene, mpirun, run_parallel

from poromech.cli import main
from poromech.errors import ConfigError
from poromech.io.outdir import LOCK_NAME, OutputDirError, output_directory
from poromech.petsc_options import PetscOptionError, check_petsc_options
from poromech.scene.expressions import ExpressionError, compile_expression
from poromech.scene.loading import apply_overrides, load_scene, scene_from_dict

POROMECH = [sys.executable, "-m", "poromech"]


def flow_scene(**flow) -> dict:
    """A small valid flow scene (unit square, one fracture reaching the right side)."""
    return {
        "name": "flow_test", "physics": "flow",
        "geometry": {"domain": {"rectangle": [0.0, 0.0, 1.0, 1.0]},
                     "fractures": [{"name": "f", "points": [[0.3, 0.5], [1.0, 0.5]]}]},
        "mesh": {"size": 0.2},
        "flow": {"permeability": [1.0e-12],
                 "boundary_conditions": [{"boundary": "left", "pressure": 1.0e5},
                                         {"boundary": "right", "pressure": 2.0e5}],
                 **flow},
    }


def cli(capsys, *args) -> tuple[int, list[str]]:
    """Run the command line in this process; the status and the lines of stderr."""
    code = main([str(a) for a in args])
    return code, capsys.readouterr().err.strip().splitlines()


def refused(capsys, *args, fragments=()) -> str:
    """Assert exit 2 with exactly one line containing the fragments; return it."""
    code, lines = cli(capsys, *args)
    assert code == 2, lines
    assert len(lines) == 1, lines
    for f in fragments:
        assert f in lines[0], (f, lines[0])
    assert "np.float64" not in lines[0] and "Traceback" not in lines[0]
    return lines[0]


def write_scene(path, raw) -> str:
    path.write_text(yaml.safe_dump(raw))
    return str(path)


# -- scene files ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("content", "fragment"), [
    (bytes(range(256)) * 4, "binary"),
    ("name: café\n".encode("latin-1"), "not UTF-8"),
    ("name: x\n".encode("utf-16"), "UTF-16"),
])
def test_scene_file_not_utf8_text(tmp_path, capsys, content, fragment):
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(content)
    refused(capsys, "validate", bad, fragments=[str(bad), fragment])


def test_scene_file_is_a_directory_or_missing(tmp_path, capsys):
    refused(capsys, "run", tmp_path, fragments=["is a directory"])
    refused(capsys, "validate", tmp_path / "none.yaml", fragments=["does not exist"])


# -- hostile YAML --------------------------------------------------------------------------------
BILLION_LAUGHS = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"{c}: &{c} [{', '.join([f'*{p}'] * 10)}]\n"
    for p, c in zip("abcdefgh", "bcdefghi", strict=True))


def test_nested_aliases_are_refused_before_any_copy(tmp_path, capsys):
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("name: bomb\n" + BILLION_LAUGHS)
    t0 = time.perf_counter()
    refused(capsys, "validate", bomb, fragments=["expands to more than", "aliases"])
    assert time.perf_counter() - t0 < 5.0
    loop = tmp_path / "loop.yaml"
    loop.write_text("name: loop\nx: &x [1, *x]\n")
    refused(capsys, "validate", loop, fragments=["recursive"])


def test_key_given_twice(tmp_path, capsys):
    twice = tmp_path / "twice.yaml"
    twice.write_text(yaml.safe_dump(mechanics_scene()) + "degree: 1\n")
    refused(capsys, "validate", twice, fragments=["'degree' is given twice", "line"])
    with pytest.raises(ConfigError, match="given twice"):
        apply_overrides(mechanics_scene(), ["time={final: 1, final: 2}"])


def test_aliases_within_bounds_are_accepted(tmp_path):
    raw = yaml.safe_dump(mechanics_scene())
    raw = raw.replace("material:\n", "material: &mat\n")
    path = tmp_path / "alias.yaml"
    path.write_text(raw + "description: same\n")
    load_scene(path)


# -- expressions ---------------------------------------------------------------------------------
@pytest.mark.parametrize(("source", "fragment"), [
    ("min(x)", "'min' takes 2 arguments, not 1"),
    ("x" + "+x" * 1000, "nested more than"),
    ("x" * 20000, "characters"),
    ("a.b(1)", "function 'a.b'"),
])
def test_malformed_expressions(source, fragment):
    with pytest.raises(ExpressionError, match=fragment):
        compile_expression(source)
    with pytest.raises(ConfigError) as info:
        scene_from_dict(mechanics_scene(material={"young": source, "poisson": 0.2}))
    assert "material.young" in str(info.value) and "\n" not in str(info.value)


@pytest.mark.parametrize(("raw", "key"), [
    (mechanics_scene(boundary_conditions=[
        {"boundary": "bottom", "displacement": [0.0, 0.0]},
        {"boundary": "top", "displacement": ["0.001/(x-x)", 0.0]}]),
     "boundary_conditions.1.displacement.0"),
    # singular only at the corner vertex (0, 1) of the top edge
    (mechanics_scene(boundary_conditions=[
        {"boundary": "bottom", "displacement": [0.0, 0.0]},
        {"boundary": "top", "traction": ["1e6/x", 0.0]}]),
     "boundary_conditions.1.traction.0"),
    (mechanics_scene(fracture_pressure="1e6/(y-y)"), "fracture_pressure"),
    (flow_scene(boundary_conditions=[{"boundary": "left", "pressure": "1e5/(x-x)"},
                                     {"boundary": "right", "pressure": 2e5}]),
     "flow.boundary_conditions.0.pressure"),
    (flow_scene(aperture="where(x > 0.6, -1e-4, 1e-4)"), "flow.aperture"),
    # a where of nan selected its faces without a word (nan != 0)
    (flow_scene(boundary_conditions=[{"boundary": "left", "pressure": 1e5},
                                     {"boundary": "right", "pressure": 2e5,
                                      "where": "sqrt(y - 0.5)"}]),
     "flow.boundary_conditions.1.where"),
])
def test_data_not_finite_or_out_of_range_where_used(raw, key):
    with pytest.raises(ConfigError) as info:
        scene_from_dict(raw)
    msg = str(info.value)
    assert f"'{key}'" in msg and "x=" in msg and "\n" not in msg, msg


def test_time_dependent_data_checked_at_every_step():
    raw = mechanics_scene(time={"final": 4.0, "steps": 4})
    raw["boundary_conditions"][1]["displacement"] = ["0.001/(t-3)", 0.0]
    with pytest.raises(ConfigError, match=r"displacement\.0.*t=3"):
        scene_from_dict(raw)


def test_a_flow_condition_is_checked_only_where_it_acts():
    """A value that is nan off the faces its ``where`` selects was refused at such a point
    (``y = 0`` for ``where: y > 0.5``); nan inside them still is."""
    def scene(pressure):
        return flow_scene(boundary_conditions=[
            {"boundary": "left", "pressure": 1e5},
            {"boundary": "right", "pressure": pressure, "where": "y > 0.5"}])

    scene_from_dict(scene("1e5*(1 + sqrt(y - 0.5))"))
    with pytest.raises(ConfigError, match=r"boundary_conditions\.1\.pressure.* is nan at x=1, "
                                          r"y=0\.[5-9]"):
        scene_from_dict(scene("1e5*(1 + sqrt(0.5 - y))"))


def test_field_invalid_only_outside_a_nonconvex_domain_is_accepted():
    raw = mechanics_scene()
    raw["geometry"] = {"domain": {"polygon": [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]],
                                  "boundary_names": {"bottom": [0], "top": [2, 4]}}}
    raw["material"]["young"] = "where((x > 1.01) and (y > 1.01), -1, 1e9)"
    raw["boundary_conditions"][1]["displacement"] = [0.0, -0.001]
    scene_from_dict(raw)


@pytest.mark.parametrize(("names", "fragment"), [
    # an edge in two names kept the last; 'edge3' on edge 1 also answered for edge 3
    ({"bottom": [0], "top": [2, 4], "lid": [4]}, "edge 4 is already named 'top'"),
    ({"bottom": [0], "top": [2], "edge3": [1]}, "'edge3' is also the default name of edge 3"),
])
def test_boundary_names_that_clash(names, fragment):
    raw = mechanics_scene()
    raw["geometry"] = {"domain": {"polygon": [[0, 0], [2, 0], [2, 1], [1, 1], [1, 2], [0, 2]],
                                  "boundary_names": names}}
    with pytest.raises(ConfigError, match="geometry.domain.boundary_names") as info:
        scene_from_dict(raw)
    assert fragment in str(info.value), info.value
    names = {"bottom": [0], "top": [2], "edge3": [1, 3]}  # renaming into a default: its own edge
    raw["geometry"]["domain"]["boundary_names"] = names
    scene_from_dict(raw)


# -- overrides -----------------------------------------------------------------------------------
def test_quiet_and_verbose_together_are_refused(capsys):
    refused(capsys, "validate", "sneddon", "-q", "-v", fragments=["not allowed with"])


def test_set_through_a_scalar(capsys):
    refused(capsys, "validate", ROOT / "configs" / "sneddon.yaml",
            "--set", "boundary_conditions.0.displacement.0.x=1",
            fragments=["boundary_conditions.0.displacement.0", "not a mapping or list"])


# -- PETSc options -------------------------------------------------------------------------------
def test_petsc_options_checked_before_meshing(tmp_path, capsys):
    out = tmp_path / "out"
    refused(capsys, "run", "sneddon", "-o", out, "-mech_snes_type", "bogus",
            fragments=["-mech_snes_type", "bogus", "newtonls"])
    refused(capsys, "run", "sneddon", "-o", out, "--set", "solver.petsc.ksp_type=nonsense",
            fragments=["solver.petsc.ksp_type", "nonsense", "KSP type"])
    refused(capsys, "run", "sneddon", "-o", out, "-snes_type", "newtonls",
            fragments=["-snes_type", "prefix", "-mech_snes_type"])
    refused(capsys, "validate", "sneddon", "-mech_pc_factor_mat_solver_type", "nopackage",
            fragments=["factorization package"])
    assert not out.exists()  # nothing was created


def test_petsc_option_checks():
    check_petsc_options({"mech_snes_type": "newtonls", "mech_ksp_type": "gmres",
                         "flow_pc_type": "gamg", "mech_pc_factor_mat_solver_type": "mumps",
                         "mech_snes_linesearch_type": "bt", "log_view": "",
                         "mech_stale_ksp_max_it": "5"})
    with pytest.raises(PetscOptionError, match="needs a KSP type"):
        check_petsc_options({"flow_ksp_type": ""})
    # numbers are numbers, before meshing (PETSc said "error 63" after it, naming no option)
    for name, value, kind in (("mech_ksp_rtol", "abc", "a number"),
                              ("mech_ksp_max_it", "1.5", "an integer"),
                              ("coupling_snes_max_it", "-5", "a non-negative integer"),
                              # nan and inf made PETSc fail (error 63) after meshing; a
                              # negative tolerance was silently PETSc's default
                              ("mech_ksp_rtol", "nan", "a finite number"),
                              ("flow_ksp_divtol", "inf", "a finite number"),
                              ("mech_pc_gamg_threshold", "0.01,-inf", "a finite number"),
                              ("mech_snes_atol", "-1", "a number >= 0")):
        with pytest.raises(PetscOptionError) as caught:
            check_petsc_options({name: value})
        assert f"'-{name}' = '{value}' needs {kind}" in str(caught.value)
    check_petsc_options({"mech_ksp_rtol": "1e-8", "mech_ksp_max_it": "50",
                         "mech_snes_lag_jacobian": "-2", "mech_ksp_gmres_restart": "100",
                         "mech_pc_gamg_threshold": "0.01,0.005"})
    check_petsc_options({"mech_pc_gamg_threshold": "-1"})  # GAMG: keep every entry
    scene = scene_from_dict(mechanics_scene(solver={"petsc": {"snes_rtol": float("nan")}}))
    with pytest.raises(PetscOptionError, match=r"scene key 'solver\.petsc\.snes_rtol' = nan "
                                               "needs a finite number"):
        check_petsc_options({}, scene)
    # the examples are types this PETSc has (it has no hypre; they listed it)
    with pytest.raises(PetscOptionError, match=r"\(e\.g\. lu, cholesky, gamg, jacobi"):
        check_petsc_options({"mech_pc_type": "hypre"})
    with pytest.raises(ConfigError, match="without the mech_ prefix"):
        scene_from_dict(mechanics_scene(solver={"petsc": {"mech_ksp_type": "cg"}}))


def test_a_newton_type_coupling_needs_its_matrix_free_jacobian():
    """``-coupling_snes_type newtonls`` without ``-snes_mf`` made PETSc difference ``g`` once per
    pressure unknown (19,595 ``g`` in the first step of the injected disc, a small run timed
    out): refused before meshing, unless the method is Newton–Krylov or the option asks for
    the matrix-free Jacobian."""
    scene = load_scene(ROOT / "configs" / "injection.yaml")
    for opts in ({"coupling_snes_type": "newtonls"}, {"coupling_fallback_snes_type": "newtontr"}):
        with pytest.raises(PetscOptionError, match="newtonkrylov"):
            check_petsc_options(opts, scene)
    check_petsc_options({"coupling_snes_type": "newtonls", "coupling_snes_mf": ""}, scene)
    check_petsc_options({"coupling_snes_type": "ngmres"}, scene)
    nk = load_scene(ROOT / "configs" / "injection.yaml", ["coupling.method=newtonkrylov"])
    check_petsc_options({"coupling_snes_type": "newtontr"}, nk)
    check_petsc_options({"mech_snes_type": "newtonls"}, scene)  # the contact Newton: assembled


def test_one_linear_step_is_refused_for_contact():
    """``-mech_snes_type ksponly`` reported a contact problem converged after one linear step
    (its residual at 7 % of the initial, 112 contact points switching): refused before meshing
    with contact conditions, allowed for open fractures (one linear solve is the solution)."""
    scene = load_scene(ROOT / "configs" / "network3d.yaml")
    with pytest.raises(PetscOptionError, match="does not check the contact conditions"):
        check_petsc_options({"mech_snes_type": "ksponly"}, scene)
    check_petsc_options({"mech_snes_type": "ksponly"},
                        load_scene(ROOT / "configs" / "penny.yaml"))


def test_a_petsc_line_search_on_top_of_the_contact_search_is_refused():
    """``-mech_snes_linesearch_type bt`` ran PETSc's search on the step poromech's search had
    taken (other Newton iterations than either search alone), unreported: refused before
    meshing, from the command line or the scene, naming solver.line_search. With a PETSc
    search chosen by solver.line_search, or PETSc's Newton, the option is PETSc's to read."""
    scene = load_scene(ROOT / "configs" / "six_fractures_mechanics.yaml")
    with pytest.raises(PetscOptionError, match=r"^PETSc option '-mech_snes_linesearch_type' = "
                       r"'bt' would search again .* solver.line_search \(contact, basic"):
        check_petsc_options({"mech_snes_linesearch_type": "bt"}, scene)
    table = load_scene(ROOT / "configs" / "six_fractures_mechanics.yaml",
                       ["solver.petsc={snes_linesearch_type: basic}"])
    with pytest.raises(PetscOptionError, match="scene key 'solver.petsc.snes_linesearch_type'"):
        check_petsc_options({}, table)
    bt = load_scene(ROOT / "configs" / "six_fractures_mechanics.yaml",
                    ["solver.line_search=bt"])
    check_petsc_options({"mech_snes_linesearch_type": "l2"}, bt)
    check_petsc_options({"mech_snes_linesearch_type": "l2", "mech_snes_type": "newtonls"}, scene)


# -- output directory ----------------------------------------------------------------------------
def test_output_directory_paths(tmp_path, capsys):
    afile = tmp_path / "file"
    afile.write_text("x")
    refused(capsys, "run", "sneddon", "-o", afile, fragments=["is a file"])
    refused(capsys, "run", "sneddon", "-o", afile / "sub", fragments=["lies below the file"])
    refused(capsys, "run", "sneddon", "-o", "/proc/poromech_out", fragments=["cannot be created"])
    refused(capsys, "run", "sneddon", "-o", "/proc", fragments=["is not writable"])
    # an empty path was taken as the default results/<scene name>
    for option in ("-o", "--restart"):
        refused(capsys, "run", "sneddon", option, " ", fragments=["' ' is not a directory path"])
    refused(capsys, "plot", tmp_path, "-o", "", fragments=["'' is not a directory path"])
    for name in ("../x", "/abs", "", "."):
        scene = write_scene(tmp_path / "s.yaml", {**mechanics_scene(), "name": name})
        refused(capsys, "run", scene, fragments=["'name'", repr(name)])


def test_restart_of_a_folder_without_a_run_or_a_checkpoint(tmp_path, capsys):
    """``--restart`` refuses, in one line before meshing, a folder with no stored scene and one
    whose run wrote no checkpoint (here a steady scene); it raised h5py's FileNotFoundError
    after meshing, and overwrote the finished run's summary.json with the error."""
    refused(capsys, "run", "--restart", tmp_path / "none", fragments=["no poromech run there"])
    out = tmp_path / "steady"
    assert cli(capsys, "run", "sneddon", "-o", out, "--set", "mesh.size=0.5")[0] == 0
    refused(capsys, "run", "--restart", out, fragments=["wrote no checkpoint.h5"])
    # the refused restart leaves the finished run's record as it was
    assert json.loads((out / "summary.json").read_text())["status"] == "converged"
    # a checkpoint cut short (or another file under its name): h5py's OSError, exit 1, after
    # meshing; an HDF5 file without poromech's metadata: a KeyError
    (out / "checkpoint.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(100))
    refused(capsys, "run", "--restart", out,
            fragments=["checkpoint.h5 cannot be read as a poromech checkpoint"])
    import h5py
    with h5py.File(out / "checkpoint.h5", "w") as f:
        f["x"] = [1.0]
    refused(capsys, "run", "--restart", out, fragments=["poromech checkpoint ("])


def test_a_petsc_error_is_one_line_with_its_routine_and_messages():
    """A PETSc error reaches the user as its innermost routine and PETSc's messages (it was
    "Error: error code 56"), and a Python exception raised inside a PETSc callback as that
    exception (it was "error code 101")."""
    from petsc4py import PETSc

    from poromech.cli import _petsc_error

    A = PETSc.Mat().createAIJ([4, 4], comm=PETSc.COMM_SELF)
    A.setUp()
    A.assemble()
    A.shift(1.0)
    ksp = PETSc.KSP().create(PETSc.COMM_SELF)
    ksp.setOperators(A)
    ksp.setType("cg")
    ksp.setNormType(PETSc.KSP.NormType.UNPRECONDITIONED)
    ksp.setPCSide(PETSc.PC.Side.RIGHT)
    with pytest.raises(PETSc.Error) as caught:
        ksp.setUp()
    line = _petsc_error(caught.value)
    assert line.startswith("PETSc error 56 in KSPSetUpNorms_Private(): ")
    assert line.endswith("KSP cg does not support norm type UNPRECONDITIONED with "
                         "preconditioner side RIGHT")
    assert "\n" not in line and " at /" not in line
    wrapped = PETSc.Error(101)
    wrapped.__cause__ = ValueError("a bad step")
    assert _petsc_error(wrapped) == "ValueError: a bad step"
    for obj in (ksp, A):
        obj.destroy()


def test_output_directory_lock(tmp_path, capsys):
    out = tmp_path / "busy"
    with output_directory(out):
        line = refused(capsys, "run", "sneddon", "-o", out, fragments=["in use", "pid"])
        assert str(out) in line
        with pytest.raises(OutputDirError, match="in use"):
            with output_directory(out):
                pass
    with output_directory(out):  # released at the end of the first run
        pass


def test_stale_outputs_refused_or_cleared(tmp_path, capsys):
    out = tmp_path / "old"
    (out / "displacement_p2.bp").mkdir(parents=True)
    (out / "displacement_p2.bp" / "data.0").write_text("x")
    (out / "fractures_steps").mkdir()
    for name in ("summary.json", "probe_a.csv", ".summary.json.part", "fractures.csv",
                 "notes.txt", "my.yaml", "fractures_paper.pdf"):
        (out / name).write_text("x")
    refused(capsys, "run", "sneddon", "-o", out, fragments=["earlier run", "--overwrite"])
    with output_directory(out, overwrite=True):
        pass
    kept = [LOCK_NAME, "fractures_paper.pdf", "my.yaml", "notes.txt"]
    assert sorted(p.name for p in out.iterdir()) == kept
    (out / "summary.json").write_text("x")
    with output_directory(out, clear=False):  # a restart keeps its outputs
        assert (out / "summary.json").exists()
    # a user's own plots folder is not a run's: --overwrite removed it; next to a run's
    # summary.json it is what poromech plot wrote
    mine = tmp_path / "mine"
    (mine / "plots").mkdir(parents=True)
    (mine / "plots" / "figure.png").write_text("x")
    with output_directory(mine, overwrite=True):
        pass
    assert (mine / "plots" / "figure.png").exists()
    (mine / "summary.json").write_text("x")
    refused(capsys, "run", "sneddon", "-o", mine, fragments=["(plots/, summary.json)"])


# -- resources -----------------------------------------------------------------------------------
def test_meshes_too_large_for_memory(tmp_path, capsys):
    refused(capsys, "run", "-o", tmp_path / "r", "--set", "mesh.refinement=7",
            fragments=["mesh.refinement = 7", "cells", "GB", "available", "--force"])
    refused(capsys, "validate", write_scene(tmp_path / "f.yaml", flow_scene()),
            "--set", "mesh.size=1e-5", fragments=["mesh.size = 1e-05", "GB"])
    refused(capsys, "validate", "six_fractures_mechanics", "--set",
            "mesh.zones=[{center: [1, 0.5], radius: 0.4, size: 1e-4, region: ball}]",
            fragments=["mesh.zones down to size 0.0001", "GB", "--force"])
    # sizes whose square or cube underflows to 0: still the refusal, in 2D and 3D
    refused(capsys, "validate", "six_fractures_mechanics", "--set", "mesh.size=1e-300",
            fragments=["mesh.size = 1e-300", "~inf cells", "~inf GB", "--force"])
    refused(capsys, "validate", "network3d", "--set", "mesh.fracture_size=1e-120",
            fragments=["mesh.fracture_size = 1e-120", "~inf cells", "~inf GB", "--force"])
    assert not (tmp_path / "r").exists()
    assert main(["validate", "six_fractures_mechanics", "--set", "mesh.refinement=7",
                 "--force"]) == 0
    assert "running anyway (--force)" in capsys.readouterr().out


def test_cell_estimate_matches_gmsh():
    from poromech.mesh.generate import MeshSizes, generate_mesh
    from poromech.scene.geometry import scene_geometry
    from poromech.scene.resources import estimate_cells

    scene = load_scene(None)
    geo, m = scene_geometry(scene), scene.mesh
    sizes = MeshSizes(m.size, m.fracture_size, m.fracture_size, 4 * m.size)
    cells = len(generate_mesh(geo, sizes).cells)
    est = estimate_cells(geo, sizes.size, sizes.fracture_size, sizes.tip_size, sizes.transition, 0)
    assert 0.8 < est / cells < 1.2
    assert estimate_cells(geo, sizes.size, sizes.fracture_size, sizes.tip_size,
                          sizes.transition, 2) == pytest.approx(16 * est)


def test_probes_bounded_and_warned_outside(caplog):
    raw = flow_scene()
    raw["probes"] = [{"name": "p", "start": [0, 0.5], "end": [1, 0.5], "samples": 3e9}]
    with pytest.raises(ConfigError, match=r"probes\.0\.samples.*<= 100000"):
        scene_from_dict(raw)
    raw["probes"] = [{"name": "far", "start": [2, 2], "end": [3, 3]},
                     {"name": "across", "start": [-1, 0.2], "end": [2, 0.2]}]
    import logging
    logger = logging.getLogger("poromech")
    records = []
    handler = logging.Handler()
    handler.emit = records.append
    logger.addHandler(handler)
    try:
        scene_from_dict(raw)
    finally:
        logger.removeHandler(handler)
    warned = [r.getMessage() for r in records if r.levelno == logging.WARNING]
    assert len(warned) == 1 and "'far'" in warned[0] and "outside the domain" in warned[0]


# -- messages ------------------------------------------------------------------------------------
def test_messages_show_plain_numbers_and_names():
    raw = mechanics_scene()
    raw["geometry"]["fractures"] = [{"points": [[0.5, 0.5], [3.0, 0.5]]}]
    with pytest.raises(ConfigError, match=r"point \(3, 0\.5\) outside") as info:
        scene_from_dict(raw)
    assert "np." not in str(info.value)
    with pytest.raises(ExpressionError, match="function 'x.sin'"):
        compile_expression("x.sin(1)")


def test_a_parameter_may_use_the_parameters_above_it(caplog):
    """``parameters: {a: 0.4, b: a/2}`` was refused (unknown name 'a', listing x, y, z, t as
    allowed); a parameter used only by another one is not reported as unused."""
    raw = mechanics_scene(parameters={"a": 0.4, "b": "a/2"}, mesh={"size": "b/2"})
    caplog.clear()
    assert scene_from_dict(raw).mesh.size == 0.1
    assert not [r for r in caplog.records if "parameters.a" in r.getMessage()]
    raw["parameters"] = {"b": "a/2", "a": 0.4}
    with pytest.raises(ConfigError, match=r"'parameters.b' = 'a/2' must be a number or an "
                                          r"expression of the parameters: unknown name 'a' "
                                          r"\(allowed: e, pi\); a parameter may use those above"):
        scene_from_dict(raw)


def test_yaml_dates_and_booleans_are_named_as_such():
    """``--set name=2026-01-01`` and ``formulation=no`` are a date and a boolean to YAML; the
    messages showed Python's datetime.date(2026, 1, 1) and False."""
    raw = mechanics_scene()
    raw["name"] = datetime.date(2026, 1, 1)
    with pytest.raises(ConfigError, match=r"'name' = 2026-01-01 \(a date to YAML: quote it"):
        scene_from_dict(raw)
    raw = mechanics_scene()
    raw["contact"] = {"formulation": False}
    with pytest.raises(ConfigError, match=r"= false \(a YAML boolean, as are yes/no/on/off: "
                                          r"quote text\) is not one of"):
        scene_from_dict(raw)


def test_a_number_may_be_an_expression_of_the_parameters():
    """``radius: a`` was accepted and ``radius: a/2`` refused as not a number: a number key
    takes an expression of the parameters, evaluated once, and refuses x, y, z, t in it."""
    raw = mechanics_scene(parameters={"w": 0.8})
    raw["geometry"]["fractures"] = [{"points": [["w/4", 0.5], ["3*w/4", "0.5*w/0.8"]]}]
    raw["mesh"]["size"] = "w/4"
    scene = scene_from_dict(raw)
    assert scene.geometry.fractures[0].points == ((0.2, 0.5), (0.6000000000000001, 0.5))
    assert scene.mesh.size == 0.2
    for value, message in (("x/4", "it may use the parameters, not x, y, z or t"),
                           ("v/4", "or an expression of the parameters: unknown name 'v'"),
                           ("w/0", "it evaluates to inf")):
        raw["mesh"]["size"] = value
        with pytest.raises(ConfigError, match=f"scene key 'mesh.size' = '{value}' must be a "
                                              "number"):
            scene_from_dict(raw)
        with pytest.raises(ConfigError, match=message):
            scene_from_dict(raw)


# -- after meshing: every expression where the solvers evaluate it -------------------------------
def _mesh(scene):
    from mpi4py import MPI

    from poromech.mesh.fractured import create_fractured_mesh
    from poromech.mesh.generate import MeshSizes, generate_mesh
    from poromech.scene.geometry import scene_geometry

    geo, m = scene_geometry(scene), scene.mesh
    f = m.fracture_size or m.size
    arrays = generate_mesh(geo, MeshSizes(m.size, f, f, 4 * m.size))
    return create_fractured_mesh(MPI.COMM_WORLD, geo, arrays), arrays


def test_fields_checked_at_mesh_points():
    from poromech.scene.fields import validate_fields

    scene = scene_from_dict(mechanics_scene(mesh={"size": 0.2}))
    fm, arrays = _mesh(scene)
    validate_fields(scene, fm)
    # a Young's modulus negative in a tiny disc around one cell centroid: the pre-mesh grid
    # misses it, the centroid check does not
    c = [float(v) for v in arrays.x[arrays.cells[7]].mean(axis=0)]
    young = compile_expression(f"where(hypot(x - {c[0]!r}, y - {c[1]!r}) < 1e-9, -1e9, 1e9)")
    bad = dataclasses.replace(scene, material=dataclasses.replace(scene.material, young=young))
    with pytest.raises(ConfigError, match=r"material\.young.*-1e\+09.*cell centre.*> 0"):
        validate_fields(bad, fm)
    # a boundary displacement singular at the midpoint of a top facet: a P2 node, not a P1 one
    top = arrays.boundary_facets[arrays.boundary_edge == 2][0]
    xm = float(arrays.x[top].mean(axis=0)[0])
    bc = scene.boundary_conditions[1]
    ux = compile_expression(f"0.001/(x - {xm!r})")
    bcs = (scene.boundary_conditions[0],
           dataclasses.replace(bc, displacement=(ux, bc.displacement[1])))
    p2 = dataclasses.replace(scene, boundary_conditions=bcs)
    with pytest.raises(ConfigError, match=r"boundary_conditions\.1\.displacement\.0.*finite"):
        validate_fields(p2, fm)
    validate_fields(dataclasses.replace(p2, degree=1), fm)


def test_flow_fields_checked_at_mesh_points():
    from poromech.scene.fields import validate_fields

    scene = scene_from_dict(flow_scene())
    fm, arrays = _mesh(scene)
    validate_fields(scene, fm)
    mid = [float(v) for v in fm.fractures.midpoint[3]]
    aperture = compile_expression(
        f"where(hypot(x - {mid[0]!r}, y - {mid[1]!r}) < 1e-9, 0, 1e-4)")
    bad = dataclasses.replace(scene, flow=dataclasses.replace(scene.flow, aperture=aperture))
    with pytest.raises(ConfigError, match=r"flow\.aperture.*fracture face.*> 0"):
        validate_fields(bad, fm)


# -- MPI: every class under mpirun -n 2 prints one line and ends both ranks alike ----------------
@pytest.mark.mpi
def test_refusals_under_mpi(tmp_path):
    binary = tmp_path / "binary.yaml"
    binary.write_bytes(bytes(range(256)))
    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("name: bomb\n" + BILLION_LAUGHS)
    afile = tmp_path / "afile"
    afile.write_text("x")
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "summary.json").write_text("{}")
    cases = {
        "binary": ["validate", binary],
        "bomb": ["validate", bomb],
        "expression": ["validate", "sneddon", "--set", "material.young=min(x)"],
        "nan_bc": ["run", "sneddon", "-o", tmp_path / "n",
                   "--set", "boundary_conditions.0.displacement.0=.nan"],
        "set_scalar": ["validate", "sneddon", "--set", "degree.x=1"],
        "petsc": ["run", "sneddon", "-o", tmp_path / "p", "-mech_ksp_type", "nonsense"],
        "outdir": ["run", "sneddon", "-o", afile / "sub"],
        "stale": ["run", "sneddon", "-o", tmp_path / "old"],
        "memory": ["run", "sneddon", "-o", tmp_path / "m", "--set", "mesh.refinement=7"],
        "usage": ["run", "--no-such-flag"],
    }
    result = run_parallel(f"""
        import contextlib, io, json
        import dolfinx_solver
        from mpi4py import MPI
        from poromech.cli import main
        import poromech.cli
        comm = MPI.COMM_WORLD
        cases = {json.dumps({k: [str(a) for a in v] for k, v in cases.items()})}

        def boom(args, petsc_opts, comm):
            raise RuntimeError("the same bug on every rank")

        poromech.cli._COMMANDS["scenes"] = boom
        cases["bug"] = ["scenes"]
        out = {{}}
        for name, args in cases.items():
            err = io.StringIO()
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = main(args)
            out[name] = (comm.gather(code), comm.gather(err.getvalue().strip().splitlines()))
        if comm.rank == 0:
            res = {{k: {{"codes": c, "lines": sum(ls, [])}} for k, (c, ls) in out.items()}}
            print(json.dumps(res))
        """)
    for name, r in result.items():
        expected = 1 if name == "bug" else 2
        assert r["codes"] == [expected, expected], (name, r)
        assert len(r["lines"]) == 1, (name, r)
    assert "RuntimeError: the same bug" in result["bug"]["lines"][0]


@pytest.mark.mpi
@pytest.mark.parametrize("args", [["run", "{bad}"], ["run", "sneddon", "-o", "{out}",
                                                     "-mech_snes_type", "bogus"]])
def test_mpirun_exits_2_with_one_line(tmp_path, args):
    bad = tmp_path / "bad.yaml"
    bad.write_bytes(b"\x00\x01binary")
    args = [a.format(bad=bad, out=tmp_path / "o") for a in args]
    proc = subprocess.run([mpirun(), "-n", "2", *POROMECH, *args], capture_output=True,
                          text=True, cwd=ROOT, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, lines


def aborts_once(script, message: str, rank: int) -> None:
    """``script`` on 2 ranks raises ``message`` on ``rank`` only: every rank ends, non-zero,
    within a minute, the error said once as that rank's alone."""
    t0 = time.perf_counter()
    proc = subprocess.run([mpirun(), "-n", "2", sys.executable, str(script)],
                          capture_output=True, text=True, cwd=ROOT, timeout=120)
    assert proc.returncode != 0 and time.perf_counter() - t0 < 60
    assert proc.stderr.count(message) == 1, proc.stderr
    assert f"on rank {rank} only" in proc.stderr


@pytest.mark.mpi
def test_error_on_one_rank_aborts_without_hang(tmp_path):
    script = tmp_path / "one_rank.py"
    script.write_text(
        "import sys\n"
        "import dolfinx_solver\n"
        "from mpi4py import MPI\n"
        "import poromech.cli as cli\n"
        "import poromech.parallel\n"
        "poromech.parallel.AGREE_TIMEOUT = 1.0\n"
        "def command(args, petsc_opts, comm):\n"
        "    if comm.rank == 1:\n"
        "        raise OSError('disk gone on rank 1')\n"
        "    comm.barrier()\n"
        "cli._COMMANDS['scenes'] = command\n"
        "sys.exit(cli.main(['scenes']))\n")
    aborts_once(script, "disk gone on rank 1", rank=1)


@pytest.mark.mpi
def test_an_error_inside_a_run_on_one_rank_aborts_without_hang(tmp_path):
    """A bug raising on rank 0 only while the physics is built: rank 0 went into the run's
    clean-up, whose calls are collective (the summary, the timers), while rank 1 waited in the
    first step's: every mechanics run on 2 ranks hung that way, silently, for a pickling
    reduction that failed on one rank. Now the clean-up is skipped where the others did not
    fail, and the error aborts every rank, said once."""
    script = tmp_path / "one_rank_run.py"
    script.write_text(
        "import sys\n"
        "import dolfinx_solver\n"
        "from mpi4py import MPI\n"
        "import poromech.parallel\n"
        "poromech.parallel.AGREE_TIMEOUT = 1.0\n"
        "import poromech.cli as cli\n"
        "import poromech.run as run\n"
        "init = run.Run.__init__\n"
        "def bug(physics):\n"
        "    if MPI.COMM_WORLD.rank == 0:\n"
        "        raise ValueError('a bug on rank 0')\n"
        "def patched(self, *args, **kwargs):\n"
        "    init(self, *args, **kwargs, prepare=bug)\n"
        "run.Run.__init__ = patched\n"
        f"sys.exit(cli.main(['run', 'sneddon', '-q', '-o', {str(tmp_path / 'out')!r}]))\n")
    aborts_once(script, "a bug on rank 0", rank=0)


@pytest.mark.mpi
def test_fields_checked_at_mesh_points_under_mpi():
    """The bad cell is owned by one rank; both raise the same one-line error."""
    result = run_parallel(f"""
        import dataclasses, json
        import dolfinx_solver
        from mpi4py import MPI
        from poromech.errors import ConfigError
        from poromech.scene.geometry import scene_geometry
        from poromech.scene.loading import scene_from_dict
        from poromech.scene.expressions import compile_expression
        from poromech.scene.fields import validate_fields
        from poromech.mesh.fractured import create_fractured_mesh
        from poromech.mesh.generate import MeshSizes, generate_mesh
        comm = MPI.COMM_WORLD
        scene = scene_from_dict({mechanics_scene(mesh={"size": 0.2})!r})
        geo = scene_geometry(scene)
        arrays = generate_mesh(geo, MeshSizes(0.2, 0.2, 0.2, 0.8)) if comm.rank == 0 else None
        fm = create_fractured_mesh(comm, geo, arrays)
        c = comm.bcast([float(v) for v in arrays.x[arrays.cells[7]].mean(axis=0)]
                       if comm.rank == 0 else None)
        young = compile_expression(f"where(hypot(x - {{c[0]!r}}, y - {{c[1]!r}}) < 1e-9, -1, 1)")
        bad = dataclasses.replace(scene, material=dataclasses.replace(scene.material,
                                                                      young=young))
        validate_fields(scene, fm)
        try:
            validate_fields(bad, fm)
            msg = None
        except ConfigError as err:
            msg = str(err)
        msgs = comm.gather(msg)
        if comm.rank == 0:
            print(json.dumps({{"messages": msgs}}))
        """)
    a, b = result["messages"]
    assert a == b and "material.young" in a and "cell centre" in a


def test_mesh_zones_checked_before_meshing(caplog):
    """A zone centre with the wrong number of components, or a ball that misses the domain, is
    refused in one line naming the key; a zone on the fractures of a scene without any, or of
    a mesh file, is reported as without effect."""
    from conftest import config_error

    zone = {"center": [0.5, 0.5], "radius": 0.1, "size": 0.01}
    raw = mechanics_scene(mesh={"size": 0.1, "zones": [{**zone, "center": [0.5, 0.5, 0.0]}]})
    assert "'mesh.zones.0.center' has 3 components: a 2D vector has 2" in config_error(raw)
    raw = mechanics_scene(mesh={"size": 0.1, "zones": [{**zone, "center": [2.5, 0.5]}]})
    msg = config_error(raw)
    assert "'mesh.zones.0.center' = [2.5, 0.5] is farther than its radius 0.1 m" in msg
    raw = mechanics_scene(mesh={"size": 0.1, "zones": [{**zone, "region": "all"}]})
    assert "'mesh.zones.0.region'" in config_error(raw) and "ball" in config_error(raw)
    raw = mechanics_scene(mesh={"size": 0.1, "zones": [zone]})
    raw["geometry"]["fractures"] = []
    caplog.clear()
    scene_from_dict(raw)
    assert any("'mesh.zones.0.size' has no effect: the scene has no fractures for the zone"
               in r.getMessage() for r in caplog.records)
    raw["mesh"]["zones"][0]["region"] = "ball"
    caplog.clear()
    scene_from_dict(raw)
    assert not any("zones" in r.getMessage() for r in caplog.records)
    # zones that refine nothing were accepted silently: a ball on the fractures that reaches
    # none, and a size not finer than the one already there
    raw = mechanics_scene(mesh={"size": 0.1, "zones": [{**zone, "center": [0.05, 0.05]}]})
    for change, said in (({"transition": 0.1}, "no fracture is within its radius and "
                                               "twice its transition (0.3 m) of its centre"),
                         # 0.35 m from the bar and the stem, beyond radius + transition: the
                         # ball's transition overlaps the band around them, and the mesh has 524
                         # cells instead of 522; it was reported as without effect
                         ({"transition": 0.2, "center": [0.15, 0.15]}, None),
                         ({}, None),  # the default transition, 0.4 m, reaches the fractures
                         ({"center": [0.5, 0.5], "size": 0.2}, "its size 0.2 m is not finer "
                                                               "than the 0.1 m the fractures"),
                         ({"center": [0.5, 0.5], "size": 0.2, "region": "ball"},
                          "its size 0.2 m is not finer than mesh.size 0.1 m"),
                         ({"center": [0.5, 0.5]}, None)):
        raw["mesh"]["zones"] = [{**zone, "center": [0.05, 0.05], "region": "fractures",
                                 **change}]
        caplog.clear()
        scene_from_dict(raw)
        warned = [r.getMessage() for r in caplog.records if "mesh.zones.0" in r.getMessage()]
        assert (said is None and not warned) or any(said in w for w in warned), (
            said, [r.getMessage() for r in caplog.records])
    # a zone that another asks for a size at most its own everywhere (ball and transition
    # inside the other's) refines nothing, the later of two equal ones; it was not reported
    big = {"center": [0.5, 0.5], "radius": 0.2, "size": 0.01}
    for zones, said in (([big, {**big, "radius": 0.1, "size": 0.02}], {1: 0}),
                        ([big, dict(big)], {1: 0}),
                        ([{**big, "radius": 0.1, "size": 0.02}, big], {0: 1}),
                        ([big, {**big, "radius": 0.1, "size": 0.005}], {}),
                        ([big, {**big, "center": [0.65, 0.5], "size": 0.02}], {}),  # sticks out
                        ([big, {**big, "transition": 0.8, "size": 0.02}], {}),
                        ([{**big, "region": "ball"}, {**big, "radius": 0.1, "size": 0.02}],
                         {1: 0}),
                        ([big, {**big, "radius": 0.1, "size": 0.02, "region": "ball"}], {})):
        raw["mesh"]["zones"] = zones
        caplog.clear()
        scene_from_dict(raw)
        warned = {int(m.group(1)): r.getMessage() for r in caplog.records
                  if (m := re.search(r"'mesh\.zones\.(\d)\.size' has no effect",
                                     r.getMessage()))}
        assert set(warned) == set(said), (zones, warned)
        for i, other in said.items():
            assert f"mesh.zones.{other} asks for a size at most its own" in warned[i]


def test_condensation_in_3d_is_reported_as_without_effect(caplog):
    """The condensed ``mixed`` solve is 2D only: ``solver.condensation`` in a 3D scene is
    reported by the one-line warning of keys without effect (it changed nothing silently)."""
    caplog.clear()
    load_scene(ROOT / "configs" / "network3d.yaml",
               ["contact.formulation=mixed", "solver.condensation=false"])
    assert any("'solver.condensation' has no effect: the condensed solve is 2D only"
               in r.getMessage() for r in caplog.records)
    caplog.clear()
    load_scene(ROOT / "configs" / "six_fractures_mechanics.yaml",
               ["contact.formulation=mixed", "solver.condensation=false"])
    assert not any("condensation" in r.getMessage() for r in caplog.records)


def test_a_section_set_to_null_is_not_given():
    """``--set flow=null`` takes a coupled scene's flow section away for a mechanics run (it
    was refused as a section of another physics); a flow section with content still is."""
    scene = load_scene(ROOT / "configs" / "injection.yaml", ["physics=mechanics", "flow=null"])
    assert scene.physics == "mechanics" and scene.flow is None
    with pytest.raises(ConfigError, match="'flow' is not allowed"):
        load_scene(ROOT / "configs" / "injection.yaml", ["physics=mechanics"])


def test_a_missing_section_names_the_scene_physics():
    """A coupled scene made from a flow or mechanics scene names ``poromechanics`` as the physics
    that needs the missing section (it said 'mechanics' or 'flow')."""
    for name, key in (("flow_six_fractures", "material"), ("sneddon", "flow")):
        with pytest.raises(ConfigError, match=f"'{key}' is required for physics 'poromechanics'"):
            load_scene(ROOT / "configs" / f"{name}.yaml", ["physics=poromechanics"])


def test_restart_with_other_time_steps_is_refused(tmp_path, capsys):
    """A checkpoint whose steps do not end where the edited scene's do is refused (the run went
    back in time: t = 30 s after t = 50 s); steps added after the last one are accepted."""
    out = tmp_path / "tz"
    assert cli(capsys, "run", "terzaghi", "-o", out, "--set", "time.steps=4")[0] == 0
    stored = out / "poromech_scene.yaml"
    raw = yaml.safe_load(stored.read_text())
    raw["time"] = {"final": 20.0, "steps": 8}  # step 4 now ends at 10 s, not 20 s
    stored.write_text(yaml.safe_dump(raw))
    refused(capsys, "run", "--restart", out,
            fragments=["after step 4 at t = 20 s", "step 4 ends at t = 10 s", "time keys"])
    raw["time"] = {"final": 30.0, "steps": 6}  # the same four steps, and two more
    stored.write_text(yaml.safe_dump(raw))
    assert cli(capsys, "run", "--restart", out)[0] == 0
    times = [s["time"] for s in json.loads((out / "summary.json").read_text())["solves"]]
    assert times == [5.0, 10.0, 15.0, 20.0, 25.0, 30.0]
    raw["degree"] = 3 - raw.get("degree", 1)  # the same mesh, another space (said "mesh")
    stored.write_text(yaml.safe_dump(raw))
    refused(capsys, "run", "--restart", out, fragments=["unknowns on this mesh",
                                                         "its degree, contact formulation"])
    raw["degree"] = 3 - raw["degree"]
    raw["mesh"]["size"] = 3.0 * raw["mesh"]["size"]  # another mesh: one line, exit 2 (was 1)
    stored.write_text(yaml.safe_dump(raw))
    refused(capsys, "run", "--restart", out, fragments=["written for another mesh"])


@pytest.mark.parametrize(("name", "fragment"), [
    ("e", "would hide the variable, constant or function 'e'"),
    ("pi", "would hide"), ("sqrt", "would hide"), ("t", "would hide"),
    ("lambda", "not a Python keyword"), (None, "'parameters.None' is not a usable name"),
    ("2a", "not a usable name"),
])
def test_parameter_names_that_cannot_be_used(name, fragment):
    """A parameter named e or pi silently replaced the constant in every expression."""
    raw = mechanics_scene()
    raw["parameters"] = {name: 1.0}
    with pytest.raises(ConfigError, match="scene key 'parameters") as info:
        scene_from_dict(raw)
    assert fragment in str(info.value), info.value


def test_two_displacements_of_one_component_where_boundaries_meet_are_reported(tmp_path,
                                                                                  capsys):
    """``u_x = 1 mm`` on the bottom and ``u_x = 0`` on the left meet at the corner, where the
    condition listed later holds (DOLFINx sets them in order): the results changed with the
    order of the list, silently. Said in one line naming both keys, the boundaries, the values
    and which holds; equal values on the shared nodes say nothing."""
    from poromech.cli import main

    cases = (
        ([{"boundary": "bottom", "displacement": [1.0e-3, 0.0]},
          {"boundary": "left", "displacement": [0.0, None]}],
         "set u_x to 0.001 and 0 m where boundaries 'bottom' and 'left' meet: the later one, "
         "boundary_conditions.1, holds there"),
        ([{"boundary": "left", "displacement": [0.0, None]},
          {"boundary": "bottom", "displacement": [1.0e-3, 0.0]}],
         "set u_x to 0 and 0.001 m where boundaries 'left' and 'bottom' meet"),
        ([{"boundary": "left", "displacement": [0.0, None]},
          {"boundary": "bottom", "displacement": ["2.0e-3*x", 0.0]}], None),  # 0 at x = 0
        ([{"boundary": "left", "displacement": [0.0, None]},
          {"boundary": "right", "displacement": [1.0e-3, None]},
          {"boundary": "bottom", "displacement": [None, 0.0]}], None),  # never meet
    )
    for conditions, said in cases:
        raw = mechanics_scene(boundary_conditions=[
            *conditions, {"boundary": "top", "traction": [0.0, -1.0e6]}])
        path = tmp_path / "scene.yaml"
        path.write_text(yaml.safe_dump(raw))
        assert main(["validate", str(path), "--mesh"]) == 0
        captured = capsys.readouterr()
        lines = [x for x in (captured.out + captured.err).splitlines() if "meet:" in x]
        if said is None:
            assert not lines, lines
        else:
            assert len(lines) == 1 and said in lines[0], lines
            assert "'boundary_conditions.0.displacement' and " \
                   "'boundary_conditions.1.displacement'" in lines[0]
    # equal at t = 0, different at the final time
    raw = mechanics_scene(boundary_conditions=[
        {"boundary": "bottom", "displacement": ["1.0e-3*t", 0.0]},
        {"boundary": "left", "displacement": [0.0, None]},
        {"boundary": "top", "traction": [0.0, -1.0e6]}], time={"final": 2.0, "steps": 2})
    path.write_text(yaml.safe_dump(raw))
    assert main(["validate", str(path), "--mesh"]) == 0
    captured = capsys.readouterr()
    assert "set u_x to 0.002 and 0 m where boundaries 'bottom' and 'left' meet" \
        in captured.out + captured.err


@pytest.mark.parametrize(("scene", "key", "value", "message"), [
    # the coupled initial equilibrium uses the loads at t = 0, not only at the step times
    ("terzaghi", "boundary_conditions.3.traction", "[0, '-sigma0*sqrt(t-1)']",
     "'boundary_conditions.3.traction.1' = '-sigma0*sqrt(t-1)' is nan at x=0, y=1, t=0"),
    ("terzaghi", "flow.permeability", "['1e-14*(1+log(t))']", "'flow.permeability' = [-inf]"),
    # the weight and the in-situ stress, where the solver interpolates them
    ("fault_reactivation", "material.density", "2450+0*log(x)",
     "'material.density' = '2450+0*log(x)' is nan at x=0"),
    ("fault_reactivation", "material.initial_stress",
     "['k*rho*g*y+0*sqrt(x-0.5)', 'rho*g*y', 0.0]",
     "'material.initial_stress.0' = 'k*rho*g*y+0*sqrt(x-0.5)' is nan at x=0"),
])
def test_fields_used_at_t0_and_the_weight_are_checked_on_the_mesh(scene, key, value, message,
                                                                   capsys):
    """``validate --mesh`` said valid, and the run failed with NaN (``DIVERGED_FUNCTION_NANORINF``
    in the initial equilibrium, or PETSc's error 76 in MUMPS)."""
    from poromech.cli import main

    sets = ["--set", f"{key}={value}", "--set", "time.steps=2"]
    assert main(["validate", scene, *sets, "--mesh"]) == 2
    last = capsys.readouterr().err.strip().splitlines()[-1]
    assert message in last, last


@pytest.mark.parametrize(("args", "message"), [
    (["sneddon", "--set", "mesh.refinement=1" + "0" * 400], "'mesh.refinement' = 1000"),
    (["penny", "--set", "geometry.fractures.0.disc.radius=1.0e+200"],
     "beyond what double precision computes with"),
    (["inclined_crack_slip", "--set",
      "boundary_conditions.0.displacement=['inclined_crack_ux(x, y, b, 0.3*y, sigma, F, E, nu)',"
      " 0]"], "cannot be evaluated (ValueError"),
    (["sneddon", "--set", "boundary_conditions.0.displacement=['mandel_p(x,t,0,1,1,0.25,1,1,1)',"
      " 0]"], "cannot be evaluated (ZeroDivisionError"),
    (["flow_barrier_conduit", "--set", "probes.0.name=" + "p" * 260],
     "is 260 bytes long (allowed: at most 200"),
    (["terzaghi", "--set", "time.final=5.0e-324", "--set", "time.steps=2"],
     "gives a step of 0 s (allowed: steps of at least 2.23e-308 s)"),
])
def test_fuzzed_input_is_one_line(args, message, capsys):
    """Inputs a fuzzer found to end in a traceback (a huge integer, an overflow in the geometry
    checks, an exact field given varying or degenerate parameters), or to pass ``validate`` and
    fail later (a probe name too long for a file name, steps that round to 0 s)."""
    from poromech.cli import main

    assert main(["validate", *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_a_yaml_set_as_a_key_is_one_line(tmp_path, capsys):
    """``? !!set {x}`` raised TypeError: unhashable type: 'set'."""
    from poromech.cli import main

    path = tmp_path / "set.yaml"
    path.write_text("? !!set {x}\n")
    assert main(["validate", str(path)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is not valid YAML" in err[0], err
