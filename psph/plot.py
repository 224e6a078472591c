"""`psph plot OUT_DIR`: PNG figures of a run (particle fields of the last snapshot, diagnostics history, probes) or
of a study (a directory of runs: error against resolution and against wall time).

A run directory holds summary.json / history.csv / snapshots; a study directory holds run directories.
|grad C| is recomputed from the snapshot (positions and volumes) with the run's kernel on one rank.
"""

import json
import re
from pathlib import Path

import numpy as np

from psph.cli import MAX_LINE_POINTS
from psph.errors import UsageError

# the scenes' own diagnostics against their references come after the general ones (the drop's semi-axes and
# pressure, the dam break's front and column, the jet's stagnation pressure, an open flow's mass budget)
HISTORY_COLUMNS = ("kinetic_energy", "L2_vx_error", "kinetic_energy_error", "max_density_variation", "volume_error",
                   "L2_grad_c", "Linf_grad_c", "L2_dfdx", "max_speed", "dt", "iips_newton", "cd_pressure",
                   "cl_pressure", "semi_axis_error", "L2_pressure_error", "front_x", "column_height",
                   "stagnation_pressure", "mass_balance_error")
ERROR_KEYS = ("L2_vx_error", "semi_axis_error", "L2_dfdx", "L2_grad_c")  # a study's error: the first a run has


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(plt, fig, path: Path, title=None) -> Path:
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _summary(run_dir: Path) -> dict:
    path = run_dir / "summary.json"
    try:
        summary = json.loads(path.read_text())
    except ValueError as exc:  # JSONDecodeError, or bytes that are not UTF-8
        raise UsageError(f"{str(path)!r} is not a psph summary: {exc}") from None
    if not isinstance(summary, dict):
        raise UsageError(f"{str(path)!r} is not a psph summary: a JSON {type(summary).__name__}, not an object")
    return summary


def _history(path: Path) -> list:
    from psph.io.history import read_history

    try:
        rows = read_history(path)
    except (ValueError, TypeError) as exc:  # a cell that is not a number; a row longer than the header
        raise UsageError(f"{str(path)!r} is not a psph history: {exc}") from None
    if rows and "time" not in rows[0]:  # (a plot audit: a KeyError, "internal error")
        raise UsageError(f"{str(path)!r} is not a psph history: no time column")
    return rows


def plot(out_dir, fig_dir=None, warn=print, line=None, points=None) -> list:
    """Write the figures for a run or a study directory; returns the PNG paths. A file that cannot be read
    (a truncated snapshot, a damaged summary or history) or written (a full disk, --figures naming a file) is
    a UsageError naming it; a run's figure that has nothing to show is left out with a line to `warn`, and a
    run with no figure at all is a UsageError. `line`: a run's segment to cut at `points` points (plot_line),
    which is then the only figure."""
    out_dir = Path(out_dir)
    if not out_dir.is_dir():
        raise UsageError(f"{str(out_dir)!r} is not a directory")
    fig_dir = Path(fig_dir) if fig_dir else out_dir / "figures"
    try:
        if line is not None:
            return [plot_line(out_dir, fig_dir, line, points)]
        return _plot(out_dir, fig_dir, warn)
    except OSError as exc:
        where = f" ({exc.filename})" if exc.filename and str(exc.filename) not in str(exc) else ""
        raise UsageError(f"psph plot {str(out_dir)!r}: {' '.join(str(exc).split())}{where}") from None


def _plot(out_dir: Path, fig_dir: Path, warn) -> list:
    runs = sorted(d for d in out_dir.iterdir() if (d / "summary.json").is_file())
    if (out_dir / "history.csv").is_file():
        fig_dir.mkdir(parents=True, exist_ok=True)
        history = plot_history(out_dir, fig_dir)
        written = [p for p in (history, plot_fields(out_dir, fig_dir), plot_probes(out_dir, fig_dir)) if p]
        if not written:
            raise UsageError(f"nothing to plot in {str(out_dir)!r}: its history.csv holds no diagnostics and it "
                             f"holds no 1-D or 2-D snapshot")
        if history is None:
            warn(f"{str(out_dir / 'history.csv')!r} holds no diagnostics (no row, or none of the columns plotted): "
                 f"no history.png")
        return written
    if runs:
        fig_dir.mkdir(parents=True, exist_ok=True)
        return plot_study(runs, fig_dir)
    if any(out_dir.glob("snapshot_*.h5")):  # a run stopped before its history's first row (at step 0, packing)
        fig_dir.mkdir(parents=True, exist_ok=True)
        fields = plot_fields(out_dir, fig_dir)
        if fields is None:
            raise UsageError(f"nothing to plot in {str(out_dir)!r}: no history.csv, and no 1-D or 2-D snapshot")
        warn(f"{str(out_dir)!r} holds no history.csv (the run stopped before its first row): fields.png only")
        return [fields]
    raise UsageError(f"{str(out_dir)!r} holds neither a run (history.csv) nor runs (*/summary.json)")


