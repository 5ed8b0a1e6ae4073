"""The README's 3D picture: Sneddon's penny-shaped crack (``configs/penny.yaml``) opened.

Runs the scene (a disc crack of radius 1 m under 1 MPa in a clamped 10 m box, P2 tetrahedra)
and draws from its output files, with pyvista (off-screen VTK):

* left, the cube of half-width 1.5 a around the crack, cut in half through it (the plane
  y = 0), displaced by ``scale · u`` on the duplicated-node mesh and coloured by ``|u|``: the
  crack's two faces part;
* right, the crack's triangles coloured by their opening ``-jump_n``, with the largest face
  value against Sneddon's opening at the centre in an infinite solid,
  ``w(0) = 8 (1 - ν²) p a / (π E)``.

Usage::

    .venv/bin/python scripts/penny_picture.py        # -> docs/images/penny/opening.png
    mpirun -n 2 .venv/bin/python scripts/penny_picture.py --run /tmp/penny   # run on 2 ranks
"""

import poromech  # noqa: F401, I001  (first: loads MPI before DOLFINx/PETSc)

import argparse
from pathlib import Path

import numpy as np
from mpi4py import MPI

from poromech.io.plot import limit_size, nice_scale, opening_picture
from poromech.io.results import open_results
from poromech.run import run_scene
from poromech.scene.loading import load_scene_and_raw

ROOT = Path(__file__).resolve().parents[1]
#: Picture size (pixels).
WINDOW = (1600, 700)
#: Colour bars: under each panel, the title below the labels.
BAR = {"color": "black", "vertical": False, "position_x": 0.2, "position_y": 0.03,
       "width": 0.6, "height": 0.07, "title_font_size": 16, "label_font_size": 14,
       "n_labels": 5}


def sneddon_centre(par: dict) -> float:
    """Sneddon's opening at the centre of a penny crack in an infinite solid (m)."""
    return 8 * (1 - par["nu"] ** 2) * par["p"] * par["a"] / (np.pi * par["E"])


def draw(outdir: Path, png: Path, scale: float | None, parameters: dict) -> Path:
    """The two panels from the outputs of a penny run (serial)."""
    import pyvista as pv

    res = open_results(outdir)
    disp, frac = res.series("displacement"), res.series("fractures")
    u = disp.fields(-1)["u"]
    size = float(np.ptp(disp.points, axis=0).max())
    scale = scale or nice_scale(disp.points, u, fraction=0.05)
    grid = pv.UnstructuredGrid({pv.CellType.TETRA: disp.cells}, disp.points)
    grid.point_data["|u| (mm)"] = 1e3 * np.linalg.norm(u, axis=1)
    grid.points = disp.points + scale * u
    box = 0.15 * size  # a cube of half-width 1.5 a around the crack, its half y < 0
    half = grid.clip_box((-box, box, -box, 0.0, -box, box), invert=False)

    pl = pv.Plotter(off_screen=True, window_size=WINDOW, shape=(1, 2), border=False)
    pl.set_background("white")
    pl.subplot(0, 0)
    pl.add_mesh(half, scalars="|u| (mm)", cmap="viridis", n_colors=64,
                scalar_bar_args={**BAR, "title": "displacement magnitude (mm)",
                                 "fmt": "%.2f"})
    pl.add_text(f"around the crack (a cube of half-width {box:g} m), cut at y = 0;\n"
                f"displacement ×{scale:g}", font_size=10, color="black")
    pl.view_vector((0.35, 1.0, 0.3), viewup=(0.0, 0.0, 1.0))
    pl.camera.zoom(1.05)

    pl.subplot(0, 1)
    pic = opening_picture(frac, len(frac.times) - 1)
    faces = pv.PolyData(pic.points, np.column_stack(
        [np.full(len(pic.triangles), 3), pic.triangles]).ravel())
    faces.cell_data[pic.label] = pic.values
    pl.add_mesh(faces, scalars=pic.label, cmap="magma", show_edges=True, edge_color="grey",
                line_width=0.5, scalar_bar_args={**BAR, "title": pic.label, "fmt": "%.3f"})
    exact = 1e3 * sneddon_centre(parameters)
    pl.add_text(f"crack opening -jump_n per face: largest {pic.values.max():.4f} mm\n"
                f"(Sneddon, infinite solid: {exact:.4f} mm at the centre)", font_size=10,
                color="black")
    pl.view_vector((0.3, -0.6, 1.0), viewup=(0.0, 0.0, 1.0))
    pl.camera.zoom(1.2)
    png.parent.mkdir(parents=True, exist_ok=True)
    pl.screenshot(str(png))
    pl.close()
    return limit_size(png)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=ROOT / "results" / "penny_picture")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "penny" /
                        "opening.png")
    parser.add_argument("--scale", type=float, help="displacement magnification (default: "
                        "the largest displacement drawn as ~5 %% of the box, rounded)")
    args = parser.parse_args()
    scene, raw = load_scene_and_raw(str(ROOT / "configs" / "penny.yaml"))
    run_scene(scene, args.run, raw=raw)
    if MPI.COMM_WORLD.rank == 0:
        png = draw(args.run, args.out, args.scale, scene.parameters)
        print(png.relative_to(ROOT) if png.is_relative_to(ROOT) else png,
              f"{png.stat().st_size // 1000} KB")


if __name__ == "__main__":
    main()
