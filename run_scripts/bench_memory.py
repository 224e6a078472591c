"""Peak memory of `psph run` against the estimate that `psph info` prints and `psph run` checks before
allocating (psph.simulation.estimate_resources; a scene estimated above 80% of the machine's memory is
refused without --allow-large).

    .venv/bin/python run_scripts/bench_memory.py [--ranks 1 2] [--cases static_mf tgv ...] [--dx 0.1 0.05]

Each case runs at two sizes, each in its own `psph run` (its own processes, so each peak is that run's
alone: summary.json's peak_memory_mib, the largest rank's resident-memory peak). The script prints, per
run, the measured peak and the estimate per rank and their ratio, and per case the measured growth per
particle between the two sizes against the estimate's bytes per particle. Target: every estimate at least
the measured peak (it guards the machine) and at most 1.5 times it. --dx gives every case the same two grid
spacings instead of its own (coarse ones make a smoke run, tests/test_run_scripts.py: their peaks are mostly
the interpreter's and the libraries', so the ratios then say little).
"""

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from psph.studies import parse_plain, positive_float, positive_int  # (numpy, not MPI: mpiexec's runs come first)

ROOT = Path(__file__).resolve().parent.parent
D3 = ["domain.dimension=3", "domain.lower=[0,0,0]", "domain.upper=[1,1,1]", "domain.periodic=[true,true,true]"]
STATIC = ["shifting.method=iips", "iips.max_newton=2"]
FLOW = ["time.t_end=0.002", "output.every=0", "iips.update=none", "shifting.method=none"]
# name: (scene, settings, the two dx)
CASES = {
    "static_mf": ("static_perturbed", STATIC + ["iips.operator=matrix_free"], (1 / 200, 1 / 400)),
    "static_aij": ("static_perturbed", STATIC + ["iips.operator=assembled"], (1 / 200, 1 / 400)),
    "static_3d_mf": ("static_perturbed", D3 + STATIC + ["iips.operator=matrix_free"], (1 / 32, 1 / 40)),
    "static_3d_aij": ("static_perturbed", D3 + STATIC + ["iips.operator=assembled"], (1 / 32, 1 / 40)),
    "tgv": ("taylor_green", FLOW, (1 / 200, 1 / 400)),
    "tgv_riemann": ("taylor_green", FLOW + ["physics.scheme=riemann_ale"], (1 / 200, 1 / 400)),
    "tgv_iips": ("taylor_green", FLOW[:2] + ["iips.update=mls2", "shifting.method=iips"], (1 / 200, 1 / 400)),
    # a 3-D delta-ALE flow (the fluid at rest in the periodic cube: the memory is the flow's whatever it does)
    "flow_3d": ("taylor_green", D3 + FLOW + ["initial.velocity=zero"], (1 / 32, 1 / 40)),
    # walls and bodies, each with its own shifting: IIPS + NFTS in the cavity and the moving square (Procedure
    # A, so that it runs within these few steps), delta+ in the dam break and the jet
    "cavity": ("lid_driven_cavity", FLOW[:2] + ["iips.procedure=A"], (0.01, 0.005)),
    "dam_break": ("dam_break", FLOW[:2], (0.05, 0.025)),
    "moving_square": ("moving_square", FLOW[:2] + ["iips.procedure=A"], (0.05, 0.025)),
    "impinging_jet": ("impinging_jet", FLOW[:2], (0.1, 0.05)),
}
TARGET = (1.0, 1.5)


