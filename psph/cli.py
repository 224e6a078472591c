"""Command line: `psph run SCENE`, `psph run --restart CHECKPOINT`, `psph info SCENE`, `psph keys`,
`psph plot OUT_DIR`.

Options psph does not know and that start with a single dash are PETSc options and pass through
untouched (`-iips_pc_type hypre -log_view`). Errors print one line `psph: error: ...` and exit non-zero
(2 for bad input) without a traceback; an unexpected failure on one rank aborts all ranks.
"""

import argparse
import decimal
import math
import os
import re
import signal
import sys
import traceback

from psph import stop
from psph.errors import NumericalError, PsphError, SceneError, UsageError, is_collective


class _Parser(argparse.ArgumentParser):
    def error(self, message):  # one line, no usage dump
        raise UsageError(message)


def number(text: str) -> float:
    """argparse type: any number (nan and inf too; the types below bound it)."""
    try:
        return float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text!r}") from None


def positive_float(text: str) -> float:
    """argparse type: a finite number > 0 (the benchmarks' timing budgets)."""
    value = number(text)
    if not 0.0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"must be a finite number > 0, got {text}")
    return value


def positive_int(text: str, least=1) -> int:
    """argparse type: an integer >= 1 (a rank count, a size; also the benchmarks'), or >= least."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected an integer, got {text!r}") from None
    if value < least:
        raise argparse.ArgumentTypeError(f"must be >= {least}, got {value}")
    return value


def line_points(text: str) -> int:
    """argparse type: psph plot --points, 2 to MAX_LINE_POINTS (a review: 0 and 1 were refused in two
    wordings)."""
    value = positive_int(text, least=-sys.maxsize)
    if not 2 <= value <= MAX_LINE_POINTS:
        raise argparse.ArgumentTypeError(f"a line takes 2 to {MAX_LINE_POINTS} points, got {value}")
    return value


def nonempty(text: str) -> str:
    """argparse type: a path that is not empty (--figures '' wrote to the default)."""
    if not text.strip():
        raise argparse.ArgumentTypeError("expected a directory, got an empty string")
    return text


def _parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="psph", description="Distributed SPH with implicit iterative particle shifting.",
                     epilog="Unknown options starting with a single dash are passed to PETSc.")
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)

    def scene_args(p, optional=False):
        p.add_argument("scene", nargs="?" if optional else None, help="scene file (TOML)")
        p.add_argument("--set", action="append", default=[], metavar="KEY.PATH=VALUE",
                       help="override a scene key; the value is a TOML literal, a bare word a string")

    run = sub.add_parser("run", help="run a scene, or continue a run from a checkpoint")
    scene_args(run, optional=True)
    run.add_argument("--restart", metavar="CHECKPOINT",
                     help="continue the run saved in CHECKPOINT (OUT/checkpoint_NNNNNN.h5) instead of a scene; "
                          "--set may change time.*, output.* and neighbours.* keys only")
    run.add_argument("--checkpoint-every", type=int, metavar="STEPS",
                     help="same as --set output.checkpoint_every=STEPS")
    run.add_argument("--checkpoint-minutes", type=float, metavar="T",
                     help="same as --set output.checkpoint_minutes=T")
    run.add_argument("--out", help="output directory (default: ./<scene name>_out; on restart, the checkpoint's)")
    run.add_argument("--overwrite", action="store_true",
                     help="replace results already in the output directory (psph's own files are set aside, and "
                     "put back if the run is refused while it sets up)")
    run.add_argument("--allow-large", action="store_true",
                     help="run even if the estimated memory exceeds 80%% of this machine's, or the estimated steps "
                          "1e9")
    run.add_argument("--quiet", action="store_true",
                     help="print nothing but errors and set-up warnings (the log file still gets it all)")
    run.add_argument("--log", metavar="FILE", help="log file (default: OUT/psph.log, which --overwrite starts "
                     "afresh); messages and errors are appended")
    info = sub.add_parser("info", help="print the resolved scene, its model terms and estimated size")
    scene_args(info)
    info.add_argument("--ranks", type=positive_int, metavar="N",
                      help="estimate the memory for this many ranks (default: the ranks psph info runs on)")
    sub.add_parser("keys", help="list every scene key with its type, default and meaning")
    plot = sub.add_parser("plot", help="PNG figures of a run (fields, history) or of a study directory of runs")
    plot.add_argument("out_dir", help="a run's output directory, or a directory of runs")
    plot.add_argument("--figures", type=nonempty, help="where to write the PNGs (default: OUT_DIR/figures)")
    plot.add_argument("--line", type=float, nargs="+", metavar="X",
                      help="instead: the last snapshot's pressure, density and velocity along the segment from "
                      "(x0, y0[, z0]) to (x1, y1[, z1]), given as x0 y0 [z0] x1 y1 [z1], in line.png and line.csv")
    plot.add_argument("--points", type=line_points, default=LINE_POINTS, metavar="N",
                      help=f"points along --line (default {LINE_POINTS})")
    return parser


def split_petsc_options(argv):
    """Separate PETSc options (single-dash tokens and their values) from psph's arguments."""
    ours, petsc = [], []
    k = 0
    while k < len(argv):
        tok = argv[k]
        if tok.startswith("-") and not tok.startswith("--") and len(tok) > 2 and not _is_number(tok):
            petsc.append(tok)
            if k + 1 < len(argv) and (not argv[k + 1].startswith("-") or _is_number(argv[k + 1])):
                petsc.append(argv[k + 1])
                k += 1
        else:
            ours.append(tok)
        k += 1
    return ours, petsc