def _values(rows, column) -> np.ndarray:
    """A history or probes column as floats, NaN where a cell is empty (a row cut short, a value not measured)."""
    return np.array([np.nan if r.get(column) is None else r[column] for r in rows], dtype=float)


def _shown(rows, column) -> bool:
    """Whether history.png draws `column`: it has a finite value (an all-NaN column drew an empty panel, with
    numpy's warning), and iips_newton only if IIPS ever iterated (a plot audit)."""
    y = _values(rows, column)
    finite = y[np.isfinite(y)]
    if column == "iips_newton":
        return bool(np.any(finite != 0.0))
    return finite.size > 0


def plot_history(run_dir: Path, fig_dir: Path):
    rows = _history(run_dir / "history.csv")
    columns = [c for c in HISTORY_COLUMNS if rows and c in rows[0] and _shown(rows, c)]
    if not columns:
        return None
    plt = _pyplot()
    n = len(columns)
    ncol = min(n, 3)
    fig, axes = plt.subplots((n + ncol - 1) // ncol, ncol, figsize=(4.2 * ncol, 3.0 * ((n + ncol - 1) // ncol)),
                             squeeze=False)
    t = _values(rows, "time")
    for ax, c in zip(axes.flat, columns):
        y = _values(rows, c)
        if c == "dt":
            y[y == 0.0] = np.nan  # (the t = 0 row's: no step yet)
        finite = y[np.isfinite(y)]
        positive = finite.size > 0 and finite.min() > 0 and finite.max() / max(finite.min(), 1e-300) > 100
        # (markers where a line has too few points to be seen: a static run's single row)
        (ax.semilogy if positive else ax.plot)(t, y, marker="o" if np.isfinite(y).sum() < 3 else None)
        ax.set_title(c, fontsize=9)
        ax.set_xlabel("time (iteration for static runs)", fontsize=8)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    return _save(plt, fig, fig_dir / "history.png", f"{run_dir.name}: diagnostics history")


def plot_probes(run_dir: Path, fig_dir: Path):
    """probes.png: pressure and speed at every probe (output.probes) against time; None without probes."""
    from psph.probes import NAME

    if not (run_dir / NAME).is_file():
        return None
    rows = _history(run_dir / NAME)
    if not rows:
        return None
    plt = _pyplot()
    fig, (ax_p, ax_u) = plt.subplots(1, 2, figsize=(9.0, 3.4))
    t = _values(rows, "time")
    for k in range(sum(c.startswith("p_") for c in rows[0])):
        velocity = [c for c in rows[0] if c[0] in "uvw" and c[1:] == f"_{k}"]
        ax_p.plot(t, _values(rows, f"p_{k}"), label=f"probe {k}")
        ax_u.plot(t, np.sqrt(sum(_values(rows, c) ** 2 for c in velocity)), label=f"probe {k}")
    for ax, what in ((ax_p, "pressure"), (ax_u, "speed")):
        ax.set_xlabel("time", fontsize=8)
        ax.set_title(what, fontsize=9)
        ax.legend(fontsize=7)
    return _save(plt, fig, fig_dir / "probes.png", f"{run_dir.name}: probes (output.probes)")


def _run_scene_table(run_dir: Path):
    """The run's scene (a table): summary.json's, or a stopped run's newest checkpoint's, or its last snapshot's
    (a run in progress; a plot audit: --line refused it, fields.png left |grad C| h out); None without any."""
    if (run_dir / "summary.json").is_file():
        return _summary(run_dir)["scene"]
    from psph.io.checkpoint import latest_checkpoint
    from psph.io.snapshots import h5py, snapshot_files

    path = latest_checkpoint(run_dir)
    if path is not None:
        with h5py.File(path) as f:
            return json.loads(bytes(f["state"][()]).decode())["scene"]
    snapshots = snapshot_files(run_dir)
    if not snapshots:
        return None
    try:
        with h5py.File(snapshots[-1]) as f:
            scene = f.attrs.get("scene")
    except OSError:  # (a damaged snapshot: _last_snapshot names it)
        return None
    return json.loads(scene) if scene is not None else None  # (an older psph's snapshot: none)


