"""The pictures of the README and docs/outputs.md, made by ``poromech plot``'s own code.

Runs the coupled six-fracture scene (``six_fractures``, Beaude et al. 2023 §3) up to T/4 = 500 s
with the paper's time step (100 s) and draws t = T/4 with the displacement magnified 20×::

    .venv/bin/python scripts/readme_picture.py     # -> docs/images/six_fractures/*.png
"""

import poromech  # noqa: F401, I001  (first: loads MPI before DOLFINx/PETSc)

import argparse
from pathlib import Path

from poromech.scene.loading import load_scene_and_raw
from poromech.io.plot import plot_run
from poromech.run import run_scene

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=ROOT / "results" / "readme_picture")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "images" / "six_fractures")
    args = parser.parse_args()
    scene, raw = load_scene_and_raw("six_fractures", ["time.final=500", "time.steps=5"])
    run_scene(scene, args.run, raw=raw)
    for path in plot_run(args.run, time=500.0, scale=20.0, out=args.out):
        print(path.relative_to(ROOT) if path.is_relative_to(ROOT) else path)


if __name__ == "__main__":
    main()