ARGPARSE_NEGATIVE = re.compile(r"^-\d+$|^-\d*\.\d+$")  # what argparse itself reads as a negative number


def plain_negative_numbers(argv):
    """Write negative numbers in exponent form (-1e-3) positionally (-0.001): argparse would take them for options."""
    return [format(decimal.Decimal(repr(float(tok))), "f") if tok.startswith("-") and _is_number(tok)
            and math.isfinite(float(tok)) and not ARGPARSE_NEGATIVE.match(tok) else tok for tok in argv]


def _is_number(tok: str) -> bool:
    try:
        float(tok)
        return True
    except ValueError:
        return False


_LOG = {"path": None}  # the run's log file, once its output directory exists


def _append_log(line: str) -> None:
    if _LOG["path"]:
        try:
            with open(_LOG["path"], "a") as f:
                f.write(line + "\n")
        except OSError:
            pass  # the log is a convenience; never let it end a run


def _say(comm, quiet=False):
    def log(msg):
        if comm.rank == 0:
            if not quiet:
                print(msg, flush=True)
            _append_log(msg)
    return log


def cmd_info(args, petsc_options, comm) -> int:
    from psph.drivers import describe_model
    from psph.scene.validate import to_table
    from psph.simulation import estimate_resources, estimate_time_step, iips_assembled, iips_runs
    from psph.solvers.petsc import initialize

    scene = read_scene(comm, args.scene, args.set)
    initialize(petsc_options, comm)  # which IIPS operator the options choose (the memory estimate)
    solver = None
    if iips_runs(scene):  # the solver the command line's PETSc options give (collective)
        from psph.shifting.iips import ImplicitShifting

        shifting = ImplicitShifting(scene.iips, comm)
        try:
            solver = "IIPS linear solver: " + ImplicitShifting.describe_settings(shifting.settings())
        finally:
            shifting.destroy()
    if comm.rank == 0:
        print(f"# scene {scene.name!r} from {args.scene}")
        _print_table(to_table(scene))
        print("# model terms (only these run)")
        for line in describe_model(scene):
            print(f"#   {solver if solver and line.startswith('IIPS linear solver:') else line}")
        ranks = args.ranks or comm.size
        n, nbytes, per_particle = estimate_resources(scene, ranks, iips_assembled(scene))
        print(f"# estimated particles: {n}, memory on {ranks} rank(s): {nbytes / 2**30:.3g} GiB "
              f"({per_particle:.0f} bytes per particle)")
        step = estimate_time_step(scene)
        if step:
            print(f"# {step}")
        for warning in scene_warnings(scene):
            print(f"# warning: {warning}")
        unread = scene.unread_keys()
        if unread:
            print(f"# keys set that this run does not read (another method's?): {', '.join(unread)} "
                  f"({_unread_why(scene)})")
    return 0


def _print_table(table, prefix=""):
    scalars = {k: v for k, v in table.items() if not isinstance(v, dict)}
    for k, v in scalars.items():
        print(f"{prefix}{k} = {_toml_value(v)}")
    for k, v in table.items():
        if isinstance(v, dict):
            print(f"\n[{prefix}{k}]")
            _print_table(v, "")


def _toml_value(v):
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return repr(v)


SAFE_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]*")  # a scene name that makes a default ./NAME_out
MAX_NAME = 200  # (+ "_out": within the 255 bytes of a file name)
RESTART_KEYS = ("time.", "output.", "neighbours.")  # skin and balance: results change as with the rank count


def read_scene(comm, path, sets):
    """The scene of the TOML file `path` with the overrides `sets`, read on rank 0 and given to every rank,
    whose packing.start snapshot rank 0 can open: a file one rank cannot read stops every rank together, and
    a missing start before any set-up work (a style audit: found after the run had set up, 51 s). Collective."""
    from pathlib import Path

    from psph.parallel.comm import on_root
    from psph.scene.load import apply_overrides, read_table, scene_from_table

    scene = scene_from_table(apply_overrides(on_root(comm, lambda: read_table(path)), sets))
    start = scene.packing.start

    def check_start():
        if start and not Path(start).is_file():
            raise SceneError("packing.start", f"no file {start}")

    on_root(comm, check_start)
    return scene