def _grad_c_magnitude(run_dir: Path, data: dict):
    """|grad C| h of the snapshot's particles (serial system with the run's kernel), or None."""
    from mpi4py import MPI

    from psph.compute.smoothing import make_kernel
    from psph.diagnostics import grad_c
    from psph.particles import ParticleSet
    from psph.scene.load import scene_from_table
    from psph.simulation import make_domain
    from psph.system import ParticleSystem

    n = len(data["gid"])
    volume = data.get("volume", np.ones(n))
    table = _run_scene_table(run_dir)
    if table is None or not (np.isfinite(data["position"]).all() and np.isfinite(volume).all()):
        return None  # a failed run's state: a NaN position would stall the neighbour search
    scene = scene_from_table(table)
    d = scene.domain
    particles = ParticleSet(d.dimension)
    particles.set_owned({"position": data["position"], "gid": data["gid"], "kind": data["kind"],
                         "volume": data.get("volume", np.full(n, d.dx ** d.dimension))})
    system = ParticleSystem(MPI.COMM_SELF, make_domain(scene), make_kernel(d.kernel, d.dimension, d.h), particles,
                            skin=scene.neighbours.skin)
    g = np.linalg.norm(grad_c(system), axis=1) * d.h
    order = np.argsort(system.particles.owned("gid"))
    out = np.empty(n)
    out[np.searchsorted(data["gid"], system.particles.owned("gid")[order])] = g[order]
    return out


def shown_fields(run_dir: Path, data: dict) -> dict:
    """The fields fields.png shows of a snapshot's particles, by their titles."""
    fields = {}
    if "velocity" in data:
        fields["|velocity|"] = np.linalg.norm(data["velocity"], axis=1)
    if "pressure" in data:
        fields["pressure"] = data["pressure"]
    if "grad_c" in data:  # (stored unscaled: a diagnostics audit found it shown as |grad C| h, 1/h times too high)
        table = _run_scene_table(run_dir)
        h = table["domain"]["dx"] * table["domain"]["h_over_dx"] if table is not None else None
        fields["|grad C| h" if h else "|grad C|"] = np.linalg.norm(data["grad_c"], axis=1) * (h or 1.0)
    else:
        fields["|grad C| h"] = _grad_c_magnitude(run_dir, data)
    if "volume0" in data:
        fields["V / V0 - 1"] = data["volume"] / data["volume0"] - 1.0
    return {k: v for k, v in fields.items() if v is not None}


def _last_snapshot(run_dir: Path) -> tuple:
    """(fields, time) of the run's last snapshot (studies.last_snapshot), checked: a file that cannot be read,
    lacks gid, kind, position or its time, or holds fields of other lengths than its gids is an error naming
    it (a review: a KeyError or a broadcast error, "internal error")."""
    from psph.io.snapshots import snapshot_files
    from psph.studies import last_snapshot

    name = snapshot_files(run_dir)[-1].name
    try:
        data, t = last_snapshot(run_dir)
    except OSError as exc:
        raise OSError(f"cannot read the last snapshot {name}: {exc}") from None
    except (KeyError, ValueError, TypeError, AttributeError) as exc:  # (no particles group or time; a
        # scalar or a group where a field should be; a time that is no number: a review)
        raise UsageError(f"the last snapshot {name} is not a psph snapshot: {' '.join(str(exc).split())}") \
            from None
    missing = [key for key in ("gid", "kind", "position") if key not in data]
    if missing:
        raise UsageError(f"the last snapshot {name} is not a psph snapshot: no {', '.join(missing)}")
    n = len(data["gid"])
    for key, values in data.items():
        values = np.asarray(values)
        if values.ndim == 0 or len(values) != n or values.dtype.kind not in "biuf":
            raise UsageError(f"the last snapshot {name} is damaged: {key} holds "
                             + (f"{len(values)} rows for {n} particles" if values.ndim and len(values) != n else
                                f"{values.dtype} values of shape {values.shape}"))
    if data["position"].ndim != 2 or not 1 <= data["position"].shape[1] <= 3:
        raise UsageError(f"the last snapshot {name} is damaged: position of shape {data['position'].shape}")
    return data, t


