"""Open every XDMF output of poromech runs in ParaView, as a user would, and check it.

Run with ParaView's Python (no poromech needed; h5py, if pvpython has it, adds a value check)::

    xvfb-run -a pvpython scripts/paraview_check.py OUTDIR [OUTDIR ...] [--reader Xdmf3ReaderT]

For every ``<stem>.xdmf`` of each output directory, with the chosen reader (ParaView's
"Xdmf3 Reader T" by default; ``Xdmf3ReaderS`` and the legacy ``XDMFReader`` can be tried), it
checks that

* the reader's time steps are the times of the XDMF index, every one of them in
  ``summary.json`` (a solved step, or t = 0), the last one the end of a finished run;
* every time step loads, with the numbers of points and cells of the index, its cell type
  (triangles, tetrahedra or segments) and exactly its arrays (name, point/cell, number of
  tuples and components), finite, and equal to the per-step HDF5 data when h5py is
  importable; the ranges ParaView reports for each component (its Information panel and
  colour maps) are then the minimum and maximum of the HDF5 data;
* the displacement warps (Warp By Vector) at every time step: the warped points are the points
  moved by the scale factor times ``u``;
* one PNG per file renders off-screen at the last time (``OUTDIR/plots/paraview_<stem>.png``,
  or ``--png-dir``); in 3D the displacement and the flow fields of the matrix are cut in half
  (a clip through the domain's centre) so that the fractures and the inside show.

A run killed at any moment (``kill -9``) must pass too: its index lists only completed steps.
Prints one Markdown table row per file; the exit status is the number of files that failed.
"""

import argparse
import json
import math
import sys
import traceback
import xml.etree.ElementTree as ET
from pathlib import Path

from paraview import servermanager
from paraview.simple import (
    Clip,
    ColorBy,
    Delete,
    GetActiveView,
    GetActiveViewOrCreate,
    GetDisplayProperties,
    Hide,
    Render,
    ResetCamera,
    SaveScreenshot,
    Show,
    WarpByVector,
)
from paraview.vtk.util.numpy_support import vtk_to_numpy

try:
    import h5py
except ImportError:  # values are then checked for finiteness only
    h5py = None

READERS = ("Xdmf3ReaderT", "Xdmf3ReaderS", "XDMFReader")

#: VTK cell types a reader may make of each XDMF topology written by poromech (segments are
#: two-point poly-lines, or lines).
VTK_CELL = {"Polyline": {3, 4}, "Triangle": {5}, "Tetrahedron": {10}}


class CheckError(AssertionError):
    """A file does not read as its index says."""


def read_index(path):
    """Times and, per step, the attributes of an XDMF index written by poromech.io.xdmf."""
    steps = []
    for grid in ET.parse(path).getroot().iter("Grid"):
        if grid.get("GridType") != "Uniform":
            continue
        topo = grid.find("Topology")
        geo = grid.find("Geometry/DataItem")
        attrs = {}
        for att in grid.iter("Attribute"):
            item = att.find("DataItem")
            dims = [int(d) for d in item.get("Dimensions").split()]
            ref = item.text.strip().split(":/")
            attrs[att.get("Name")] = (att.get("Center"), 1 if len(dims) == 1 else dims[1],
                                      ref[0], ref[1])
        steps.append({"time": float(grid.find("Time").get("Value")),
                      "topology": topo.get("TopologyType"),
                      "solid": grid.find("Geometry").get("GeometryType") == "XYZ",
                      "cells": int(topo.get("NumberOfElements")),
                      "points": int(geo.get("Dimensions").split()[0]),
                      "attributes": attrs})
    return steps


def solved_times(summary):
    """Times of the solves recorded in summary.json (mechanics, coupled or flow runs)."""
    solves = summary.get("solves") or summary.get("flow", {}).get("solves") or []
    return [float(s["time"]) for s in solves]


def close(a, b):
    return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)