def _scene_and_restart(args, comm, petsc_options=()):
    """The scene to run and, for --restart, the checkpoint's contents (read collectively)."""
    from psph.drivers import StaticDriver, driver_for
    from psph.scene.load import apply_overrides, scene_from_table

    sets = list(args.set)
    if args.checkpoint_every is not None:
        sets.append(f"output.checkpoint_every={args.checkpoint_every}")
    if args.checkpoint_minutes is not None:
        sets.append(f"output.checkpoint_minutes={args.checkpoint_minutes}")
    restart = None
    if args.restart:
        from psph.io.checkpoint import check_positions, read_checkpoint
        from psph.simulation import make_domain

        if args.scene:
            raise UsageError("give a scene or --restart CHECKPOINT, not both (the checkpoint holds its scene)")
        for item in sets:
            if not item.startswith(RESTART_KEYS):
                raise UsageError(f"--set {item!r}: a restart may change only time.*, output.* and neighbours.* keys")
            if item.split("=", 1)[0].strip() == "time.integrator":  # the method, mid-run: not a continuation
                raise UsageError(f"--set {item!r}: a restart continues with the checkpoint's time integrator")
        restart = read_checkpoint(comm, args.restart)
        try:  # the checkpoint's own scene first: an error there is the file's, not an override's
            saved = scene_from_table(restart[0]["scene"])
        except SceneError as err:
            raise UsageError(f"cannot restart from {args.restart!r}: its scene: {err}") from None
        check_positions(comm, args.restart, restart[1], make_domain(saved))
        if driver_for(saved) is StaticDriver:
            raise UsageError(f"cannot restart from {args.restart!r}: its scene is a static run (physics.scheme = "
                             "'none'), which writes no checkpoints")
        try:
            scene = scene_from_table(apply_overrides(restart[0]["scene"], sets))
        except SceneError as err:  # the checkpoint's scene passed: an override made it fail, and a key that
            # only the checkpoint sets cannot be changed back (a restarts audit: a t_end that took a moving
            # body into a wall was refused as 'bodies[1].motion')
            given = list(dict.fromkeys(item.split("=", 1)[0].strip() for item in sets))
            if err.key in given or not given:
                raise
            raise SceneError(" / ".join(given), str(err)) from None
    elif args.scene:
        scene = read_scene(comm, args.scene, sets)
    else:
        # a PETSc option without a value before the scene took the scene for its value (a PETSc-options audit)
        taken = [f"{name} {value}" for name, value in zip(petsc_options, list(petsc_options[1:]) + [""])
                 if name.startswith("-") and value.endswith(".toml")]
        raise UsageError("run needs a scene file (or --restart CHECKPOINT)"
                         + (f": PETSc options go after it ({taken[0]!r} took the scene as the option's value)"
                            if taken else ""))
    if restart is not None:
        state = restart[0]
        if state["time"] >= scene.time.t_end * (1.0 - 1e-12):  # the drivers' end test: nothing would be run
            raise SceneError("time.t_end", f"{scene.time.t_end:g} is not after the checkpoint's time "
                                           f"{state['time']:.6g} (step {state['step']}): nothing to continue")
    return scene, restart


def _start_log(path, line: str) -> None:
    """Append the run's first line to its log file `path`, or raise OSError (a log that cannot be written
    is refused before any work, rather than lost in silence: /dev/full, a missing directory)."""
    with open(path, "a") as f:
        f.write(line + "\n")
        f.flush()  # where the write fails (ENOSPC on /dev/full)


