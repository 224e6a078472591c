"""The dam break's long-time evolution (seed 001 section 6.3, figs. 18-19): standard SPH against
delta-ALE-SPH at t sqrt(g/H) = 30, when the fluid has lost most of its kinetic energy and settles towards
the hydrostatic layer.

    .venv/bin/python run_scripts/dam_break_long.py [--resolutions 20] [--t-end 30] [--jobs 2]

Seed 001 finds the standard SPH's pressure "affected by a sort of spot-like spurious noise" (fig. 18), which
it traces to the particles' masses and volumes (fig. 19): in standard SPH the masses are advected
Lagrangianly, so the splash-ups mix particles of different masses, while the delta-ALE-SPH's diffusive terms
in the mass and density equations keep both fields smooth. Seed 001 runs H/dx = 400; this study runs
cases/dam_break.toml at the --resolutions given, each scheme on one rank, --jobs runs at a time:

- delta-ALE-SPH: the scene as it is (delta-plus shifting, D^rho and D^m with delta = delta_m = 0.1, none
  where lambda < 0.2);
- standard SPH: the same scene with no shifting (the particles move with the fluid) and no diffusive terms
  (physics.delta = physics.delta_m = 0, and so free_surface.lambda_diffusion = 0, which switches them),
  the weakly compressible SPH with artificial viscosity the paper compares against. Its masses are those
  of the hydrostatic start, rho_i dx^2, and never change. At H/dx = 20 it stops at t = 6.17, where the
  plunging wave closes an air cavity: a particle driven to 0.1 dx above the floor reaches |rho / rho0 - 1|
  = 0.58, past the scene's limit of 0.5 (with a limit of 0.9 it stopped at t = 6.19, at 0.97); at H/dx =
  40 it stops at t = 7.67, a particle's volume off by 51%. The table reports the stop;
- Lagrangian delta-SPH: standard SPH with the density diffusion D^rho (delta = 0.1) but still no shifting and
  no mass diffusion, so its masses are as Lagrangian as the standard SPH's: it shows what mixing makes of
  them at t_end.

Written in --out (results/dam_break_long): long.md/.csv, per run at t_end: the spread of the mass and
volume variations eps_m = m_i / m0 - 1 (m0 = rho0 dx^2, seed 001's reference, the mass of a particle at
the free surface) and eps_V = V_i / dx^2 - 1 over the fluid, and their "spot" noise
(psph.studies.spot_noise: the RMS over the fluid particles of a particle's departure from the plane
fitted to its own and its fluid neighbours' values within 2 dx; zero for a linear field, the spots' size
for a field of spots); the same noise of the pressure (in rho0 g H) and the pressure's departure from the
hydrostatic pressure of the flat layer; how many fluid particles are still above 1.5 times the layer's
depth (drops, films held on the walls and the roof) and the spot noises of eps_m and p without them, in
the layer; the kinetic energy left, the largest density variation of the
run's history rows (every 10th step), the wall reflections and the wall time. long.png: the pressure,
eps_V and eps_m near the left wall (x < 1.5 H), the finished runs side by side at the finest resolution
that has one, as in the paper's figures.
"""

import argparse
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from psph.particles import Kind
from psph.studies import (
    CASES,
    Run,
    RunStopped,
    command_line,
    last_snapshot,
    parse_args,
    positive_float,
    positive_int,
    run_scene,
    spot_noise,
    stop_message,
    write_table,
)

H, B, L = 1.0, 2.0, 5.367  # cases/dam_break.toml (rho0 = g = 1)
LAYER = B * H / L  # depth of the flat layer the column ends as
LAGRANGIAN = ["shifting.method=none", "physics.delta_m=0"]  # no shifting, no mass diffusion: constant masses
SCHEMES = {"delta-ALE-SPH": ([], "delta_ale"),
           "standard SPH": (LAGRANGIAN + ["physics.delta=0", "free_surface.lambda_diffusion=0"], "standard"),
           "Lagrangian delta-SPH": (LAGRANGIAN, "delta_sph")}
DETAIL = 1.5  # x / H shown in long.png (the paper's side panels: the flow close to the left wall)
ABOVE = 1.5 * LAYER  # fluid higher up at t_end has not come back to the layer (drops, films on the walls)
HEADER = ["scheme", "H/dx", "particles", "eps_m min", "eps_m max", "eps_m spot noise", "eps_V std", "eps_V spot noise",
          "p spot noise", "p - hydrostatic, RMS", "fluid above 1.5 x layer", "eps_m spot noise, layer",
          "p spot noise, layer", "kinetic energy", "max density variation", "wall reflections", "wall s"]