def plot_fields(run_dir: Path, fig_dir: Path):
    from psph.io.snapshots import snapshot_files

    if not snapshot_files(run_dir):
        return None
    data, t = _last_snapshot(run_dir)
    pos = data["position"]
    if pos.shape[1] == 3:
        return None  # 3-D: ParaView (OUT/psph.xdmf)
    from psph.particles import Kind

    fields = shown_fields(run_dir, data)
    plt = _pyplot()
    n = len(fields)
    fig, axes = plt.subplots(1, n, figsize=(4.6 * n, 4.2), squeeze=False)
    placed = np.isfinite(pos).all(axis=1)
    # the fluid's values only: walls, bodies and buffers hold stand-ins (a plot audit: the cavity's outer wall
    # layers' |grad C| h of 0.91 set the colour scale of a fluid at 0.039, and the moving lid showed |u| = 0)
    fluid = data["kind"] == Kind.FLUID
    solid = placed & ~fluid
    size = max(0.5, 4000.0 / len(pos))
    for ax, (name, values) in zip(axes.flat, fields.items()):
        # a failed run's last snapshot holds the state at the failure, possibly with non-finite values
        shown = placed & fluid & np.isfinite(values)
        left_out = int(np.count_nonzero(fluid)) - int(np.count_nonzero(shown))
        if not shown.any():
            ax.axis("off")
        elif pos.shape[1] == 1:
            ax.plot(pos[shown, 0], values[shown], ".", ms=2)
        else:
            if solid.any():  # where the solids and buffers are, uncoloured
                ax.scatter(pos[solid, 0], pos[solid, 1], c="0.8", s=size, linewidths=0)
            sc = ax.scatter(pos[shown, 0], pos[shown, 1], c=values[shown], s=size, cmap="viridis", linewidths=0)
            fig.colorbar(sc, ax=ax, shrink=0.8)
            ax.set_aspect("equal")
        ax.set_title(name + (f" ({left_out} non-finite left out)" if left_out else ""), fontsize=10)
    table = _run_scene_table(run_dir)
    static = table is not None and table.get("physics", {}).get("scheme") == "none"  # (its time: the iteration)
    when = f"iteration {t:g}" if static else f"t = {t:.4g}"
    return _save(plt, fig, fig_dir / "fields.png", f"{run_dir.name}: last snapshot, {when}")


LINE_FIELDS = ("pressure", "density", "velocity")  # what a line cut samples, where a snapshot holds them