def cmd_run(args, petsc_options, comm) -> int:
    import numpy as np
    from mpi4py import MPI

    from psph.drivers import driver_for
    from psph.io.checkpoint import results_after
    from psph.io.files import discard_results, holds_results, restore_results
    from psph.io.snapshots import foreign_snapshots
    from psph.parallel.comm import raise_if_any
    from psph.simulation import check_resources, iips_runs
    from psph.solvers.petsc import initialize

    scene, restart = _scene_and_restart(args, comm, petsc_options)
    initialize(petsc_options, comm)  # the memory check asks PETSc's options which IIPS operator the run builds
    node = comm.Split_type(MPI.COMM_TYPE_SHARED)  # the ranks on this machine
    node_ranks = node.Get_size()
    node.Free()
    refusal = None
    try:  # each node judges its own memory: one node's refusal is every rank's (a parallel audit: the other
        check_resources(scene, allow_large=args.allow_large, ranks=comm.size, node_ranks=node_ranks)
    except SceneError as err:  # ranks waited for the refusing ones in the next collective, for ever)
        refusal = err
    raise_if_any(comm, refusal)
    if not (restart or args.out or (SAFE_NAME.fullmatch(scene.name) and len(scene.name) <= MAX_NAME)):
        # ("../x" or "a/b" would write elsewhere; a name past the system's limit failed as an I/O error)
        raise SceneError("name", f"{scene.name[:40]!r}{'...' if len(scene.name) > 40 else ''} names no output "
                         f"directory ./NAME_out: give --out, or a name of at most {MAX_NAME} letters, digits, '.', "
                         "'_' and '-' that starts with a letter or digit")
    default_out = os.path.dirname(os.path.abspath(args.restart)) if restart else f"{scene.name}_out"
    out = os.path.abspath(args.out or default_out)
    continuing = restart is not None and os.path.realpath(out) == os.path.dirname(os.path.realpath(args.restart))
    if holds_results(out) and not args.overwrite and not continuing:
        raise UsageError(f"output directory {out!r} already holds results; choose another --out or pass --overwrite")
    if os.path.exists(out) and not os.path.isdir(out):
        raise UsageError(f"output path {out!r} exists and is not a directory")
    start = scene.packing.start
    if start and restart is None and os.path.realpath(os.path.dirname(os.path.abspath(start))) == os.path.realpath(out):
        # (a review: --overwrite set the snapshot aside with the rest, and the run said there was no file)
        raise SceneError("packing.start", f"{start} lies in the output directory {out}, whose results this run "
                         "replaces: copy it elsewhere first, or choose another --out")
    later = []  # an in-place continuation: what the directory holds past the checkpoint, replaced
    if continuing:
        foreign = comm.bcast(foreign_snapshots(out, restart[0].get("run")) if comm.rank == 0 else None, root=0)
        if foreign:  # (a checkpoint copied into another run's directory: continuing would list, replace or
            # remove that run's snapshots as its own)
            raise UsageError(f"output directory {out!r} holds snapshots of another run than the checkpoint's: "
                             f"{', '.join(p.name for p in foreign[:3])}{', ...' if len(foreign) > 3 else ''}; "
                             "continue into another --out")
        final, later = comm.bcast(results_after(out, restart[0]) if comm.rank == 0 else None, root=0)
        if final and not args.overwrite:
            state = restart[0]
            raise UsageError(f"output directory {out!r} holds results past the checkpoint's t = {state['time']:.6g} "
                             f"(step {state['step']}): {', '.join(os.path.basename(p) for p in final)}; continuing "
                             "there replaces them: pass --overwrite to do so, or choose another --out")
        later = final + later
    if iips_runs(scene):
        from psph.shifting.iips import ImplicitShifting

        shifting = ImplicitShifting(scene.iips, comm)  # a bad -iips_ option stops the run before --overwrite clears
        try:
            solver = shifting.settings()  # (the trial may raise its max_it)
            shifting.trial(scene.domain.dimension)
        finally:
            shifting.destroy()
    log_path = os.path.abspath(args.log) if args.log else os.path.join(out, "psph.log")
    first = (f"psph: running scene {scene.name!r} on {comm.size} rank(s)"
             + (f", continuing {args.restart}" if restart else "") + f" ({' '.join(sys.argv[1:]) or 'run'})")
    fresh = comm.bcast(not os.path.exists(out) if comm.rank == 0 else None, root=0)  # (before anything is written)
    # every rank stops with rank 0's failure, none waits for rank 0
    failure, aside = comm.bcast(_prepare_output(args, out, log_path, first, continuing, later) if comm.rank == 0
                                else None, root=0)
    if failure:
        if comm.rank == 0 and aside is not None:
            restore_results(out, aside, keep=[log_path] if args.log else [], clear=not continuing)
        raise UsageError(failure)
    _LOG["path"] = log_path
    log = _say(comm, args.quiet)
    if comm.rank == 0 and not args.quiet:
        print(first, flush=True)
    if later:
        log(f"psph: removed what {out} held past the checkpoint, which the continuation replaces: "
            + ", ".join(os.path.basename(p) for p in later))
    elif restart and not continuing:
        log(f"psph: {os.path.join(out, 'psph.xdmf')} lists the snapshots from the checkpoint on; the earlier ones "
            f"are in {os.path.dirname(os.path.abspath(args.restart))}")
    for warning in scene_warnings(scene, restart):
        _warn(comm, f"psph: warning: {warning}")
    if iips_runs(scene):
        log(f"psph: IIPS linear solver: {ImplicitShifting.describe_settings(solver)}")
    given = {item.split("=", 1)[0].strip() for item in args.set}  # a scene file may hold other methods' keys
    unread = [key for key in scene.unread_keys() if key in given]
    if unread:
        _warn(comm, f"psph: warning: --set keys this run does not read: {', '.join(unread)} ({_unread_why(scene)})")
    kwargs = {"restart": restart} if restart else {}  # static runs write no checkpoints
    stop.install(comm, after="iteration with a snapshot" if scene.physics.scheme == "none" else
                 "step with a checkpoint")
    settled = []  # the run has set up (Simulation.settle): the results --overwrite replaces can go

    def settle():
        settled.append(True)
        if comm.rank == 0:
            discard_results(aside)

    try:  # numpy's floating-point warnings (a blown-up speed squared) would come before psph's one-line
        # diagnosis, which the state's checks give (non-finite fields, the density's range, the time step)
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"), \
                driver_for(scene)(scene, comm, out, log=log, progress=not args.quiet, **kwargs) as driver:
            driver.sim.on_settled = settle
            if iips_runs(scene):
                driver.sim.summary_extra["iips_solver"] = solver
            summary = driver.run()
            rejected = sum(getattr(m, "rejections", 0) for m in driver.shifting_methods())
            solvers = {id(m.solver): m.solver for m in driver.shifting_methods() if hasattr(m, "solver")}
            loose = [w for solver in solvers.values() if (w := solver.loose_warning())]
        late = stop.requested(comm)
    except BaseException as err:
        if not settled:
            _unsettled(comm, err, out, aside, fresh, continuing, keep=[log_path] if args.log else [])
        raise
    finally:
        stop.uninstall()
    if late:  # the signal came during the last step or the final writes: nothing was cut short
        log(f"psph: {signal.Signals(late).name} came as the run ended: it is complete")
    log(f"psph: {summary['n_particles']} particles, {summary['steps']} steps, {summary['wall_time_s']:.2f} s, "
        f"peak memory {summary['peak_memory_mib']:.0f} MiB per rank; results in {out}")
    if rejected:  # with iips.on_failure/on_stall = "reject" a run ends well even if no call moved anything
        _warn(comm, f"psph: warning: {rejected} IIPS call(s) were rejected and their displacements undone "
                    f"(iips.on_failure / iips.on_stall = \"reject\"; each is in the log)")
    for warning in loose:
        _warn(comm, f"psph: warning: {warning}")
    _warn_unused_options(comm)
    return 0


