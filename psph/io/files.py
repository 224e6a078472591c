"""Atomic file writes (temporary file, fsync, rename) and output-directory housekeeping."""

import json
import os
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
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(text)
    replace_atomically(tmp, path)


def write_json_atomic(path, data) -> None:
    write_text_atomic(path, json.dumps(data, indent=2, sort_keys=True, default=jsonable) + "\n")


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


OUTPUT_MARKERS = ("summary.json", "history.csv", "psph.xdmf")


def holds_results(directory) -> bool:
    """True if `directory` already holds psph output (which a new run must not overwrite silently)."""
    d = Path(directory)
    if not d.is_dir():
        return False
    return any((d / m).exists() for m in OUTPUT_MARKERS) or any(d.glob("snapshot_*.h5"))