def check_times(times, summary):
    """Index times against summary.json (a killed run may have one step written, not recorded)."""
    solved = solved_times(summary)
    allowed = [0.0, *solved]
    extra = [t for t in times if not any(close(t, s) for s in allowed)]
    finished = summary.get("status") == "converged"
    if extra and (finished or len(extra) > 1 or not solved or extra[0] < max(solved)
                  or extra[0] != times[-1]):
        raise CheckError(f"times {extra} of the index are not solved steps in summary.json")
    if finished and solved and not close(times[-1], max(solved)):
        raise CheckError(f"finished run ends at t = {max(solved)}, the index at {times[-1]}")
    if sorted(times) != times or len(set(times)) != len(times):
        raise CheckError(f"index times are not increasing: {times}")


def open_reader(name, path):
    """The ParaView reader ``name`` on ``path``, its pipeline information updated."""
    from paraview import simple

    if name == "XDMFReader":
        reader = simple.XDMFReader(FileNames=[str(path)])
    else:
        reader = getattr(simple, name)(FileName=[str(path)])
    reader.UpdatePipelineInformation()
    return reader


def reader_times(reader):
    """The reader's time steps as a list (ParaView gives a number for a single one)."""
    values = reader.TimestepValues
    try:
        return [float(v) for v in values]
    except TypeError:
        return [float(values)]


def first_leaf(data):
    """The dataset itself, or the first non-empty leaf of a composite dataset."""
    if not data.IsA("vtkCompositeDataSet"):
        return data
    it = data.NewIterator()
    it.InitTraversal()
    while not it.IsDoneWithTraversal():
        leaf = it.GetCurrentDataObject()
        if leaf is not None and leaf.GetNumberOfPoints():
            return leaf
        it.GoToNextItem()
    raise CheckError("the reader returned an empty composite dataset")


def check_step(reader, step, outdir):
    """Load one time step and compare it with the index (and the HDF5 data with h5py)."""
    reader.UpdatePipeline(step["time"])
    data = first_leaf(servermanager.Fetch(reader))
    if (data.GetNumberOfPoints(), data.GetNumberOfCells()) != (step["points"], step["cells"]):
        raise CheckError(f"t = {step['time']}: {data.GetNumberOfPoints()} points, "
                         f"{data.GetNumberOfCells()} cells; index: {step['points']}, "
                         f"{step['cells']}")
    types = {data.GetCellType(i) for i in range(data.GetNumberOfCells())}
    if len(types) != 1 or not types <= VTK_CELL[step["topology"]]:
        raise CheckError(f"t = {step['time']}: VTK cell types {sorted(types)}, index "
                         f"{step['topology']}")
    for center, fields in (("Node", data.GetPointData()), ("Cell", data.GetCellData())):
        want = {k: v for k, v in step["attributes"].items() if v[0] == center}
        have = {fields.GetArrayName(i) for i in range(fields.GetNumberOfArrays())}
        have.discard("vtkOriginalCellIds")
        have.discard("vtkOriginalPointIds")
        if have != set(want):
            raise CheckError(f"t = {step['time']}: {center} arrays {sorted(have)}, index "
                             f"{sorted(want)}")
        size = step["points"] if center == "Node" else step["cells"]
        for name, (_, comps, file, dataset) in want.items():
            values = vtk_to_numpy(fields.GetArray(name))
            if (values.shape[1] if values.ndim == 2 else 1) != comps or len(values) != size:
                raise CheckError(f"t = {step['time']}: {name} has shape {values.shape}, "
                                 f"index {size} × {comps}")
            if not (values == values).all():
                raise CheckError(f"t = {step['time']}: {name} has NaN")
            if h5py is not None:
                with h5py.File(outdir / file, "r") as f:
                    stored = f[dataset][()]
                if stored.shape != values.shape or abs(stored - values).max() > 0:
                    raise CheckError(f"t = {step['time']}: {name} differs from {file}")