def _unsettled(comm, err, out, aside, fresh, continuing, keep) -> None:
    """A run that ends before it has set up: refused as bad input (found late: a fill region with no lattice
    node, a pre-procedure that leaves nothing for iips.beta to scale), it leaves the directory as it found it,
    the results --overwrite set aside put back (a fuzzing audit found them deleted) and a directory it made
    removed (an in-place continuation: what it set aside put back, nothing else removed); any other end (a
    diagnosed start, a bug) keeps what it wrote, and the set-aside results go.
    Rank 0 moves the files; the log they held is no longer this run's. Collective error: every rank."""
    from psph.io.files import discard_results, restore_results

    refused = isinstance(err, PsphError) and err.exit_code == 2 and is_collective(err)
    if refused and not keep:
        _LOG["path"] = None
    if comm.rank != 0:
        return
    if not refused:
        discard_results(aside)
        return
    restore_results(out, aside, keep, clear=not continuing)
    if fresh and os.path.isdir(out) and not os.listdir(out):
        os.rmdir(out)


def _prepare_output(args, out, log_path, first, continuing, later):
    """Rank 0, before a run: start the log (a log the user named first: refused, it leaves everything else
    untouched), set the directory's results aside (--overwrite: cli._unsettled puts them back if the run is
    refused while it sets up; an in-place continuation: what it replaces, `later`, and copies of what it
    rewrites). Returns (what failed, in one line, or None; the set-aside results' directory, or None)."""
    from psph.io.files import set_aside_for_continuation, set_aside_results

    aside = None
    try:
        if args.log:
            if os.path.commonpath([os.path.abspath(out), os.path.dirname(log_path)]) == os.path.abspath(out):
                os.makedirs(os.path.dirname(log_path), exist_ok=True)  # a log inside the new --out
            _start_log(log_path, first)
    except OSError as err:
        return f"--log {args.log!r}: {err.strerror or err}", None
    try:
        if args.overwrite and not continuing:
            aside = set_aside_results(out, keep=[log_path] if args.log else [])
        os.makedirs(out, exist_ok=True)
    except OSError as err:
        return f"output directory {out!r}: {err.strerror or err}", aside
    try:
        if continuing:  # before the log line that tells of `later`
            aside = set_aside_for_continuation(out, later, keep=[log_path] if args.log else [])
        if not args.log:
            _start_log(log_path, first)
    except OSError as err:
        return f"{err.filename or log_path!r}: {err.strerror or err}", aside
    return None, aside


# the largest time.cfl at which a scheme ran stably in an audit's runs (riemann_ale: 1-D acoustic wave, 2-D
# Taylor-Green; delta_ale with delta+ ran Taylor-Green at 1.5, as far as the neighbour skin allowed)
STABLE_CFL = {"riemann_ale": 0.8}
# the largest Mach number U / c0 of a weakly compressible flow (psph run warns above it)
MAX_MACH = 0.1
LINE_POINTS = 200  # psph plot --line's default number of points
MAX_LINE_POINTS = 100_000  # and its most (a review: 1e8 points ran for minutes)
# PETSc options read only when PETSc finalises, after psph's check
AT_FINALIZE = ("-options_left", "-options_view", "-malloc_dump", "-memory_view", "-objects_dump")


