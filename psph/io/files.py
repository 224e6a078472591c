"""Atomic file writes (temporary file, fsync, rename) and output-directory housekeeping."""

import json
import math
import os
import re
import shutil
from pathlib import Path


def fsync_path(path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def replace_atomically(tmp, final) -> None:
    """fsync `tmp`, rename it over `final`, fsync the directory."""
    fsync_path(tmp)
    os.replace(tmp, final)
    fsync_path(Path(final).parent)


def write_text_atomic(path, text: str) -> None:
    """Write `path` whole or not at all (the old file stays, and no temporary file is left, if it fails)."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        tmp.write_text(text)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    replace_atomically(tmp, path)


def write_json_atomic(path, data) -> None:
    """Write `data` as JSON, whole or not at all; a non-finite number (the smallest spacing of a domain the
    fluid has left, an error against a zero reference) is written as null: JSON has no NaN or Infinity, and
    strict readers (JavaScript's JSON.parse) refuse the file (a diagnostics audit)."""
    text = json.dumps(_finite_or_null(data), indent=2, sort_keys=True, default=jsonable, allow_nan=False)
    write_text_atomic(path, text + "\n")


def _finite_or_null(value):
    """`value` with every non-finite float, at any depth (numpy's included), replaced by None."""
    if isinstance(value, dict):
        return {k: _finite_or_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_finite_or_null(v) for v in value]
    if type(value).__module__ == "numpy":
        return _finite_or_null(jsonable(value))
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def jsonable(value):
    try:
        import numpy as np

        if isinstance(value, np.generic):
            return value.item()
        if isinstance(value, np.ndarray):
            return value.tolist()
    except ImportError:  # pragma: no cover
        pass
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


# everything a run (and `psph plot`, in figures/) writes into its output directory, as regular expressions
OUTPUT_FILES = re.compile(r"(summary\.json|history\.csv|psph\.xdmf|psph\.log|probes\.csv|wall_pressure\.csv"
                          r"|packing\.csv|(snapshot|checkpoint)_\d{6,}\.h5)(\.tmp)?")
OUTPUT_FIGURES = re.compile(r"(history|probes|fields|convergence)\.png")
CHECKPOINT_FILES = re.compile(r"checkpoint_\d{6,}\.h5")  # io.checkpoint.checkpoint_name's


def holds_results(directory) -> bool:
    """True if `directory` already holds psph output (which a new run must not overwrite silently): any of
    OUTPUT_FILES but the log (a snapshot, a checkpoint to continue, the probes' or the packing's series: a
    fuzzing audit found probes.csv overwritten, the markers alone being checked)."""
    d = Path(directory)
    if not d.is_dir():
        return False
    return any(OUTPUT_FILES.fullmatch(p.name) and not p.name.startswith("psph.log") for p in d.iterdir())


def _own_outputs(directory, keep=()) -> list:
    """psph's own output files in `directory` (OUTPUT_FILES, unfinished .tmp files included, and OUTPUT_FIGURES
    in its figures/ unless that is a link elsewhere), but those in `keep`."""
    keep = {os.path.realpath(k) for k in keep}
    d = Path(directory)
    if not d.is_dir():
        return []
    figures = d / "figures"
    places = [(d, OUTPUT_FILES)] + ([(figures, OUTPUT_FIGURES)] if figures.is_dir() and not figures.is_symlink()
                                    else [])
    return [path for folder, names in places for path in folder.iterdir()
            if names.fullmatch(path.name) and (path.is_file() or path.is_symlink())
            and os.path.realpath(path) not in keep]


def clear_results(directory, keep=()) -> None:
    """Remove psph's own output from `directory` (_own_outputs), and nothing else: `psph run --overwrite`
    then leaves no snapshot, checkpoint or log line of the run it replaces (a shorter run would otherwise sit
    beside the older run's later snapshots, and a restart could pick the older run's checkpoint). Files in
    `keep` (the log the user named with --log, already started) stay."""
    for path in _own_outputs(directory, keep):
        path.unlink()


# where `psph run --overwrite` keeps the run it replaces until the new one has set up
REPLACED = ".psph_replaced"


def set_aside_results(directory, keep=()):
    """Move psph's own output in `directory` (what clear_results would remove) into directory/REPLACED, to
    be put back by restore_results if the new run is refused while it sets up (bad input found late: a fill
    region holding no lattice node, a pre-procedure that leaves nothing for iips.beta to scale; a fuzzing
    audit found the old results deleted by then), or removed by discard_results once it has set up.
    Returns that directory, or None if nothing was there (a REPLACED left over is removed all the same)."""
    d = Path(directory)
    outputs = _own_outputs(d, keep)
    if outputs:
        return _set_aside(d, move=outputs)
    _remove_stale_aside(d)
    return None


# what a continuation leaves as it is until it has set up: the snapshots and checkpoints up to its checkpoint
UNTOUCHED = re.compile(r"(snapshot|checkpoint)_\d{6,}\.h5")


def set_aside_for_continuation(directory, later, keep=()):
    """An in-place continuation: into directory/REPLACED, move what the directory holds past the checkpoint
    (`later`, io.checkpoint.results_after's, which the continuation replaces) and copy the series it rewrites
    while it sets up (every own output but the snapshots and checkpoints: history.csv and psph.xdmf from the
    checkpoint's, the log it appends to), for restore_results(..., clear=False) to put back if it is refused
    while it sets up, or discard_results to remove once it has. Refused, it had removed every result there, the
    checkpoint it continued included (a restarts audit), and the results past the checkpoint before it.
    Returns that directory."""
    d = Path(directory)
    later = {os.path.realpath(p) for p in later}
    outputs = _own_outputs(d, keep)
    return _set_aside(d, move=[p for p in outputs if os.path.realpath(p) in later],
                      copy=[p for p in outputs if os.path.realpath(p) not in later and not UNTOUCHED.fullmatch(p.name)])


def _set_aside(d, move=(), copy=()):
    """Move `move` and copy `copy` (paths in directory d or its figures/) into d/REPLACED, all or nothing: a
    failure part way (a full disk, a dangling link) moves back what it moved and removes REPLACED, then
    raises (it had left an in-place continuation's later results in REPLACED, which the next run removed: a
    review). A REPLACED left by a run killed while it set up holds the run before the one it replaced, and
    is removed first. Returns REPLACED."""
    aside = _remove_stale_aside(d)
    moved = []

    def target(path):
        out = aside / path.relative_to(d)
        out.parent.mkdir(parents=True, exist_ok=True)
        return out

    try:
        aside.mkdir()
        for path in move:
            kept = target(path)
            os.replace(path, kept)
            moved.append((kept, path))
        for path in copy:
            shutil.copy2(path, target(path), follow_symlinks=False)
    except BaseException:
        for kept, path in reversed(moved):
            os.replace(kept, path)
        shutil.rmtree(aside, ignore_errors=True)
        raise
    return aside


def _remove_stale_aside(d):
    """Remove d/REPLACED if a run killed while it set up left it (it holds the run before the one that run
    replaced); returns its path."""
    aside = d / REPLACED
    if aside.is_dir() and not aside.is_symlink():
        shutil.rmtree(aside)
    return aside


def restore_results(directory, aside, keep=(), clear=True) -> None:
    """Remove what the refused run wrote in `directory` (not with clear = False: a continuation's directory,
    whose results it has not replaced yet) and put back what set_aside_results (or set_aside_for_continuation)
    moved."""
    if clear:
        clear_results(directory, keep)
    if aside is None:
        return
    for path in sorted(p for p in Path(aside).rglob("*") if not p.is_dir()):
        target = Path(directory) / path.relative_to(aside)
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(path, target)
    shutil.rmtree(aside)


def discard_results(aside) -> None:
    """The new run has set up: the results it replaces go."""
    if aside is not None:
        shutil.rmtree(aside, ignore_errors=True)
