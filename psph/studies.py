"""Helpers for the studies in run_scripts/: run scenes through the command line, read what they wrote,
and write tables (Markdown and CSV) and convergence rates. Every figure a study reports comes from runs
it makes itself."""

import argparse
import csv
import functools
import hashlib
import json
import math
import os
import re
import shlex
import subprocess
import sys
import tempfile
import tomllib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from psph.cli import number, positive_float, positive_int  # noqa: F401 (the scripts' argparse types)
from psph.errors import NumericalError, PsphError, UsageError
from psph.io.history import read_history

ROOT = Path(__file__).resolve().parents[1]
CASES = ROOT / "cases"


@dataclass
class Run:
    out: Path
    summary: dict
    history: list


class NotRun(Exception):
    """run_scene(..., only_finished=True) found no finished run of its command."""


class RunStopped(RuntimeError):
    """psph stopped a run with a numerical diagnosis (exit code 3; its state and history are kept): a result
    of the study, which a sweep tables (stop_message gives its line)."""


class RunFailed(Exception):
    """psph refused a run (a bad scene, key or PETSc option: exit code 2) or it crashed: no result, and the
    study cannot go on. The message is one line (psph's error); the run's whole stderr is in
    OUT/study_failed.txt; returncode is psph's exit code."""

    def __init__(self, message, returncode=1):
        super().__init__(message)
        self.returncode = returncode


def run_study(main) -> None:
    """Run a study's main(): bad input (PsphError, a run psph refused: RunFailed with exit code 2), a
    diagnosed stop the study does not table (RunStopped, or a NumericalError of an in-process benchmark) and
    a run that crashed (RunFailed otherwise) end it with one line on stderr and exit code 2 (bad input), 3
    (a stop) or 1 (a crash, whose line names the file holding the run's whole stderr); the runs already
    made stay in their directories (PSPH_STUDY_REUSE=1 resumes). A main() that returns a number exits with
    it."""
    name = Path(sys.argv[0]).name
    try:
        code = main()
    except RunFailed as err:
        print(f"{name}: error: {err}", file=sys.stderr)
        sys.exit(2 if err.returncode == 2 else 1)
    except NumericalError as err:
        print(f"{name}: error: {err}", file=sys.stderr)
        sys.exit(NumericalError.exit_code)
    except PsphError as err:
        print(f"{name}: error: {err}", file=sys.stderr)
        sys.exit(2)
    except RunStopped as err:
        print(f"{name}: error: {stop_message(err)}", file=sys.stderr)
        sys.exit(NumericalError.exit_code)
    if code:
        sys.exit(code)