def scene_warnings(scene, restart=None) -> list:
    """What psph run warns of in this scene before it starts (psph info prints them too): settings that run
    but give poor or misleading results. A continuation (restart) is not warned again of its start."""
    from psph.scene.schema import EXPLICIT_LAWS, FLUID_SCHEMES
    from psph.simulation import iips_runs

    warnings = []
    iips = scene.iips
    if (scene.shifting.method == "iips" and scene.physics.scheme != "none" and iips.threshold == 0.0
            and iips.beta == 0.0):  # time-dependent: a static run iterates to iips.max_newton by design
        warnings.append(f"iips.threshold = 0 (and no iips.beta): every IIPS call of this run iterates "
                        f"until iips.max_newton = {iips.max_newton} (or a step without descent ends it), on past "
                        "convergence, where round-off grows and the results differ between rank counts (thesis: 0.02 "
                        "with a free surface, 0.08 in bounded flows, 0.001 in Taylor-Green)")
    if (iips_runs(scene) and scene.physics.scheme != "none" and iips.update == "nfts"
            and scene.initial.sigma_over_dx > 0 and iips.pre_newton == 0 and not restart):
        warnings.append(f"initial.sigma_over_dx = {scene.initial.sigma_over_dx:g} with iips.update = nfts "
                        "and no iips.pre_newton: the first IIPS calls level the perturbed start inside the flow, and "
                        "NFTS's mass line exceeds rho x its volume line by 2 rho V s . grad C (thesis eq. 9.7), so "
                        "they change a uniform density (at rest, sigma = 0.1 dx: by -5.6% / +1.3% in one call); give "
                        "iips.pre_newton")
    if scene.shifting.method == "iips" and scene.physics.scheme in FLUID_SCHEMES and iips.update == "mls1":
        warnings.append("iips.update = mls1 replaces every field by its first-order fit at every IIPS "
                        "call, which smooths the flow (Taylor-Green at dx = 0.05 from a relaxed start: kinetic energy "
                        "-99.8% by t = 1, against -0.07% with no update; one call took 5.2%); mls1_increment adds only "
                        "the fit's change, and mls2 smooths less")
    if scene.shifting.method in ("explicit_iterative", "lind"):
        from psph.shifting.explicit import stability_limit
        from psph.shifting.velocity import Lind

        dom, lind = scene.domain, scene.shifting.method == "lind"
        limit = stability_limit(dom.kernel, dom.dimension, dom.h_over_dx, Lind.grad_c_weights if lind else (0, 4))
        key = "lind_diffusion" if lind else "diffusion"
        value = getattr(scene.shifting, key)
        if value > limit:
            warnings.append(f"shifting.{key} = {value:g} exceeds {limit:.3g}, the limit above which "
                            f"dx = -D grad C{'^' if lind else ''} (thesis eq. {'6.16' if lind else '6.13'}) amplifies "
                            f"the shortest waves on the lattice ({dom.kernel}, h/dx = {dom.h_over_dx:g}, "
                            f"{dom.dimension}-D): the distribution degrades instead of relaxing")
    bare = scene.bare_fluid_faces()
    if bare and not restart:  # (a 3-D audit: a box at rest stopped at step 6 on its density, a hydrostatic column
        # with no floor at step 112 on particles leaving, neither naming the cause)
        warnings.append(f"the fluid reaches the bounded face(s) {', '.join(bare)} with no wall, outflow or "
                        f"inflow there (domain.periodic = {list(scene.domain.periodic)}): its particles there have "
                        "no neighbour beyond it, and the pressure, gravity or shifting pushes them out of the domain; "
                        "make the axis periodic, wall the fluid (bodies, 2-D), name the face in domain.outflow, or "
                        "leave a free surface there (initial.fill_lower / fill_upper)")
    phys = scene.physics
    mach = phys.reference_velocity / phys.sound_speed if phys.sound_speed > 0 else 1.0
    if phys.scheme in FLUID_SCHEMES and mach > MAX_MACH * (1.0 + 1e-9) and not restart:  # (a new user's audit:
        # c0 = 0.5 at U = 1 ran without a word)
        warnings.append(f"physics.sound_speed = {phys.sound_speed:g} is {1.0 / mach:.3g} times "
                        f"physics.reference_velocity = {phys.reference_velocity:g}: weakly compressible SPH takes "
                        f"c0 >= {1.0 / MAX_MACH:g} U (Mach <= {MAX_MACH:g}), which keeps the density within about 1% "
                        "of rho0 (its variation grows as Mach^2)")
    height = scene.fluid_height()
    wave = math.sqrt(math.hypot(*phys.gravity) * height)  # the speed of a gravity wave as deep as the fluid
    if (phys.scheme in FLUID_SCHEMES and wave > MAX_MACH * phys.sound_speed * (1.0 + 1e-9) and not restart
            and not (mach > MAX_MACH * (1.0 + 1e-9) and phys.reference_velocity >= wave)):  # (a new user's audit:
        # g = 9.81 with c0 = 10 over H = 1 started at 98% of the density limit, and stopped at step 32 naming it)
        warnings.append(f"physics.sound_speed = {phys.sound_speed:g} is {phys.sound_speed / wave:.3g} times "
                        f"sqrt(|g| H) = {wave:.3g}, the speed gravity gives a fluid {height:g} deep "
                        f"(physics.gravity, H along it): its weight compresses the fluid's foot by g H / c0^2 = "
                        f"{wave**2 / phys.sound_speed**2:.2%} (physics.max_density_variation = "
                        f"{phys.max_density_variation:g}); weakly compressible SPH takes c0 >= {1.0 / MAX_MACH:g} "
                        f"sqrt(g H) (1%)")
    speed = math.hypot(*scene.initial.uniform_velocity) if scene.initial.velocity == "uniform" else 0.0
    if phys.scheme in FLUID_SCHEMES and speed > phys.reference_velocity * (1.0 + 1e-9) and not restart:
        warnings.append(f"initial.uniform_velocity: the fluid starts at {speed:g}, faster than "
                        f"physics.reference_velocity = {phys.reference_velocity:g}, the speed the Mach number "
                        "(its warning) and the shifting laws' caps assume: raise it")
    if phys.scheme == "riemann_ale" and phys.riemann_dissipation == "full" and mach < 0.05:
        warnings.append(f"physics.sound_speed / reference_velocity = {1.0 / mach:g}: the acoustic Riemann "
                        "solver's dissipation z (u_L - u_R) / 2 grows with c0 (Taylor-Green, dx = 0.05, t = 0.01: "
                        "kinetic energy -2.3% at c0/U = 10, -10% at 50, -89% at 1000); "
                        "physics.riemann_dissipation = \"low\" keeps it (-0.13%)")
    for k, inflow in enumerate(scene.inflow):
        if inflow.ramp_time >= scene.time.t_end and not restart:  # (a review: 1e300 ran without a word)
            warnings.append(f"inflow[{k}].ramp_time = {inflow.ramp_time:g} is not shorter than time.t_end = "
                            f"{scene.time.t_end:g}: the buffer does not reach its velocity within the run")
    method = scene.shifting.method
    moving = [f"bodies[{k}] {b.name!r}" for k, b in enumerate(scene.bodies)
              if b.motion.law != "fixed" or b.motion.turning_law != "fixed"]
    if phys.scheme == "riemann_ale" and moving and method != "none":
        warnings.append(f"a moving body ({', '.join(moving)}) in physics.scheme = \"riemann_ale\" with "
                        f"shifting.method = {method!r}: the fluid at its corners shrinks as it does next to a fixed "
                        "wall, and the shifts fixed walls take do not hold it (SPHERIC 6's moving square at dx = 0.1 "
                        "stopped with a volume drifted by 50% at t = 0.66 with delta_plus, 1.95 with neuhauser and "
                        "its P^F, 0.93 with IIPS, 0.67 with IIPS + NFTS; with the low-dissipation pressure IIPS "
                        "ran); without shifting it ran to t = 2 (run_scripts/riemann_walls.py)")
    elif phys.scheme == "riemann_ale" and scene.bodies and (
            (method in EXPLICIT_LAWS and not (method == "neuhauser" and scene.shifting.fictitious_pressure))
            or (method == "iips" and iips.update == "nfts")):
        how = f"iips.update = {iips.update!r}" if method == "iips" else f"shifting.method = {method!r}"
        warnings.append(f"walls in physics.scheme = \"riemann_ale\" with {how}: the scheme's volumes follow the "
                        "shift and nothing pushes a particle shifted towards a wall back, so the particles there "
                        "shrink and the shift fills their place (the lid-driven cavity at dx = 0.04 stopped with "
                        "a volume drifted by 50% at t = 0.67 with delta_plus, 0.52-1.2 with lind, skillen, oger and "
                        "neuhauser's P_S, 3.6 with IIPS + NFTS); shifting.method = \"neuhauser\" with "
                        "shifting.fictitious_pressure = true (thesis eq. 7.3-7.4), iips with iips.update = \"none\" "
                        "or \"mls2\", or no shifting ran to t = 5, though a volume drifted by 8-45% "
                        "(run_scripts/riemann_walls.py)")
    if phys.scheme == "riemann_ale" and scene.time.cfl > STABLE_CFL["riemann_ale"]:
        warnings.append(f"time.cfl = {scene.time.cfl:g} with physics.scheme = \"riemann_ale\": the scheme "
                        f"runs stably up to about {STABLE_CFL['riemann_ale']:g} (an acoustic wave and Taylor-Green "
                        "blew up from 1.0 in 2-D and 1.2 in 1-D; the thesis uses 0.2, eq. 5.52)")
    return warnings


