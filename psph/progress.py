"""Progress of a time loop on rank 0: simulated time, step, dt, Newton and KSP iterations, and the ETA.

On a terminal a tqdm bar over simulated time; otherwise (a batch job's log) a plain line every `every`
seconds of wall time, with the ETA extrapolated from the simulated time advanced so far.
"""

import sys
import time


class Progress:
    def __init__(self, comm, t_start, t_end, enabled=True, every=10.0, stream=None):
        self.on = enabled and comm.rank == 0 and t_end > t_start
        self.t_start, self.t_end = t_start, t_end
        self.every = every
        self.stream = stream or sys.stderr
        self.started = time.monotonic()
        self.last = self.started
        self.bar = None
        if self.on and self.stream.isatty():
            import shutil

            from tqdm import tqdm

            columns = shutil.get_terminal_size().columns or 100  # a pseudo-terminal may report 0
            self.bar = tqdm(total=t_end - t_start, unit="t", file=self.stream, ncols=columns,
                            bar_format="{l_bar}{bar}| t {n:.4g}/{total:.4g} [{elapsed}<{remaining}{postfix}]")

    def update(self, step, t, dt, **counts) -> None:
        """After a step: counts are cumulative iteration counts (e.g. newton=..., ksp=...)."""
        if not self.on:
            return
        extra = ", ".join(f"{k} {v}" for k, v in counts.items())
        if self.bar is not None:
            self.bar.n = min(t - self.t_start, self.bar.total)
            self.bar.set_postfix_str(f"step {step}, dt {dt:.3g}" + (f", {extra}" if extra else ""), refresh=False)
            self.bar.refresh()
            return
        now = time.monotonic()
        if now - self.last < self.every:
            return
        self.last = now
        done = (t - self.t_start) / (self.t_end - self.t_start)
        eta = (now - self.started) * (1.0 - done) / done if done > 0 else float("inf")
        print(f"t = {t:.5g} / {self.t_end:.5g} ({100 * done:.1f}%), step {step}, dt {dt:.3g}"
              + (f", {extra}" if extra else "") + f", ETA {format_duration(eta)}", file=self.stream, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
            self.bar = None


def format_duration(seconds: float) -> str:
    if seconds == float("inf"):
        return "?"
    seconds = int(round(seconds))
    h, rest = divmod(seconds, 3600)
    m, s = divmod(rest, 60)
    return f"{h}h{m:02d}m{s:02d}s" if h else (f"{m}m{s:02d}s" if m else f"{s}s")