def fields(out, dx):
    """(positions, eps_m, eps_V, pressure, time) of the fluid in a run's last snapshot."""
    f, t = last_snapshot(out)
    fluid = f["kind"] == int(Kind.FLUID)
    m0 = dx * dx  # rho0 dx^2
    return (f["position"][fluid], f["mass"][fluid] / m0 - 1.0, f["volume"][fluid] / m0 - 1.0,
            f["pressure"][fluid], t)


def row(scheme, n, run):
    dx = H / n
    pos, eps_m, eps_v, p, _ = fields(run.out, dx)
    hydrostatic = np.clip(LAYER - pos[:, 1], 0.0, None)
    radius = 2.0 * dx
    layer = pos[:, 1] < ABOVE
    last = run.history[-1]
    return [scheme, n, run.summary["n_particles"], float(eps_m.min()), float(eps_m.max()),
            spot_noise(pos, eps_m, radius), float(eps_v.std()), spot_noise(pos, eps_v, radius),
            spot_noise(pos, p, radius), float(np.sqrt(np.mean((p - hydrostatic) ** 2))),
            int(np.count_nonzero(~layer)), spot_noise(pos[layer], eps_m[layer], radius),
            spot_noise(pos[layer], p[layer], radius), last["kinetic_energy"],
            max(r["max_density_variation"] for r in run.history), last["wall_reflections"],
            run.summary["wall_time_s"]]


def figure(path, runs, n):
    """Pressure, eps_V and eps_m near the left wall, one column per scheme (paper figs. 18-19)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    data = {scheme: fields(run.out, H / n) for (scheme, m), run in runs.items() if m == n}
    panels = [("p / (rho0 g H)", 3), ("eps_V", 2), ("eps_m", 1)]
    fig, axes = plt.subplots(len(panels), len(data), figsize=(5.5 * len(data), 2.3 * len(panels)), squeeze=False)
    fig.subplots_adjust(hspace=0.55)
    for r, (label, k) in enumerate(panels):
        for c, (scheme, values) in enumerate(data.items()):
            ax = axes[r, c]
            near = values[0][:, 0] < DETAIL
            shown = values[k][near]  # each panel its own scale: the schemes' masses differ by 20 times their spots
            art = ax.scatter(values[0][near, 0], values[0][near, 1], c=shown, s=9.0, cmap="viridis",
                             vmin=np.percentile(shown, 1), vmax=np.percentile(shown, 99))
            ax.set(xlim=(0.0, DETAIL), ylim=(0.0, 1.6 * LAYER), aspect="equal",
                   title=f"{scheme}, {label}, t sqrt(g/H) = {values[4]:.0f}")
            ax.tick_params(labelsize=7)
            ax.title.set_fontsize(8)
            fig.colorbar(art, ax=ax, shrink=0.8).ax.tick_params(labelsize=7)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("results/dam_break_long"))
    parser.add_argument("--t-end", type=positive_float, default=30.0, help="t sqrt(g/H) (seed 001: 30)")
    parser.add_argument("--resolutions", type=positive_int, nargs="+", default=[20], help="H/dx")
    parser.add_argument("--schemes", nargs="+", choices=list(SCHEMES), default=list(SCHEMES))
    parser.add_argument("--jobs", type=positive_int, default=2, help="runs at a time (one rank each)")
    args = parse_args(parser)
    cases = [(scheme, n) for n in args.resolutions for scheme in args.schemes]

    def run(case):
        """The run, or psph's message if psph stopped it with a diagnosis (any other failure is raised)."""
        scheme, n = case
        sets, tag = SCHEMES[scheme]
        out = args.out / f"{tag}_h{n}"
        try:
            return run_scene(CASES / "dam_break.toml", out, sets=[f"domain.dx={H / n}", f"time.t_end={args.t_end}",
                                                                  "output.every=1", "output.history_every=10"] + sets)
        except RunStopped as err:
            if not (out / "study_stopped.txt").exists():
                raise
            return stop_message(err)

    with ThreadPoolExecutor(args.jobs) as pool:
        runs = dict(zip(cases, pool.map(run, cases)))
    rows = [row(scheme, n, runs[scheme, n]) if isinstance(runs[scheme, n], Run) else
            [scheme, n, "stopped: " + runs[scheme, n].removeprefix("psph: error: ")]
            + ["-"] * (len(HEADER) - 3) for scheme, n in cases]
    finished = {case: run for case, run in runs.items() if isinstance(run, Run)}
    print(write_table(args.out / "long", HEADER, rows,
                      title=f"Dam break at t sqrt(g/H) = {args.t_end:g}: the masses, volumes and pressure of the "
                            "fluid (eps = value / (rho0 dx^2 or dx^2) - 1; spot noise: RMS of a particle's departure "
                            "from the plane fitted to its fluid neighbours within 2 dx; pressures in rho0 g H)",
                      note="Command: " + command_line()))
    shown = max((n for _, n in finished), default=None)
    if shown is not None:
        figure(args.out / "long.png", finished, shown)


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