@functools.cache
def code_version() -> str:
    """A hash of psph's source (every psph/**/*.py): a study resumed on other code runs again."""
    digest = hashlib.sha256()
    for path in sorted((ROOT / "psph").rglob("*.py")):
        digest.update(str(path.relative_to(ROOT)).encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


# studies' runs that a table was made from although they are of other code (run_scene(only_finished=True))
_STALE_RUNS = []


# what the study's own command line adds to every run it makes (parse_args)
_EVERY_RUN = {"sets": [], "petsc": [], "allow_large": False}

# the study's --out (parse_args), and the runs run_scene(only_finished=True) found no finished run of
_STUDY = {"out": None, "not_run": []}

# keys a study sets on its runs that the study's own --set may change: how often a run writes its snapshots
# (the cadence changes no bit of a run, and the studies read the last snapshot only), not what it computes,
# what the study's tables label, or the history rows they read (a review: a dam break's time average of
# probe rows moved from 0.018 to 0.057 with output.history_every = 40)
WRITE_KEYS = ("output.every",)

# psph's rule for domain.h_over_dx (psph.scene.schema)
H_OVER_DX = (1.0, 4.0)


def smoothing_ratio(text: str) -> float:
    """argparse type: a smoothing length over particle spacing, a finite number within psph's H_OVER_DX."""
    value = number(text)
    if not H_OVER_DX[0] <= value <= H_OVER_DX[1]:  # (NaN fails it too)
        raise argparse.ArgumentTypeError(f"h/dx must be within {H_OVER_DX[0]:g} and {H_OVER_DX[1]:g} (as psph's "
                                         f"domain.h_over_dx), got {text}")
    return value


# the variables MPI launchers (Open MPI, MPICH / Hydra, PMIx) give each process its rank in
LAUNCHER_RANK_VARIABLES = ("OMPI_COMM_WORLD_RANK", "PMI_RANK", "PMIX_RANK")


def launcher_rank() -> int:
    """This process' rank under mpiexec (0 outside it, and under a launcher that sets none of
    LAUNCHER_RANK_VARIABLES, such as srun), from the launcher's environment: a script's arguments are checked
    before MPI is imported."""
    return next((int(os.environ[v]) for v in LAUNCHER_RANK_VARIABLES if os.environ.get(v, "").isdigit()), 0)


def one_line_errors(parser):
    """Make `parser` report a bad argument as one line, `PROG: error: MESSAGE`, and exit 2 (argparse prints
    its usage first). Under mpiexec every rank exits, rank 0 prints (the line was once per rank)."""
    def error(message):
        if launcher_rank() == 0:
            print(f"{parser.prog}: error: {message}", file=sys.stderr)
        sys.exit(2)

    parser.error = error
    return parser


def check_out(parser, path, option="--out") -> None:
    """Refuse (parser.error) an output directory that is a file or cannot be created, before any run: the
    nearest existing ancestor must be a directory in which one can be made (tried, and removed)."""
    if path is None:
        return
    path = Path(path)
    base = path
    while not base.exists() and base != base.parent:
        base = base.parent
    if not base.is_dir():
        what = "is a file" if base == path else f"lies in {base}, a file"
        parser.error(f"argument {option}: {path} {what}, not a directory")
    try:
        tempfile.TemporaryDirectory(dir=base).cleanup()
    except OSError as err:
        parser.error(f"argument {option}: cannot create {path if base != path else 'files in ' + str(path)}: "
                     f"{err.strerror or err}")


def check_args(parser, args) -> None:
    """The checks of every study's and benchmark's arguments, after parsing: --out (check_out) and no value
    given twice to an option of resolutions (a convergence rate between them divides by log 1)."""
    check_out(parser, getattr(args, "out", None))
    for name, values in vars(args).items():
        if name.endswith("resolutions") and isinstance(values, list):
            twice = [v for k, v in enumerate(values) if v in values[:k]]
            if twice:
                parser.error(f"argument --{name.replace('_', '-')}: {twice[0]:g} given twice")


def machine_memory() -> int:
    """This machine's memory in bytes (as psph.simulation.machine_memory, without importing MPI)."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")


def check_memory(parser, option, value, need, particles=None) -> None:
    """Refuse (parser.error, naming `option` and its `value`) what would need `need` bytes, more than 80% of
    this machine's memory: the limit psph run applies (psph.simulation.check_resources)."""
    if need > 0.8 * machine_memory():
        what = f"{particles:.4g} particles" if particles is not None else "it"
        parser.error(f"argument {option}: {value}: {what} would need about {need / 2**30:.3g} GiB, more than 80% "
                     f"of this machine's {machine_memory() / 2**30:.3g} GiB")


def check_scene_memory(parser, option, value, scene, ranks=1, assembled=False) -> None:
    """check_memory of a scene a benchmark builds itself (not through psph run, which checks it): psph's own
    estimate (psph.simulation.estimate_resources) on `ranks` ranks of this machine."""
    from psph.simulation import estimate_resources

    n, need, _ = estimate_resources(scene, ranks, assembled)
    check_memory(parser, option, value, need, n)


def parse_plain(parser, argv=None):
    """parser.parse_args(argv) with one-line errors (one_line_errors) and check_args: what a script that takes
    neither --set nor PETSc options for runs (a benchmark, a study of no runs) parses with."""
    one_line_errors(parser)
    args = parser.parse_args(argv)
    check_args(parser, args)
    return args


def parse_args(parser, argv=None):
    """The study's arguments by `parser`, plus what every study takes: `--set KEY=VALUE` (repeatable; as
    `args.set`), `--allow-large` and PETSc options (`-iips_pc_type hypre`, ...; as `args.petsc`). run_scene gives
    them to every run after the study's own overrides, as `psph run` takes them. A bad argument is one line
    (one_line_errors), and --out and the resolutions are checked (check_args)."""
    from psph.cli import split_petsc_options

    one_line_errors(parser)
    parser.add_argument("--set", action="append", default=[], metavar="KEY=VALUE",
                        help="a scene override for every run, after the study's own (as psph run --set); a key "
                             "the study sets itself to another value is refused (but output.every)")
    parser.add_argument("--allow-large", action="store_true",
                        help="run scenes psph estimates too large for this machine (as psph run --allow-large)")
    parser.add_argument("--overwrite", action="store_true",
                        help=f"run into an --out that holds another command's results ({STUDY_STAMP} names it): "
                             "its runs and tables are replaced as this study makes its own, the others are left; "
                             "the same command again needs no --overwrite")
    parser.epilog = "PETSc options (e.g. -iips_pc_type hypre) are passed to every run."
    ours, petsc = split_petsc_options(sys.argv[1:] if argv is None else list(argv))
    args = parser.parse_args(ours)
    args.petsc = petsc
    check_args(parser, args)
    claim_out(parser, args)
    _EVERY_RUN.update(sets=list(args.set), petsc=petsc, allow_large=args.allow_large)
    _STUDY.update(out=getattr(args, "out", None), not_run=[])
    return args


STUDY_STAMP = "study.json"  # in a study's --out: the script and the arguments whose results it holds
# arguments that change no result: --no-run and ellipse.py's --in-progress table the runs of the same
# arguments again, --rerun makes them again, dam_break_long.py's --jobs runs them side by side
UNSTAMPED_ARGUMENTS = ("out", "overwrite", "no_run", "allow_large", "in_progress", "rerun", "jobs")


def claim_out(parser, args) -> None:
    """Refuse (parser.error on --out) a study's --out that holds the results of another script, or of this
    one with other arguments, unless --overwrite: a second study into a default --out replaced the first one's runs and
    tables silently (a scripts audit). The stamp (STUDY_STAMP) is this study's from its first run or table
    on (stamp_out): a study refused before it wrote anything leaves none, and a stamp alone holds no
    results. A directory without a stamp (results made before stamps) is taken as it is."""
    _STUDY.pop("stamp", None)
    out = getattr(args, "out", None)
    if out is None:
        return
    stamp = Path(out) / STUDY_STAMP
    ours = {"script": Path(sys.argv[0]).name,
            "arguments": json.loads(json.dumps({k: v for k, v in sorted(vars(args).items())
                                                if k not in UNSTAMPED_ARGUMENTS}, default=str))}
    try:
        theirs = json.loads(stamp.read_text())
    except (OSError, ValueError):  # no stamp (or one cut short: not a study's)
        theirs = None
    results = Path(out).is_dir() and any(p.name != STUDY_STAMP for p in Path(out).iterdir())
    if theirs is not None and theirs != ours and results and not args.overwrite:
        old, new = theirs.get("arguments", {}), ours["arguments"]
        changed = [f"{k} {old.get(k, '-')} -> {new.get(k, '-')}" for k in sorted(set(old) | set(new))
                   if old.get(k) != new.get(k)]
        what = (f"other arguments ({'; '.join(changed)})" if theirs.get("script") == ours["script"]
                else str(theirs.get("script")))
        parser.error(f"argument --out: {out} holds the results of {what}; give --overwrite to replace them, or "
                     "another --out")
    _STUDY["stamp"] = (stamp, ours)


def stamp_out() -> None:
    """Write the stamp claim_out made of the study's --out (once; by rank 0 under mpiexec, whole or not at
    all): run_scene before the first run and write_table before the first table call it, and a study that
    runs psph in-process before its first run."""
    stamp, ours = _STUDY.pop("stamp", (None, None))
    if stamp is not None and launcher_rank() == 0:
        stamp.parent.mkdir(parents=True, exist_ok=True)
        part = stamp.with_name(f"{stamp.name}.{os.getpid()}.part")  # (several processes, a launcher unknown)
        part.write_text(json.dumps(ours, indent=1) + "\n")
        os.replace(part, stamp)


def _scene_value(text):
    """A --set value as psph reads it: a TOML literal, else a bare word (a string)."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text.strip()


def study_command(scene, out, sets=(), petsc=(), ranks=1, quiet=True, settable=()) -> list:
    """The command line of `psph run scene --out out --overwrite --set ... [PETSc options]` on `ranks` MPI
    ranks, the study's command line's --set, --allow-large and PETSc options (parse_args) after `sets` and
    `petsc`. A --set of the study's command line that gives a key of `sets` another value is refused
    (UsageError): the study labels its tables with its own values. Exempt are WRITE_KEYS and `settable`, the
    keys the study reads back from the scene the run had."""
    own = dict(s.split("=", 1) for s in sets if "=" in s)
    for s in _EVERY_RUN["sets"]:
        key, _, value = s.partition("=")
        key = key.strip()
        if key in own and key not in (*WRITE_KEYS, *settable) and _scene_value(value) != _scene_value(own[key]):
            raise UsageError(f"--set {s}: this study sets {key} on its runs itself ({key}={own[key]} in {out}), "
                             "and its tables say so; change it with the study's own options")
    cmd = [sys.executable, "-m", "psph", "run", str(scene), "--out", str(out), "--overwrite"]
    for s in [*sets, *_EVERY_RUN["sets"]]:
        cmd += ["--set", s]
    if quiet:
        cmd.append("--quiet")
    if _EVERY_RUN.get("allow_large"):
        cmd.append("--allow-large")
    cmd += [*petsc, *_EVERY_RUN["petsc"]]
    if ranks > 1:
        cmd = ["mpiexec", "-n", str(ranks), "--oversubscribe"] + cmd
    return cmd


def run_scene(scene, out, sets=(), petsc=(), ranks=1, quiet=True, reuse=None, only_finished=False,
              settable=()) -> Run:
    """`psph run scene --out out --set ... [PETSc options]` on `ranks` MPI ranks; raises on failure.

    With reuse (default: the PSPH_STUDY_REUSE environment variable is set), a directory holding a
    complete run of exactly this command (the same rank count, scene file contents and psph source) is
    read instead of run again (to resume or extend a study), and one that psph stopped with a numerical
    diagnosis (exit code 3) raises that diagnosis again. only_finished: reuse, and raise NotRun instead of
    running (a study's table from the runs it has); a run of other psph source is read then, and
    write_table says so in the table's note.
    Raises RunStopped for a diagnosed stop (exit code 3) and RunFailed for anything else.
    The study's command line's --set and PETSc options (parse_args) follow `sets` and `petsc`; a --set that
    changes a key of `sets` (but those in `settable`) is refused (study_command)."""
    cmd = study_command(scene, out, sets, petsc, ranks, quiet, settable)
    out = Path(out)
    stamp = out / "study_command.json"
    if only_finished:
        reuse = True
    elif reuse is None:
        reuse = bool(os.environ.get("PSPH_STUDY_REUSE"))
    stopped, summary, failed = out / "study_stopped.txt", out / "summary.json", out / "study_failed.txt"
    key = {"command": cmd[cmd.index("-m"):], "ranks": ranks, "scene_sha256": _file_hash(scene),
           "code": code_version(), "study": command_line()}
    old = json.loads(stamp.read_text()) if reuse and stamp.exists() else None
    if isinstance(old, list) and only_finished:  # a stamp of an older psph: its command only
        old = {"command": old, "ranks": ranks, "scene_sha256": key["scene_sha256"], "code": None}
    if old is not None and _same_command(old, key, code=not only_finished):
        if old.get("code") != key["code"] and (summary.exists() or stopped.exists()):
            _STALE_RUNS.append(f"{out} ({old.get('study') or 'an unrecorded command'})")
        if summary.exists():
            return Run(out, json.loads(summary.read_text()), read_history(out / "history.csv"))
        if stopped.exists():
            raise RunStopped(stopped.read_text())
    if only_finished:
        _STUDY["not_run"].append(out)
        raise NotRun(f"{out}: no finished run of this command")
    for path in (stamp, stopped, failed):  # a run killed half-way must not pass for the old complete one
        path.unlink(missing_ok=True)
    stamp_out()
    env = {k: v for k, v in os.environ.items() if not k.startswith(("OMPI_COMM", "PMIX"))}
    res = subprocess.run(cmd, capture_output=True, text=True, env=env)
    if res.returncode != 0:
        message = f"{' '.join(cmd)} failed:\n{res.stderr[-2000:]}"
        if res.returncode == NumericalError.exit_code and out.is_dir():  # a diagnosed stop is a result too
            stopped.write_text(message)
            stamp.write_text(json.dumps(key))
            raise RunStopped(message)
        line = f"{out}: {stop_message(message).removeprefix('psph: error: ')}"
        if out.is_dir():
            failed.write_text(message)
        if res.returncode != 2:  # a crash: its cause is in the traceback, which the line points to
            cause = next((t.strip() for t in reversed(res.stderr.splitlines())
                          if re.match(r"\s*[\w.]*(Error|Exception)\b.*:", t)), "")
            line += (f" ({cause})" if cause and cause not in line else "") + \
                (f"; its stderr is in {failed}" if out.is_dir() else "")
        raise RunFailed(line, res.returncode)
    stamp.write_text(json.dumps(key))
    return Run(out, json.loads(summary.read_text()), read_history(out / "history.csv"))


def _file_hash(path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:16] if Path(path).is_file() else ""


def stop_message(err) -> str:
    """The one-line reason of a run_scene failure: psph's `psph: error: ...` line (mpiexec adds its own
    banner after it), else the last line."""
    lines = [line for line in str(err).splitlines() if line.strip()]
    return next((line for line in lines if line.startswith("psph: error:")), lines[-1] if lines else "")


def _same_command(a, b, code=True) -> bool:
    """Two study stamps (run_scene) are the same run if their commands differ at most in where the scene
    file lies (a study resumed from another checkout of psph) and in how the output directory is spelled
    (the stamp lies in that directory, so it names it already), on the same rank count, with the same scene
    file contents and (code) psph source. A stamp of an older psph (a bare command) matches nothing here;
    run_scene(only_finished=True) reads it by its command, as a run of other source."""
    def key(cmd):
        cmd = [c for k, c in enumerate(cmd) if k == 0 or cmd[k - 1] != "--out"]
        return [Path(c).name if c.endswith(".toml") else c for c in cmd]
    if not isinstance(a, dict):
        return False
    same = [key(a["command"]) == key(b["command"])] + [a.get(k) == b[k] for k in ("ranks", "scene_sha256")]
    return all(same) and (not code or a.get("code") == b["code"])


# the lid-driven cavity scene, and the overrides of each wall model: clone particles with IIPS + NFTS (the
# scene's), or seed 001's setting (section 6.2): the fixed ghost particles of a straight wall
# (bodies[0].model = "ghost") with delta+ shifting (IIPS needs clone walls)
# the fluid schemes the wall studies compare, as --set overrides (riemann_low: the Riemann scheme with Zhang et
# al.'s low-dissipation pressure; README, "Walls in the Riemann scheme")
SCHEME_SETS = {"delta_ale": [], "riemann_ale": ["physics.scheme=riemann_ale"],
               "riemann_low": ["physics.scheme=riemann_ale", "physics.riemann_dissipation=low"]}
CAVITY = CASES / "lid_driven_cavity.toml"
CAVITY_DELTA_PLUS = ["shifting.method=delta_plus", "iips.update=none"]
CAVITY_WALLS = {"clone": [], "ghost": ["bodies.0.model=ghost", *CAVITY_DELTA_PLUS]}


def shifting_label(scene) -> str:
    """The shifting of a fluid scene as a table cell: "delta_plus", or "iips + nfts" with IIPS's update."""
    method = scene.shifting.method
    return f"{method} + {scene.iips.update}" if method == "iips" and scene.iips.update != "none" else method


def rate(e_coarse, e_fine, ratio=2.0) -> float:
    """Observed convergence order between two resolutions `ratio` apart."""
    if e_coarse and e_fine and e_coarse > 0 and e_fine > 0:
        return math.log(e_coarse / e_fine) / math.log(ratio)
    return float("nan")


def at_time(history, t, column):
    """`column` of the history row closest to time t."""
    return min(history, key=lambda r: abs(r["time"] - t))[column]


def pareto(points):
    """Indices of the (time, error) points no other point beats in both."""
    return [i for i, (t, e) in enumerate(points)
            if not any(t2 <= t and e2 <= e and (t2, e2) != (t, e) for t2, e2 in points)]


def tag(label) -> str:
    """A method's table label as a directory name part: "IIPS + MLS-II" -> "IIPS_MLS-II"."""
    return label.replace(" ", "").replace("+", "_").replace("=", "")


def after(rows, key, t0, t1=np.inf):
    """The values of a history column (cl: pressure + viscous) over t0 <= t <= t1."""
    rows = [r for r in rows if t0 <= r["time"] <= t1]
    if key == "cl":
        return np.array([r["cl_pressure"] + r["cl_viscous"] for r in rows])
    return np.array([r[key] for r in rows])


def mean_after(rows, key, t0, t1=np.inf):
    """The mean of after(...), nan without rows."""
    values = after(rows, key, t0, t1)
    return float(values.mean()) if values.size else float("nan")


def in_progress(scene_path, out, sets, compare=(("domain", "dx"), ("time", "t_end"))):
    """A Run of the scene at `scene_path` with `sets`, read from a directory whose run the study did not finish
    (or that was resumed by hand with `psph run --restart`, stopped, or run by hand): its history so far, the
    scene of its command, the particle count of its latest checkpoint, and its summary once it has one
    (without one, a run psph stopped has its log's last line, the stop, as the summary's "stopped").
    Refuses (SystemExit, one line) a directory without a summary or a checkpoint, and a run whose scene
    differs in a key of `compare` ((section, key), or (section,) for a whole section, such as the bodies)."""
    import h5py

    from psph.scene.load import load_scene
    from psph.scene.validate import to_table

    scene = to_table(load_scene(scene_path, sets))
    out = Path(out)
    checkpoints = sorted(out.glob("checkpoint_*.h5"))
    summary_path = out / "summary.json"
    if not (out / "history.csv").exists() or not (checkpoints or summary_path.exists()):
        raise SystemExit(f"{out}: no run in progress (no checkpoint or summary, and history)")
    if summary_path.exists():  # finished (a hand restart, or a run by hand, writes no study stamp)
        summary = json.loads(summary_path.read_text())
        saved = summary["scene"]
    else:
        with h5py.File(checkpoints[-1]) as f:
            summary = {"scene": scene, "n_particles": len(f["particles/gid"])}
            saved = json.loads(bytes(f["state"][()]).decode())["scene"]
        log = (out / "psph.log").read_text().strip().splitlines() if (out / "psph.log").exists() else []
        if log and log[-1].startswith("psph: error:"):  # a diagnosed stop: its message, as run_scene's RunStopped
            summary["stopped"] = log[-1]
    for path in compare:
        mine, theirs = scene, saved
        for key in path:
            mine, theirs = mine.get(key), theirs.get(key)
        if json.dumps(mine, sort_keys=True) != json.dumps(theirs, sort_keys=True):  # (tuples as lists)
            name = ".".join(path)
            raise SystemExit(f"{out}: its run has {name} = {theirs}, the study {mine}" if len(path) > 1 else
                             f"{out}: its run's {name} differ from the study's")
    return Run(out, summary, read_history(out / "history.csv"))


def long_run(scene, out, sets, ranks=1, in_progress_ok=False, rerun=False, compare=(("domain", "dx"),
                                                                                     ("time", "t_end"))):
    """A study's run that takes hours (ellipse.py, triangle.py): a finished run of this very command in `out`
    is read back, never run again (unless `rerun`); with `in_progress_ok` (the study's --in-progress) a run
    still going, stopped, resumed or run by hand is tabled from what it has written (in_progress, checking the
    keys `compare`); any other run there stops the study (SystemExit) rather than being run over; an empty
    `out` is run."""
    try:
        return run_scene(scene, out, sets=sets, ranks=ranks, only_finished=not rerun)
    except NotRun:
        out = Path(out)
        if in_progress_ok:
            return in_progress(scene, out, sets, compare)
        if any(out.glob("checkpoint_*.h5")) or (out / "history.csv").exists():
            raise SystemExit(f"{out} holds a run that is not a finished run of this study's command (one in "
                             "progress, resumed or run by hand): tabulate it with --in-progress, or replace it "
                             "with --rerun") from None
        return run_scene(scene, out, sets=sets, ranks=ranks, reuse=False)


def dominant_frequency(times, values, t0=0.0, oversample=64, periods=3) -> float:
    """Frequency of the largest peak in the periodogram of values(t) over t >= t0 (history rows need not be
    evenly spaced: they are interpolated onto an even grid of the same number of samples). The window is
    zero-padded `oversample` times and detrended linearly, so a steady oscillation over a few periods is
    located to a small fraction of 1/(window length); nan with fewer than 8 samples, no oscillation, or
    fewer than `periods` periods of the peak's frequency in the window (a transient is no frequency)."""
    from scipy.signal import periodogram

    t, v = np.asarray(times, dtype=float), np.asarray(values, dtype=float)
    keep = t >= t0
    t, v = t[keep], v[keep]
    if t.size < 8 or t[-1] <= t[0] or np.ptp(v) <= 1e-12 * np.abs(v).max():
        return float("nan")
    grid = np.linspace(t[0], t[-1], t.size)
    step = grid[1] - grid[0]
    freq, power = periodogram(np.interp(grid, t, v), fs=1.0 / step, detrend="linear",
                              nfft=oversample * t.size, window="hann")
    peak = float(freq[1 + np.argmax(power[1:])])
    return peak if peak * (t[-1] - t[0]) >= periods else float("nan")


def fmt(value, spec=".3g") -> str:
    """A table cell: "-" for a value not measured (None), "nan" for a NaN."""
    if value is None:
        return "-"
    if isinstance(value, str):
        return value
    if isinstance(value, int) and not isinstance(value, bool):
        return str(value)
    return format(value, spec)


def command_line() -> str:
    """The study's own command line as typed (script and arguments), for a table's note: the run that made a
    table is reproduced by copying it."""
    return " ".join(["run_scripts/" + Path(sys.argv[0]).name, *map(shlex.quote, sys.argv[1:])])


class NothingMeasured(UsageError):
    """write_table was given a table without a measured row: it writes nothing (exit code 2)."""


def unmeasured(value) -> bool:
    """A table cell that holds no measurement: None (fmt's "-"), "-" or empty."""
    return value is None or (isinstance(value, str) and value.strip() in ("", "-"))


def write_table(path, header, rows, title="", note="", labels=1) -> str:
    """Write a Markdown table (path.md) and the same data as CSV (path.csv); returns the Markdown. The note
    ends with the study's command line (unless it gives one) and names the runs read back that other psph
    source made (run_scene(only_finished=True)).

    A table without a measured row (no rows, or in every row each cell past its first `labels` columns
    unmeasured) is refused (NothingMeasured, one line) and the files already there are left as they are: a
    study whose runs all failed, or found none (--no-run), replaces no table with an empty one."""
    path = Path(path)
    if not rows or (len(header) > labels and all(all(map(unmeasured, row[labels:])) for row in rows)):
        where = _STUDY["out"] or path.parent
        why = (f"found no finished run in --out {where} (--no-run)" if _STUDY["not_run"]
               else "no row of it was measured")
        raise NothingMeasured(f"{path.with_suffix('.md')} not written: {why}; the files there are kept")
    stamp_out()
    path.parent.mkdir(parents=True, exist_ok=True)
    lines = [f"### {title}", ""] if title else []
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(fmt(v).replace("|", "\\|") for v in row) + " |" for row in rows]
    if "Command: " not in note:
        note = (note.rstrip() + ("" if not note or note.rstrip().endswith(".") else ".") + " " if note else "") \
            + "Command: " + command_line()
    if _STALE_RUNS:
        note += " Read back from runs of other psph source: " + "; ".join(sorted(set(_STALE_RUNS))) + "."
    if note:
        lines += ["", note]
    text = "\n".join(lines) + "\n"
    path.with_suffix(".md").write_text(text)
    with open(path.with_suffix(".csv"), "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(header)
        writer.writerows(rows)
    return text


def plot_histories(path, curves, xlabel, ylabel, title, logy=False, size=(7, 4)):
    """One figure of time histories: curves = [(t, values, label, matplotlib line keywords), ...]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=size)
    for t, values, label, style in curves:
        (ax.semilogy if logy else ax.plot)(t, values, label=label, **style)
    ax.set(xlabel=xlabel, ylabel=ylabel, title=title)
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_histories(path, labels, runs, columns) -> None:
    """The plotted time histories as data: a CSV of the label columns `labels` (each run's labels), then
    time and `columns`, one line per history row of each run. runs = [(label values, Run), ...]."""
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow([*labels, "time", *columns])
        for label, run in runs:
            writer.writerows([*label, r["time"], *(r[c] for c in columns)] for r in run.history)


# nine points inside the dam break's column (H = 1, B = 2: cases/dam_break.toml) where the release's pressure
# is compared with the incompressible one, as `output.probes`
DAM_BREAK_INSIDE = np.array([[x, y] for y in (0.25, 0.5, 0.75) for x in (0.5, 1.0, 1.5)])
DAM_BREAK_PROBES = "output.probes=[" + ",".join(f"[{x:g},{y:g}]" for x, y in DAM_BREAK_INSIDE) + "]"


def release_pressure_errors(out) -> tuple:
    """(error, start, swing): at the DAM_BREAK_INSIDE probes of a run of cases/dam_break.toml in `out`, its pressure
    averaged over the run (trapezoidal in time) less the incompressible initial pressure
    (analytic.dam_break_initial), the same for the hydrostatic start, and the pressure's range over the run
    after its first tenth (the sound of the release), in rho0 g H (H = rho0 = g = 1, B = 2)."""
    from scipy.integrate import trapezoid

    from psph.analytic import dam_break_initial

    H, B = 1.0, 2.0

    rows = read_history(Path(out) / "probes.csv")
    t = np.array([r["time"] for r in rows])
    p = np.array([[r[f"p_{k}"] for k in range(len(DAM_BREAK_INSIDE))] for r in rows])
    mean = trapezoid(p, t, axis=0) / (t[-1] - t[0])
    exact, _ = dam_break_initial(DAM_BREAK_INSIDE, H=H, B=B)
    swing = np.ptp(p[t > t[0] + 0.1 * (t[-1] - t[0])], axis=0)
    return mean - exact, H - DAM_BREAK_INSIDE[:, 1] - exact, swing


def first_iteration(history, predicate):
    """(row) of the first history row satisfying predicate, or None."""
    for row in history:
        if predicate(row):
            return row
    return None


def last_snapshot(out, index=-1) -> tuple:
    """(fields by name, time) of the last snapshot a run wrote in `out` (index -2: the one before it)."""
    from psph.io.snapshots import h5py, snapshot_files

    path = snapshot_files(out)[index]
    with h5py.File(path) as f:
        return {k: f["particles"][k][:] for k in f["particles"]}, float(f.attrs["time"])


def spot_noise(pos, values, radius) -> float:
    """RMS over the particles of each one's departure from the plane fitted, by least squares, to its own and
    its neighbours' values within `radius` (the particles with fewer than d + 2 of them are left out): the
    noise of a field made of spots, zero for any linear field (a hydrostatic pressure, also at a surface,
    where a neighbours' mean would be biased). The particle's own value takes part in its fit, so uncorrelated
    spots of RMS s measure a little less than s (0.88 s on a lattice, radius 2.1 spacings). pos: (n, d);
    values: (n,)."""
    from scipy.spatial import cKDTree

    d = pos.shape[1]
    residuals = []
    for i, near in enumerate(cKDTree(pos).query_ball_point(pos, radius)):
        if len(near) < d + 2:
            continue
        design = np.hstack([np.ones((len(near), 1)), pos[near] - pos[i]])
        coef = np.linalg.lstsq(design, values[near], rcond=None)[0]
        residuals.append(values[i] - coef[0])
    return float(np.sqrt(np.mean(np.square(residuals)))) if residuals else float("nan")


def shepard_sample(pos, vol, values, points, kernel):
    """Kernel (Shepard) interpolation sum_j W_j V_j f_j / sum_j W_j V_j of particle `values` at `points`
    (probes, e.g. a centreline), from the particles within the kernel support."""
    from psph.diagnostics import shepard_sums

    num, den = shepard_sums(kernel, pos, values, vol, points)
    with np.errstate(invalid="ignore", divide="ignore"):  # nan where no particle reaches
        return num / den.reshape((-1,) + (1,) * (num.ndim - 1))


def unit_box_kernel(n, h_over_dx):
    """The Wendland C6 kernel of n particles of the bi-periodic unit box at h = h_over_dx / sqrt(n), refused
    (UsageError) where psph refuses a periodic axis: a support not smaller than the box (the 3 x 3 tiling
    then misses neighbours and counts images of a particle's own), or h/dx outside psph's H_OVER_DX."""
    from psph.compute.smoothing import make_kernel

    dx = 1.0 / math.sqrt(n) if n > 0 else math.inf
    if not H_OVER_DX[0] <= h_over_dx <= H_OVER_DX[1]:
        raise UsageError(f"h/dx = {h_over_dx:g}: must be within {H_OVER_DX[0]:g} and {H_OVER_DX[1]:g} (as psph's "
                         "domain.h_over_dx)")
    kern = make_kernel("wendland_c6", 2, h_over_dx * dx) if n > 0 else None
    if kern is None or kern.support >= 1.0:
        support = f"{kern.support:g}" if kern is not None else "inf"
        raise UsageError(f"h/dx = {h_over_dx:g} on {n} particles (dx = {dx:g}): the kernel support {support} is not "
                         "smaller than the periodic unit box; use more particles or a smaller h/dx")
    return kern


def unit_box_bytes(n, h_over_dx) -> float:
    """A rough upper estimate of the memory tgv_operator_errors takes on n particles at h_over_dx: the 3 x 3
    tiling's fields (9 copies of about 80 bytes) and, per particle, a neighbour list entry and the pair cache's
    values (80 bytes) for each neighbour within the support (2 h_over_dx spacings)."""
    return n * (9 * 80 + 80 * math.pi * (2.0 * h_over_dx) ** 2)


def _tiled_unit_box(pos, vol, h_over_dx):
    """A 2-D distribution of the bi-periodic unit box and its 3 x 3 tiling (the box itself first), Wendland
    C6 with h = h_over_dx / sqrt(n): (positions, volumes, kernel, ptr, idx), the neighbour lists of the n
    particles of the box (unit_box_kernel refuses a support not smaller than the box)."""

    from psph.compute.neighbours import build_neighbour_lists

    n = len(pos)
    kern = unit_box_kernel(n, h_over_dx)
    tiles = np.array([(a, b) for a in (0, -1, 1) for b in (0, -1, 1)], float)
    all_pos = np.ascontiguousarray((np.mod(pos, 1.0)[None, :, :] + tiles[:, None, :]).reshape(-1, 2))
    all_vol = np.ascontiguousarray(np.tile(vol, len(tiles)))
    ptr, idx = build_neighbour_lists(all_pos, n, kern.support)
    return all_pos, all_vol, kern, ptr, idx


def _lu_solve(matrix, rhs):
    """Solve a scipy CSR system on one process with PETSc's LU (scipy's SuperLU is minutes slower here), a
    LinearSolver of prefix `study_lu_` (its result checked; nested dissection unless -study_lu_ options say
    otherwise)."""
    from mpi4py import MPI

    from psph.solvers.linear import LinearSolver
    from psph.solvers.petsc import petsc

    PETSc = petsc()
    options = PETSc.Options()
    if not options.hasName("study_lu_pc_factor_mat_ordering_type"):
        options.setValue("study_lu_pc_factor_mat_ordering_type", "nd")
    a = PETSc.Mat().createAIJ(matrix.shape, csr=(matrix.indptr, matrix.indices, matrix.data), comm=PETSc.COMM_SELF)
    solver = LinearSolver(MPI.COMM_SELF, "study_lu_", ksp_type="preonly", pc_type="lu")
    b, x = a.createVecs()
    try:
        solver.set_operator(a)
        b.setArray(rhs)
        solver.solve(b, x)
        return x.getArray().copy()
    finally:
        for obj in (solver, a, b, x):
            obj.destroy()


def iips_pair_defects(pos, vol, h_over_dx, newton=3) -> dict:
    """Where IIPS's printed operator (thesis eq. 8.32, psph.compute.iips) stops being a Newton operator, on a
    2-D distribution of the bi-periodic unit box (e.g. a Taylor-Green run's particles), Wendland C6:

      min_spacing      smallest distance between two particles over dx = 1 / sqrt(n);
      hess_c_ratio     |Hess C_i| / |omega_i HessW(0)| per particle (2-norm): the printed operator differs
                       from the exact Jacobian by Hess C_i on its diagonal (seeds/README.md), and Hess C_i is
                       the sum of the operator's blocks in row i;
      linf             h max|grad C| before and after each of `newton` iterations with the printed operator,
                       solved exactly (PETSc's sparse LU, nested-dissection order), not by BCGS;
      max_step         largest displacement of each iteration over dx.

    Returns those, with hess_c_ratio and the nearest-neighbour distance per particle (for correlations)."""
    import scipy.sparse as sp

    from psph.compute import iips, sums

    n = len(pos)
    dx = 1.0 / math.sqrt(n)
    row = np.tile(np.arange(n, dtype=np.int64), 9)  # images carry their particle's number

    def state(p):
        all_pos, all_vol, kern, ptr, idx = _tiled_unit_box(p, vol, h_over_dx)
        grad = np.zeros((n, 2))
        sums.grad_concentration(all_pos, all_vol, ptr, idx, kern.params, grad)
        indptr, indices, slot = iips.iips_structure(row, ptr, idx, 2)
        data = np.zeros(len(indices))
        iips.iips_values(all_pos, all_vol, row, ptr, idx, kern.params, slot, data, np.zeros(0))
        matrix = sp.csr_matrix((data, indices, indptr), shape=(2 * n, 2 * n))
        return all_pos, kern, ptr, idx, grad, matrix

    all_pos, kern, ptr, idx, grad, matrix = state(pos)
    nearest = np.zeros(n)
    group = np.zeros(len(all_pos), np.int8)
    sums.nearest_distance(all_pos, ptr, idx, group, group, nearest)
    hess_c = np.stack([matrix @ np.tile(e, n) for e in np.eye(2)], axis=-1).reshape(n, 2, 2)
    self_term = np.abs(vol * kern.radial(np.zeros(1))[0])
    ratio = np.linalg.norm(hess_c, ord=2, axis=(1, 2)) / self_term
    linf, max_step, p = [kern.h * float(np.sqrt((grad * grad).sum(axis=1)).max())], [], np.array(pos, float)
    for _ in range(newton):
        step = _lu_solve(matrix, grad.ravel()).reshape(n, 2)
        p = p + step
        max_step.append(float(np.sqrt((step * step).sum(axis=1)).max()) / dx)
        _, _, _, _, grad, matrix = state(p)
        linf.append(kern.h * float(np.sqrt((grad * grad).sum(axis=1)).max()))
    return {"min_spacing": float(nearest.min()) / dx, "hess_c_ratio": ratio, "nearest": nearest / dx,
            "linf": linf, "max_step": max_step}


def viscous_operator_on_lattice(n, dim, h_over_dx, morris, sigma, rng, kernel="wendland_c6", stretch=1.0):
    """The viscous operator (per unit nu; pi_ij of seed 001 eq. 11, or Morris' with `morris`) of psph's sums on
    a periodic lattice of spacing dx = 1/16, n^dim particles (in 2-D with `stretch` a: spacing a dx along x and
    dx / a along y, n / a by n a particles), perturbed by sigma dx (Gaussian, from `rng`), as a dense matrix,
    with dx, the kernel and the largest diagonal weight (sums.largest_kernel_factor_sum): what
    psph.schemes.viscous_limit's estimate is checked against (tests/schemes/test_viscous_limit.py,
    run_scripts/viscous_limit_check.py)."""
    from psph.compute import sums
    from psph.compute.neighbours import build_neighbour_lists
    from psph.compute.smoothing import make_kernel

    dx = 1.0 / 16
    spacing = np.array([stretch, 1.0 / stretch] if dim == 2 else [1.0] * dim) * dx
    counts = np.array([max(4, round(n / stretch)), max(4, round(n * stretch))] if dim == 2 else [n] * dim)
    box = counts * spacing
    axes = [np.arange(c) * s for c, s in zip(counts, spacing)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, dim)
    grid = (grid + sigma * dx * rng.standard_normal(grid.shape)) % box
    kern = make_kernel(kernel, dim, h_over_dx * dx)
    shifts = np.stack(np.meshgrid(*[[-1.0, 0.0, 1.0]] * dim, indexing="ij"), axis=-1).reshape(-1, dim)
    shifts = shifts[np.argsort(np.abs(shifts).sum(axis=1), kind="stable")] * box  # the unshifted copy first
    pos = np.ascontiguousarray(np.concatenate([grid + s for s in shifts]))
    m = len(grid)
    ptr, idx = build_neighbour_lists(pos, m, kern.support)
    vol = np.full(len(pos), dx ** dim)
    matrix = np.zeros((m * dim, m * dim))
    for column in range(m * dim):
        u = np.zeros((m, dim))
        u.flat[column] = 1.0
        images = np.tile(u, (len(shifts), 1))
        out = np.zeros((m, dim))
        if morris:
            for a in range(dim):
                sums.laplacian_morris(pos, vol, ptr, idx, kern.params, np.ascontiguousarray(images[:, a]), out[:, a])
        else:
            sums.viscous_pi(pos, vol, ptr, idx, kern.params, images, out)
        matrix[:, column] = out.ravel()
    diagonal = sums.largest_kernel_factor_sum(pos, vol, ptr, idx, kern.params, np.arange(m), not morris,
                                              np.zeros((0, dim, dim)))
    return matrix, dx, kern, diagonal


def tgv_operator_errors(pos, vol, h_over_dx, morris=False) -> dict:
    """How well the delta-ALE-SPH operators (psph.compute.fluid, the kernels every run uses) reproduce the
    analytic Taylor-Green vortex on a given 2-D particle distribution of the bi-periodic unit box (e.g.
    the one a run left at t = 1), Wendland C6 with h = h_over_dx * dx, dx = 1 / sqrt(n):

      nu_eff / nu  = sum_i a_i . u_i / sum_i (nu lap u)_i . u_i with a_i the viscous acceleration of
                     seed 001 eq. 11 and lap u = -8 pi^2 u: the kinetic-energy-weighted effective viscosity
                     (1 on an exact operator; E_k then decays as exp(-16 pi^2 nu_eff t));
      viscous_rms  = RMS |a - nu lap u| / RMS |nu lap u|, the pointwise error;
      grad_p_rms   = RMS |<grad p>/rho - grad p| / RMS |grad p| (seed 001 eq. 13, p_j + p_i form).

    The periodic neighbours come from the 3 x 3 tiling of the box. morris: Morris' viscous operator instead
    of eq. 11 (physics.viscosity)."""

    from psph.analytic import taylor_green
    from psph.compute import fluid

    n = len(pos)
    all_pos, all_vol, kern, ptr, idx = _tiled_unit_box(pos, vol, h_over_dx)
    vel, prs = taylor_green(all_pos)
    rho, kind = np.ones(len(all_pos)), np.zeros(len(all_pos), np.int8)
    grad_rho, pairs = np.zeros_like(all_pos), fluid.PairCache()
    fluid.renormalised_gradient(all_pos, all_vol, rho, ptr, idx, kern.params, kind, False, grad_rho, pairs)

    def acceleration(v, p, nu):  # variant 1: du/dt, no shifting terms, no diffusion
        out = np.zeros((n, 2))
        fluid.delta_ale_rhs(all_pos, all_vol, rho, all_vol, np.ascontiguousarray(v), np.zeros_like(all_pos), p,
                            grad_rho, pairs, kern.params, 1.0, 0.0, 0.0, nu, np.zeros(2), 1, False, False, kind,
                            False, np.zeros(n), np.zeros(n), out, morris=morris)
        return out

    u = vel[:n]
    lap = -8.0 * np.pi**2 * u
    x = 4.0 * np.pi * all_pos[:n]
    grad_p = np.pi * np.sin(x)  # p = -(cos 4 pi x + cos 4 pi y) / 4

    def rms(a):
        return math.sqrt(float((a * a).sum(axis=1).mean()))

    visc = acceleration(vel, np.zeros(len(all_pos)), 1.0)
    minus_grad_p = acceleration(np.zeros_like(all_pos), prs, 0.0)
    return {"nu_eff_ratio": float((visc * u).sum() / (lap * u).sum()), "viscous_rms": rms(visc - lap) / rms(lap),
            "grad_p_rms": rms(minus_grad_p + grad_p) / rms(grad_p)}
