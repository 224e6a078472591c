"""history.csv (one row per output step or iteration) and summary.json, written by rank 0 atomically."""

import csv
import io
import math
import time
from pathlib import Path

from psph.io.files import write_json_atomic, write_text_atomic

HISTORY_NAME = "history.csv"
SUMMARY_NAME = "summary.json"


class History:
    """Diagnostics rows with a `time` column; the file is rewritten whole (temporary file + rename).

    Columns are fixed by the first row; later rows may not add columns (a programming error), except after
    a restart: a checkpoint written by an older psph may lack columns that this one writes, and its rows
    get empty cells there (also when that checkpoint was itself written after such a restart). By default
    the file is rewritten at most every `interval` seconds of wall time (and on `flush()`), so a run of
    many short iterations does not spend its time rewriting the file.
    """

    def __init__(self, comm, out_dir, interval=2.0):
        self.comm = comm
        self.path = Path(out_dir) / HISTORY_NAME
        self.columns = None
        self.rows = []
        self.interval = interval
        self._last_flush = -math.inf
        self._restored = False

    def append(self, row: dict, flush=None) -> None:
        """Add a row; flush=True writes now, False never, None when `interval` has passed."""
        if "time" not in row:
            raise KeyError("history rows need a 'time' column")
        if self.columns is None:
            self.columns = ["time"] + [k for k in row if k != "time"]
        elif set(row) - set(self.columns):
            if not self._restored:
                raise KeyError(f"history columns {sorted(set(row) - set(self.columns))} not in the first row")
            self.columns += [k for k in row if k not in self.columns]
        self.rows.append(dict(row))
        if flush or (flush is None and time.monotonic() - self._last_flush >= self.interval):
            self.flush()

    def restore(self, rows) -> None:
        """Continue from the rows of a checkpoint (restart); its own rows may already widen (a checkpoint
        written after an earlier restart from an older psph)."""
        self.columns = None
        self.rows = []
        self._restored = True
        for row in rows:
            self.append(row, flush=False)

    def flush(self) -> None:
        """Rewrite history.csv with every row so far (rank 0; others return)."""
        self._last_flush = time.monotonic()
        if self.comm.rank != 0 or self.columns is None:
            return
        buf = io.StringIO()
        writer = csv.DictWriter(buf, fieldnames=self.columns, restval="", lineterminator="\n")
        writer.writeheader()
        for row in self.rows:
            writer.writerow({k: _fmt(v) for k, v in row.items()})
        write_text_atomic(self.path, buf.getvalue())


def _fmt(value):
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else str(value)
    return value


def start_series(path, header: str, resumed_at=None) -> str:
    """Start a CSV time series at `path` (its first column is the time): with the `header` line only, or, on
    a restart at time `resumed_at`, with the rows up to it kept (the rows after it are written again). Rows
    that do not parse or have another column count (a line torn by a kill or a full disk) are dropped; a
    file with another header (the restart changed output.probes) keeps its rows up to the restart in
    NAME_upto_tT.csv (a name no file has), not mixed with the new columns. Returns what it did to the old
    rows, for the log ("" if nothing)."""
    path = Path(path)
    kept, said = [], ""
    if resumed_at is not None and path.exists():
        lines = path.read_text().splitlines()
        if lines and lines[0] != header:  # its rows up to the restart, under their own header, in a new file
            width = lines[0].count(",") + 1
            old = [r for r in lines[1:] if (t := _time_of(r, width)) is not None and t <= resumed_at]
            aside, k = path.with_name(f"{path.stem}_upto_t{resumed_at:g}{path.suffix}"), 1
            while aside.exists():
                k += 1
                aside = path.with_name(f"{path.stem}_upto_t{resumed_at:g}_{k}{path.suffix}")
            aside.write_text(lines[0] + "\n" + "".join(r + "\n" for r in old))
            said = f"{path.name} had other columns: its rows up to t = {resumed_at:g} are in {aside.name}"
        else:
            width = header.count(",") + 1
            good = [(r, t) for r in lines[1:] if (t := _time_of(r, width)) is not None]
            kept = [r for r, t in good if t <= resumed_at]
            if len(good) < len(lines) - 1:
                said = f"{path.name}: dropped {len(lines) - 1 - len(good)} damaged row(s)"
    path.write_text(header + "\n" + "".join(r + "\n" for r in kept))
    return said


def _time_of(row: str, width: int):
    """The time of a CSV row of `width` fields whose every field is a number, or None."""
    fields = row.split(",")
    try:
        values = [float(v) for v in fields]
    except ValueError:
        return None
    return values[0] if len(fields) == width else None


def read_history(path) -> list:
    """Rows of a history.csv as dicts of floats (empty cells -> None)."""
    with open(path, newline="") as f:
        return [{k: (float(v) if v not in ("", None) else None) for k, v in row.items()}
                for row in csv.DictReader(f)]


def write_summary(comm, out_dir, summary: dict) -> None:
    """summary.json (rank 0): wall_time_s, ranks, n_particles, steps, final diagnostics, ..."""
    if comm.rank == 0:
        write_json_atomic(Path(out_dir) / SUMMARY_NAME, summary)