def plot_line(run_dir: Path, fig_dir: Path, ends, points: int) -> Path:
    """line.png and line.csv: the pressure, density and velocity of the last snapshot along the segment
    `ends` = (x0, y0[, z0], x1, y1[, z1]) at `points` evenly spaced points, each the Shepard interpolation
    of the fluid particles within a kernel support, sum_j f_j W_j V_j / sum_j W_j V_j, with the run's kernel
    and periodic images (diagnostics.shepard_sums, as the probes are sampled); nan where no fluid reaches.
    The csv's columns: s (the distance from the first end), the point, then the fields."""
    from psph.compute.smoothing import make_kernel
    from psph.diagnostics import shepard_sums
    from psph.io.snapshots import snapshot_files
    from psph.particles import Kind
    from psph.scene.load import scene_from_table
    from psph.simulation import make_domain

    table = _run_scene_table(run_dir)
    if table is None or not snapshot_files(run_dir):
        raise UsageError(f"--line: {str(run_dir)!r} holds no snapshot of a run to cut")
    scene = scene_from_table(table)
    d = scene.domain
    if len(ends) != 2 * d.dimension:
        raise UsageError(f"--line: a {d.dimension}-D run's segment takes {2 * d.dimension} numbers (its two ends' "
                         f"coordinates), got {len(ends)}")
    ends = np.asarray(ends, dtype=np.float64).reshape(2, d.dimension)
    if not np.isfinite(ends).all():
        raise UsageError(f"--line: the ends' coordinates must be finite numbers, got {ends.ravel().tolist()}")
    if np.array_equal(ends[0], ends[1]) or not 2 <= points <= MAX_LINE_POINTS:
        raise UsageError("--line: the two ends coincide" if 2 <= points <= MAX_LINE_POINTS else
                         f"argument --points: a line takes 2 to {MAX_LINE_POINTS} points, got {points}")
    for a in range(d.dimension):
        outside = (ends[:, a] < d.lower[a] - 1e-12) | (ends[:, a] > d.upper[a] + 1e-12)
        if outside.any():
            raise UsageError(f"--line: the end {list(ends[int(np.argmax(outside))])} lies outside the domain along "
                             f"axis {a} ({d.lower[a]:g} .. {d.upper[a]:g})")
    data, t = _last_snapshot(run_dir)
    shapes = {key: data[key].shape for key in ("position", "velocity") if key in data}
    if any(shape[1:] != (d.dimension,) for shape in shapes.values()):
        raise UsageError(f"the last snapshot of {str(run_dir)!r} does not match its {d.dimension}-D scene: "
                         + ", ".join(f"{key} of shape {shape}" for key, shape in shapes.items()))
    if not len(data["gid"]):
        raise UsageError(f"--line: the last snapshot of {str(run_dir)!r} holds no particle")
    names = [f for f in LINE_FIELDS if f in data]
    if not names:
        raise UsageError(f"--line: the last snapshot of {str(run_dir)!r} holds none of {', '.join(LINE_FIELDS)} "
                         "(a static or kinematic run has no flow to cut)")
    columns = {"pressure": ["p"], "density": ["rho"], "velocity": list("uvw"[: d.dimension])}
    labels = [c for f in names for c in columns[f]]
    values = np.column_stack([data[f].reshape(len(data["gid"]), -1) for f in names])
    pos = data["position"]
    volume = data.get("volume", np.full(len(pos), d.dx ** d.dimension))
    fluid = (data["kind"] == Kind.FLUID) & np.isfinite(pos).all(axis=1) & np.isfinite(values).all(axis=1)
    s = np.linspace(0.0, 1.0, points)
    at = ends[0] + s[:, None] * (ends[1] - ends[0])
    num, den = shepard_sums(make_kernel(d.kernel, d.dimension, d.h), pos[fluid], values[fluid], volume[fluid], at,
                            make_domain(scene))
    with np.errstate(invalid="ignore", divide="ignore"):
        cut = num / den[:, None]
    if not np.isfinite(cut).any():
        raise UsageError(f"--line: no fluid particle lies within a kernel support ({d.support:g}) of the segment "
                         f"{ends.ravel().tolist()} at t = {t:.6g}")
    distance = s * np.linalg.norm(ends[1] - ends[0])
    header = ["s", *("xyz"[: d.dimension]), *labels]
    fig_dir.mkdir(parents=True, exist_ok=True)
    np.savetxt(fig_dir / "line.csv", np.column_stack([distance, at, cut]), delimiter=",", header=",".join(header),
               comments="", fmt="%.10g")
    plt = _pyplot()
    panels = [(f, [labels.index(c) for c in columns[f]]) for f in names]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.2 * len(panels), 3.4), squeeze=False)
    for ax, (name, cols) in zip(axes.flat, panels):
        for c in cols:
            ax.plot(distance, cut[:, c], label=labels[c])
        if len(cols) > 1:
            ax.legend(fontsize=7)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("distance along the line", fontsize=8)
        ax.set_xlim(distance[0], distance[-1])  # the whole segment, dry parts too (a plot audit)
    first, last = (", ".join(f"{v:.4g}" for v in e) for e in ends)
    return _save(plt, fig, fig_dir / "line.png", f"{run_dir.name}: t = {t:.4g}, from ({first}) to ({last})")


def study_error(final: dict):
    """The key of a run's error in a study (its summary's final row): the first of ERROR_KEYS it has, its
    reference's error before grad C (a drop's semi-axes, whose L2(grad C) without shifting covers the rim:
    0.41 against 0.04 with delta+, an audit), or None."""
    return next((k for k in ERROR_KEYS if final.get(k) is not None), None)


def plot_study(runs, fig_dir: Path) -> list:
    """Error against dx and against wall time, one line per method (run name without its _dx... part)."""
    groups = {}
    for run in runs:
        s = _summary(run)
        final = s.get("final", {})
        key = study_error(final)
        if key is None or "scene" not in s:
            continue
        method = re.sub(r"_?dx[0-9.e-]+", "", run.name) or run.name
        groups.setdefault((method, key), []).append((s["scene"]["domain"]["dx"], final[key], s["wall_time_s"]))
    if not groups:
        raise UsageError(f"no run in this directory reports an error (final {', '.join(ERROR_KEYS)})")
    plt = _pyplot()
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 4.2))
    for (method, key), points in sorted(groups.items()):
        points.sort()
        dx, err, wall = (np.array(v) for v in zip(*points))
        a.loglog(dx, err, "o-", label=f"{method} ({key})")
        b.loglog(wall, err, "o-", label=method)
    a.set_xlabel("dx")
    a.set_ylabel("error at the end")
    a.set_title("error against resolution")
    b.set_xlabel("wall time [s]")
    b.set_title("error against wall time")
    a.legend(fontsize=7)
    return [_save(plt, fig, fig_dir / "convergence.png")]
