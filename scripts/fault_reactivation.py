"""A critically stressed fault reactivated by injection: when and where it slips.

    python scripts/fault_reactivation.py

Runs ``configs/fault_reactivation.yaml`` (in-situ stress, gravity, hydrostatic pressure; fluid
injected into the centre of a 60° normal fault at 2 km depth, then shut in) and compares the
slip the coupled solver finds with the Coulomb criterion applied to the initial tractions and
the computed fracture pressure alone,

    slip where  |T_τ⁰| ≥ F (|T_n⁰| − Δp_f),

which ignores the poroelastic stress change of the rock and the stress carried over from the
slipping faces. On each fault face it reports the overpressure Δp_f at which the face first slips
and the one this criterion predicts, and at every step the slipping length and the slip.

Writes docs/poromechanics/fault_reactivation.{csv,md,png}.
"""

from __future__ import annotations

import argparse
import datetime
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))

from poromechanics_study import markdown_table, write_csv  # noqa: E402

from poromech.io.results import open_results  # noqa: E402
from poromech.run import run_scene  # noqa: E402
from poromech.scene.loading import load_scene  # noqa: E402

DOCS = ROOT / "docs" / "poromechanics"
COMMAND = "python scripts/fault_reactivation.py"
SCENE = ROOT / "configs" / "fault_reactivation.yaml"
MPA = 1e6


def face_history(outdir: Path):
    """Per time and fault face: tractions, slip, state and fracture pressure, as 2D arrays."""
    res = open_results(outdir)
    times = np.array(sorted(set(res.fractures()["time"])))
    rows = [res.fractures(t) for t in times]
    order = np.argsort(rows[0]["s"])
    field = {k: np.array([r[k][order] for r in rows]) for k in
             ("traction_n", "traction_t", "jump_t", "p_f")}
    field["state"] = np.array([np.asarray(r["state"])[order] for r in rows])
    return times, rows[0]["s"][order], field


def analyse(scene, times, s, f):
    """Onset per face (computed vs pressure-only Coulomb) and the slipping patch per step."""
    fc = float(scene.contact.friction_coefficient)
    tn0, tt0, p0 = f["traction_n"][0], f["traction_t"][0], f["p_f"][0]
    dp = f["p_f"] - p0                                   # overpressure, per step and face
    critical = np.abs(tn0) - np.abs(tt0) / fc           # pressure-only Coulomb prediction
    slipping = f["state"] == "slip"
    predicted = dp >= critical[None, :]
    ds = np.gradient(s)                                  # face lengths (uniform faces)
    steps = []
    for i, t in enumerate(times):
        steps.append([t, dp[i].max() / MPA, float(ds[slipping[i]].sum()),
                      float(ds[predicted[i]].sum()),
                      float(np.abs(f["jump_t"][i]).max()) * 1e3])
    onset = []
    for j in range(len(s)):
        first = np.flatnonzero(slipping[:, j])
        if first.size:
            i = first[0]
            onset.append([s[j], times[i], dp[i, j] / MPA, critical[j] / MPA,
                          np.abs(tt0[j]) / (fc * np.abs(tn0[j]))])
    return steps, onset, critical


def main(argv: list[str] | None = None) -> None:
    # no options: --help says what the script runs and writes, and runs nothing
    argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                            formatter_class=argparse.RawDescriptionHelpFormatter).parse_args(argv)
    DOCS.mkdir(parents=True, exist_ok=True)
    scene = load_scene(SCENE, ["output.xdmf=false"])
    with tempfile.TemporaryDirectory() as tmp:
        summary = run_scene(scene, Path(tmp))
        times, s, f = face_history(Path(tmp))
    steps, onset, critical = analyse(scene, times, s, f)
    stamp = (f"Generated {datetime.date.today()} by `{COMMAND}` (1 MPI rank, "
             f"{summary['mesh']['cells']} cells, {len(s)} fault faces, "
             f"{summary['wall_time']['total']:.0f} s)")
    head_steps = ["time s", "max overpressure MPa", "slipping length m",
                  "predicted slipping length m", "max slip mm"]
    head_onset = ["s m", "first slip time s", "overpressure at first slip MPa",
                  "predicted overpressure MPa", "initial Coulomb ratio"]
    write_csv(DOCS / "fault_reactivation.csv", head_steps, steps, stamp)
    first = min(onset, key=lambda r: r[1]) if onset else None
    centre = int(np.argmin(np.abs(s - s.mean())))
    text = [f"# A fault reactivated by injection\n\n{stamp}.\n\n"
            "Predicted: the Coulomb criterion on the initial tractions and the computed fracture "
            "pressure alone, |T_τ⁰| ≥ F (|T_n⁰| − Δp_f). Computed: the coupled solve (contact "
            "state `slip`).\n\n"]
    if first is not None:
        text.append(f"First slip at t = {first[1]:g} s on the face at s = {first[0]:.1f} m, "
                    f"overpressure {first[2]:.2f} MPa there (predicted {first[3]:.2f} MPa); "
                    f"at the fault centre the predicted overpressure is "
                    f"{critical[centre] / MPA:.2f} MPa.\n\n")
    text += ["## The slipping patch, step by step\n\n", markdown_table(head_steps, steps),
             "\n## Onset, face by face (faces that slip)\n\n", markdown_table(head_onset, onset)]
    (DOCS / "fault_reactivation.md").write_text("".join(text))
    figure(times, s, f, critical, steps, float(scene.contact.friction_coefficient))


def figure(times, s, f, critical, steps, fc) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array(steps)
    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 3.8))
    a.plot(steps[:, 0] / 1e3, steps[:, 1], "k-", label="max overpressure Δp_f (MPa)")
    centre = int(np.argmin(np.abs(s - s.mean())))
    a.axhline(critical[centre] / MPA, color="k", ls=":", lw=0.8,
              label="pressure-only Coulomb limit at the centre (MPa)")
    a.set_xlabel("time (ks)")
    a.set_ylabel("MPa")
    a2 = a.twinx()
    a2.plot(steps[:, 0] / 1e3, steps[:, 2], "C3-", label="slipping length, computed")
    a2.plot(steps[:, 0] / 1e3, steps[:, 3], "C3--", label="slipping length, predicted")
    a2.set_ylabel("m", color="C3")
    lines = a.get_legend_handles_labels()
    lines2 = a2.get_legend_handles_labels()
    a.legend(lines[0] + lines2[0], lines[1] + lines2[1], fontsize=7, loc="center right")
    ratio = np.abs(f["traction_t"]) / (fc * np.abs(f["traction_n"]))
    peak = int(np.argmax(steps[:, 1]))
    for i, style in ((0, ":"), (peak // 2, "--"), (peak, "-"), (len(times) - 1, "-.")):
        b.plot(s, ratio[i], "k" + style, lw=1, label=f"t = {times[i] / 1e3:g} ks")
    b.set_xlabel("distance along the fault (m)")
    b.set_ylabel("|T_τ| / (F |T_n|)")
    b.set_ylim(0.5, 1.05)
    b.legend(fontsize=7, loc="lower center")
    fig.tight_layout()
    fig.savefig(DOCS / "fault_reactivation.png", dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