def run(scene, sets, ranks, out):
    """summary.json of one `psph run` (its own processes)."""
    launcher = ["mpiexec", "-n", str(ranks), "--oversubscribe"] if ranks > 1 else []
    cmd = launcher + [str(ROOT / ".venv/bin/psph"), "run", str(ROOT / "cases" / f"{scene}.toml"), "--out", str(out),
                      "--overwrite", "--quiet"]
    for s in sets:
        cmd += ["--set", s]
    done = subprocess.run(cmd, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    if done.returncode != 0:
        sys.exit(f"bench_memory: {' '.join(cmd)} failed ({done.returncode}):\n{(done.stdout + done.stderr).strip()}")
    return json.loads((out / "summary.json").read_text())


def estimate(scene, sets, ranks):
    """(particles, bytes per rank, bytes per particle) of psph.simulation.estimate_resources."""
    from psph.scene.load import load_scene
    from psph.simulation import estimate_resources, iips_assembled

    sc = load_scene(ROOT / "cases" / f"{scene}.toml", sets)
    n, nbytes, per_particle = estimate_resources(sc, ranks, iips_assembled(sc))
    return n, nbytes / ranks, per_particle


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ranks", type=positive_int, nargs="+", default=[1])
    parser.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    parser.add_argument("--dx", type=positive_float, nargs=2, metavar=("DX0", "DX1"),
                        help="the two grid spacings of every case (default: each case's own)")
    args = parse_plain(parser)
    if args.dx and args.dx[0] == args.dx[1]:  # (the growth per particle divides by their counts' difference)
        parser.error(f"--dx: two different grid spacings, got {args.dx[0]:g} twice")
    if args.dx:
        from psph.scene.load import load_scene  # (no MPI: mpiexec's runs come first)

        for name in args.cases:
            scene, sets, _ = CASES[name]
            counts = [load_scene(ROOT / "cases" / f"{scene}.toml", [*sets, f"domain.dx={dx!r}"]).domain
                      .estimated_particles() for dx in args.dx]
            if counts[0] == counts[1]:
                parser.error(f"--dx {args.dx[0]!r} {args.dx[1]!r}: the same {counts[0]} particles (case {name}); "
                             "give two spacings whose lattices differ")
    mib = 2**20
    print(f"{'case':>14} {'ranks':>5} {'particles':>9} {'peak/rank MiB':>13} {'estimate MiB':>12} {'ratio':>6}   "
          f"growth per particle: measured / estimate [bytes]")
    runs = []  # every run first: the estimates import psph, whose MPI would then be the parent of mpiexec's
    with tempfile.TemporaryDirectory() as tmp:
        for ranks in args.ranks:
            for name in args.cases:
                scene, sets, sizes = CASES[name]
                for dx in args.dx or sizes:
                    settings = sets + [f"domain.dx={dx!r}"]
                    summary = run(scene, settings, ranks, Path(tmp) / name)
                    peak = summary["peak_memory_mib"] * mib
                    runs.append((name, ranks, scene, settings, summary["n_particles"], peak))
    misses = []
    for first, second in zip(runs[::2], runs[1::2]):
        name, ranks = first[:2]
        (n0, p0), (n1, p1) = first[4:], second[4:]
        if n0 == n1:  # (the estimate's lattice counted apart what the runs built alike)
            sys.exit(f"bench_memory.py: error: --dx: both runs of {name} had {n0} particles: no growth per particle")
        growth = (p1 - p0) / ((n1 - n0) / ranks)
        for i, (_, _, scene, settings, n, peak) in enumerate((first, second)):
            _, per_rank, per_particle = estimate(scene, settings, ranks)
            ratio = per_rank / peak
            if not TARGET[0] <= ratio <= TARGET[1]:
                misses.append(f"{name} on {ranks} rank(s), {n} particles: {ratio:.2f}")
            tail = f"   {growth:8.0f} / {per_particle:.0f}" if i == 1 else ""
            print(f"{name:>14} {ranks:>5} {n:>9} {peak / mib:>13.0f} {per_rank / mib:>12.0f} {ratio:>6.2f}{tail}")
    print(f"target: estimate / peak within {TARGET[0]}-{TARGET[1]}: " + ("met" if not misses else
                                                                        "missed by " + "; ".join(misses)))


if __name__ == "__main__":
    from psph.studies import run_study

    run_study(main)