def check_ranges(reader, step, outdir):
    """The ranges ParaView reports (Information panel, colour maps) are those of the HDF5 data.

    Per component, from the reader proxy's data information at the step's time: the path by
    which the ranges reach the client, not the fetched dataset of :func:`check_step`.
    """
    reader.UpdatePipeline(step["time"])
    for name, (center, comps, file, dataset) in step["attributes"].items():
        info = (reader.PointData if center == "Node" else reader.CellData)[name]
        got = [tuple(info.GetRange(c)) for c in range(comps)]
        with h5py.File(outdir / file, "r") as f:
            stored = f[dataset][()].reshape(-1, comps)
        want = [(float(stored[:, c].min()), float(stored[:, c].max())) for c in range(comps)]
        if got != want:
            raise CheckError(f"t = {step['time']}: ParaView's range of {name} is {got}, the "
                             f"HDF5 data's {want}")


def check_warp(reader, step):
    """Warp By Vector moves every point by the scale factor times ``u`` (one time step)."""
    reader.UpdatePipeline(step["time"])
    data = first_leaf(servermanager.Fetch(reader))
    points = vtk_to_numpy(data.GetPoints().GetData()).astype(float)
    u = vtk_to_numpy(data.GetPointData().GetArray("u")).astype(float)
    size = max(points.max(axis=0) - points.min(axis=0))
    umax = abs(u).max()
    scale = 0.1 * size / umax if umax > 0 else 1.0
    warp = WarpByVector(Input=reader, Vectors=["POINTS", "u"], ScaleFactor=scale)
    warp.UpdatePipeline(step["time"])
    moved = vtk_to_numpy(first_leaf(servermanager.Fetch(warp)).GetPoints().GetData())
    Delete(warp)
    error = abs(moved - points - scale * u).max()
    if moved.shape != points.shape or error > 1e-6 * size:
        raise CheckError(f"t = {step['time']}: Warp By Vector moved the points by "
                         f"scale × u ± {error:.2g}")


def render(reader, time, png, solid):
    """One off-screen picture at ``time``: the displacement warped, other series coloured.

    ``solid``: a 3D run (a perspective view; the displacement and the matrix fields of flow
    runs cut in half, 3D fractures coloured by their normal jump, or by ``p_f``).
    """
    view = GetActiveViewOrCreate("RenderView")
    view.ViewSize = [1200, 650]
    view.ViewTime = time
    view.OrientationAxesVisibility = 0
    source, field = reader, None
    arrays = reader.PointData.keys() + reader.CellData.keys()
    bounds = first_leaf(servermanager.Fetch(reader)).GetBounds()
    if "u" in reader.PointData.keys():
        magnitude = reader.PointData["u"].GetRange(-1)[1]
        size = max(bounds[1] - bounds[0], bounds[3] - bounds[2], bounds[5] - bounds[4])
        scale = 0.1 * size / magnitude if magnitude > 0 else 1.0
        source = WarpByVector(Input=reader, Vectors=["POINTS", "u"], ScaleFactor=scale)
        if solid:  # cut in half: the warped fractures inside show
            warp = source
            source = Clip(Input=warp, ClipType="Plane")
            source.ClipType.Origin = [0.5 * (bounds[2 * i] + bounds[2 * i + 1])
                                      for i in range(3)]
            source.ClipType.Normal = [0.0, 1.0, 0.0]
        field = ("POINTS", "u", "Magnitude")
    else:
        if solid and first_leaf(servermanager.Fetch(reader)).GetCellType(0) == 10:
            source = Clip(Input=reader, ClipType="Plane", Crinkleclip=1)  # the inside shows
            source.ClipType.Origin = [0.5 * (bounds[2 * i] + bounds[2 * i + 1])
                                      for i in range(3)]
            source.ClipType.Normal = [0.0, 1.0, 0.0]
        for name in (*(("jump_n",) if solid else ()), "state", "p_m", "p_f", *arrays):
            if name in arrays:
                kind = "CELLS" if name in reader.CellData.keys() else "POINTS"
                field = (kind, name)
                break
    display = Show(source, view)
    if field is not None:
        ColorBy(display, field)
        display.RescaleTransferFunctionToDataRange(True, False)
        display.SetScalarBarVisibility(view, True)
    GetDisplayProperties(source, view).LineWidth = 3.0
    if solid:
        view.InteractionMode = "3D"
        view.CameraPosition = [1.0, 2.5, 1.0]
        view.CameraFocalPoint = [0.0, 0.0, 0.0]
        view.CameraViewUp = [0.0, 0.0, 1.0]
    else:
        view.InteractionMode = "2D"
    ResetCamera(view)
    Render(view)
    png.parent.mkdir(parents=True, exist_ok=True)
    SaveScreenshot(str(png), view, ImageResolution=[1200, 650])
    Hide(source, view)
    while source is not reader:
        upstream = source.Input
        Delete(source)
        source = upstream


