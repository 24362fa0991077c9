"""Plots of one parefg run: PNGs in RUNDIR/plots/ made from RUNDIR/result.h5.

    python scripts/plots/plot_run.py RUNDIR

- displacement.png      deformed node cloud x + scale * u_h at a few output steps, coloured
                        by |u_h| (scale chosen so the largest displacement is 10 % of the body)
- contact_pressure.png  normal pressure along Gamma_C (against x) at every output time
- energy.png            the energy columns of /history and the balance
                        kinetic + elastic + penalty + dissipated - external work
- iterations.png        Newton (and linear) iterations per time step

A plot whose data the file lacks (no contact boundary, no displacement output) is skipped
with a note. Reads only result.h5 and, for the title, summary.json if present.
"""

import argparse
import json
import sys
from pathlib import Path

import h5py
import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the Agg backend)

SNAPSHOTS = 4
ENERGY_COLUMNS = (
    "kinetic_energy",
    "elastic_energy",
    "penalty_energy",
    "dissipated_energy",
    "external_work",
)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("rundir", type=Path, help="directory holding result.h5")
    args = parser.parse_args(argv)
    result = args.rundir / "result.h5"
    if not result.is_file():
        print(f"plot_run: {result} not found", file=sys.stderr)
        return 2
    plots = args.rundir / "plots"
    plots.mkdir(exist_ok=True)
    title = run_title(args.rundir)
    with h5py.File(result, "r") as f:
        for plot in (plot_displacement, plot_contact_pressure, plot_energy, plot_iterations):
            figure = plot(f)
            if figure is None:
                print(f"plot_run: {plot.__name__}: no data in {result}, skipped")
                continue
            figure.suptitle(title)
            path = plots / f"{plot.__name__.removeprefix('plot_')}.png"
            figure.savefig(path, dpi=120)
            plt.close(figure)
            print(f"plot_run: wrote {path}")
    return 0


def run_title(rundir: Path) -> str:
    """Scene name and rank count from summary.json, else the directory name."""
    summary = rundir / "summary.json"
    if not summary.is_file():
        return rundir.name
    data = json.loads(summary.read_text())
    return f"{data.get('scene', rundir.name)} ({data.get('mpi_ranks', '?')} ranks)"


def output_keys(f, group: str, name: str) -> list[str]:
    """Output indices "0000", "0001", ... stored for field ``name``, in order."""
    return sorted(f[group][name]) if name in f.get(group, {}) else []


def plot_displacement(f):
    """Deformed node cloud at up to SNAPSHOTS output steps, coloured by |u_h|."""
    keys = output_keys(f, "fields", "displacement")
    if not keys:
        return None
    coords = f["mesh/coordinates"][()]  # (n_nodes, 2)
    chosen = [keys[i] for i in np.unique(np.linspace(0, len(keys) - 1, SNAPSHOTS).astype(int))]
    # (n_chosen, n_nodes, 2) displacements of the chosen outputs
    displacements = np.stack([f[f"fields/displacement/{k}"][()] for k in chosen])
    magnitudes = np.linalg.norm(displacements, axis=2)  # (n_chosen, n_nodes)
    body_size = np.ptp(coords, axis=0).max()
    largest = magnitudes.max()
    scale = 0.1 * body_size / largest if largest > 0 else 1.0
    times = f["steps/time"][()]
    figure, axes = plt.subplots(
        1, len(chosen), figsize=(3.5 * len(chosen) + 1, 3.8), squeeze=False, layout="constrained"
    )
    for axis, key, u, size in zip(axes[0], chosen, displacements, magnitudes, strict=True):
        deformed = coords + scale * u
        points = axis.scatter(*deformed.T, c=size, s=6, vmin=0, vmax=largest, cmap="viridis")
        axis.set_title(f"t = {times[int(key)]:.4g}")
        axis.set_aspect("equal")
    figure.colorbar(points, ax=axes[0].tolist(), label=f"|u_h|  (shown x {scale:.3g})")
    return figure


def plot_contact_pressure(f):
    """Normal pressure along Gamma_C against x, one line per output time."""
    keys = output_keys(f, "contact_fields", "normal_pressure")
    if not keys:
        return None
    x = f["contact/coordinates"][:, 0]
    order = np.argsort(x)
    times = f["steps/time"][()]
    colours = plt.get_cmap("viridis")(np.linspace(0, 1, len(keys)))
    figure, axis = plt.subplots(figsize=(7, 4.5))
    for key, colour in zip(keys, colours, strict=True):
        pressure = f[f"contact_fields/normal_pressure/{key}"][()]
        axis.plot(x[order], pressure[order], color=colour, lw=1)
    mappable = plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(times[0], times[-1]))
    figure.colorbar(mappable, ax=axis, label="t")
    axis.set_xlabel("x on Gamma_C")
    axis.set_ylabel("normal pressure")
    return figure


def plot_energy(f):
    """Each energy column of /history against time, and the energy balance."""
    history = f.get("history", {})
    columns = [name for name in ENERGY_COLUMNS if name in history]
    if "time" not in history or not columns:
        return None
    time = history["time"][()]
    figure, axis = plt.subplots(figsize=(7, 4.5))
    balance = np.zeros_like(time)
    for name in columns:
        values = history[name][()]
        axis.plot(time, values, label=name)
        balance += -values if name == "external_work" else values
    axis.plot(time, balance, "k--", label="kinetic + elastic + penalty + dissipated - external")
    axis.set_xlabel("t")
    axis.set_ylabel("energy")
    axis.legend(fontsize="small")
    return figure


def plot_iterations(f):
    """Newton iterations per time step, linear iterations on a second axis."""
    history = f.get("history", {})
    if "newton_iterations" not in history:
        return None
    newton = history["newton_iterations"][()]
    steps = np.arange(1, newton.size + 1)
    figure, axis = plt.subplots(figsize=(7, 4.5))
    axis.step(steps, newton, where="mid", label="Newton")
    axis.set_xlabel("time step")
    axis.set_ylabel("Newton iterations")
    if "linear_iterations" in history:
        linear_axis = axis.twinx()
        linear_axis.plot(steps, history["linear_iterations"][()], "C1.", ms=3)
        linear_axis.set_ylabel("linear iterations", color="C1")
    return figure


if __name__ == "__main__":
    sys.exit(main())