def _warn_unused_options(comm) -> None:
    """Warn (stderr and the log) about command-line PETSc options that nothing read: a misspelling
    (-iips_ksp_rtoll) or an option of a solver the scene does not have (-iips_* without IIPS)."""
    from psph.solvers.petsc import is_initialized, unused_options

    if not is_initialized():
        return
    unused = [o for o in unused_options() if not o.startswith(AT_FINALIZE)]
    if unused:
        _warn(comm, f"psph: warning: PETSc options that nothing read: {', '.join(unused)} (misspelt, or for a "
                    "solver this scene does not have)")


def _unread_why(scene) -> str:
    return f"physics.scheme = {scene.physics.scheme!r}, shifting.method = {scene.shifting.method!r}"


def _warn(comm, line: str) -> None:
    """A warning on stderr (also with --quiet) and in the log, from rank 0."""
    if comm.rank == 0:
        print(line, file=sys.stderr, flush=True)
        _append_log(line)


def cmd_keys(args, petsc_options, comm) -> int:
    from psph.scene.schema import Scene
    from psph.scene.validate import describe_keys

    if comm.rank == 0:
        for key, kind, default, doc in describe_keys(Scene):
            print(f"{key:34s} {kind:24s} {'required' if default == 'required' else _toml_value(default):>12s}  {doc}")
    return 0