def check_file(reader_name, path, summary, png):
    """Check one series; returns (steps, arrays) or raises CheckError."""
    steps = read_index(path)
    if not steps:
        raise CheckError("the index lists no step")
    times = [s["time"] for s in steps]
    check_times(times, summary)
    for s in steps:
        for _, _, file, _ in s["attributes"].values():
            if not (path.parent / file).exists():
                raise CheckError(f"{file} listed but missing")
    reader = open_reader(reader_name, path)
    got = reader_times(reader)
    if not got and len(times) == 1:  # one step: no time information is needed
        got = times
    if len(got) != len(times) or not all(close(a, b) for a, b in zip(got, times, strict=True)):
        raise CheckError(f"reader time steps {got}, index {times}")
    for s in steps:
        check_step(reader, s, path.parent)
        if h5py is not None:
            check_ranges(reader, s, path.parent)
        if any(a[0] == "Node" and name == "u" for name, a in s["attributes"].items()):
            check_warp(reader, s)
    render(reader, times[-1], png, steps[-1]["solid"])
    Delete(reader)
    cells = f"{steps[-1]['cells']} {steps[-1]['topology'].lower()}"
    return len(steps), cells, sorted(steps[-1]["attributes"])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("outdirs", nargs="+", type=Path)
    parser.add_argument("--reader", choices=READERS, default="Xdmf3ReaderT")
    parser.add_argument("--png-dir", type=Path, help="pictures here (default OUTDIR/plots)")
    args = parser.parse_args()
    version = servermanager.vtkSMProxyManager.GetParaViewSourceVersion()
    print(f"{version}, reader {args.reader}, h5py {'yes' if h5py else 'no (values unchecked)'}")
    print("| run | file | steps | cells | arrays | result |\n|---|---|---|---|---|---|")
    failed = 0
    for outdir in args.outdirs:
        summary = json.loads((outdir / "summary.json").read_text())
        for path in sorted(outdir.glob("*.xdmf")):
            pngdir = args.png_dir or outdir / "plots"
            png = pngdir / f"paraview_{outdir.name}_{path.stem}.png"
            try:
                n, cells, arrays = check_file(args.reader, path, summary, png)
                result, info = "pass", (str(n), cells, ", ".join(arrays))
            except Exception as err:  # noqa: BLE001  (reported per file)
                failed += 1
                result, info = f"FAIL: {err}", ("", "", "")
                if not isinstance(err, CheckError):
                    traceback.print_exc()
            print(f"| {outdir.name} ({summary.get('status')}) | {path.name} | {info[0]} | "
                  f"{info[1]} | {info[2]} | {result} |", flush=True)
    view = GetActiveView()
    if view is not None:  # else pvpython's exit through sys.exit fails with GLXBadContext
        Delete(view)
    return failed


if __name__ == "__main__":
    sys.exit(main())