def cmd_plot(args, petsc_options, comm) -> int:
    from psph.plot import plot

    if comm.rank == 0:
        def warn(line):
            print(f"psph: warning: {line}", file=sys.stderr, flush=True)

        for path in plot(args.out_dir, args.figures, warn, args.line, args.points):
            print(f"psph: wrote {path}")
    return 0


COMMANDS = {"run": cmd_run, "info": cmd_info, "keys": cmd_keys, "plot": cmd_plot}


def main(argv=None) -> int:
    from mpi4py import MPI

    comm = MPI.COMM_WORLD  # the application entry point owns the world communicator
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        ours, petsc_options = split_petsc_options(argv)
        args = _parser().parse_args(plain_negative_numbers(ours))
        return COMMANDS[args.command](args, petsc_options, comm)
    except PsphError as err:
        if comm.size == 1 or is_collective(err):
            if comm.rank == 0:
                line = f"psph: {err}" if isinstance(err, stop.Stopped) else f"psph: error: {err}"
                print(line, file=sys.stderr, flush=True)
                _append_log(line)
            if isinstance(err, (NumericalError, stop.Stopped)):  # the run ran: a misspelt option may be why (a
                _warn_unused_options(comm)  # PETSc-options audit: only a run that ended well told of them)
            return err.exit_code
        print(f"psph: error on rank {comm.rank}: {err}", file=sys.stderr, flush=True)
        _append_log(f"psph: error on rank {comm.rank}: {err}")
        comm.Abort(err.exit_code)
    except BrokenPipeError:
        if not _reader_left():
            return _internal_error(comm)
        # the reader of the output left (psph info ... | head): stop quietly, as Unix tools do
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # the exit's flush has nowhere to fail
        if comm.size > 1:
            comm.Abort(141)
        return 141  # 128 + SIGPIPE
    except KeyboardInterrupt as err:
        signum = getattr(err, "signum", signal.SIGINT)
        if comm.rank == 0:
            print(f"psph: stopped at once by {signal.Signals(signum).name}; nothing saved past the last checkpoint",
                  file=sys.stderr, flush=True)
        _append_log(f"psph: stopped at once by {signal.Signals(signum).name} on rank {comm.rank}")
        if comm.size > 1:
            comm.Abort(128 + signum)
        return 128 + signum
    except MemoryError as err:  # numpy's names the array: "Unable to allocate 74.5 GiB for an array ..."
        return _machine_error(comm, f"out of memory: {err}", getattr(err, "collective", False))
    except OSError as err:  # a read or write the system refused mid-run: a full disk, a file taken away
        return _machine_error(comm, f"input/output failed: {err}", getattr(err, "collective", False))
    except Exception:
        return _internal_error(comm)


def _machine_error(comm, message: str, collective=False) -> int:
    """Not a bug: the machine refused (memory, disk). One line from each rank that met it, no traceback on the
    terminal (the log file gets it, should it have been a bug after all); with several ranks the job is
    aborted, since the others may be waiting in a collective; `collective`: every rank met the same error
    at the same point (parallel.comm.on_root): rank 0's line, and every rank exits."""
    try:
        sys.stdout.flush()
    except OSError:  # standard output is what failed (psph keys > /dev/full): the exit's flush would fail again
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    line = ("psph: error" + (f" on rank {comm.rank}" if comm.size > 1 and not collective else "")
            + f": {' '.join(message.split())}")
    if comm.rank == 0 or not collective:
        print(line, file=sys.stderr, flush=True)
        _append_log(traceback.format_exc().rstrip() + "\n" + line)  # where it happened, for a report if a bug
    if comm.size > 1 and not collective:
        comm.Abort(1)
    return 1


def _internal_error(comm) -> int:
    """A bug: show it, and never leave other ranks waiting in a collective."""
    traceback.print_exc()
    print(f"psph: internal error on rank {comm.rank} (a bug; please report it)", file=sys.stderr, flush=True)
    if comm.size > 1:
        comm.Abort(1)
    return 1


def _reader_left() -> bool:
    """Whether standard output is a pipe whose reader has closed it (poll reports an error on it)."""
    import select

    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLERR)
        return any(event & select.POLLERR for _, event in poller.poll(0))
    except (OSError, ValueError, AttributeError):
        return False
