"""Point probes (`output.probes`): the fluid's pressure and velocity at fixed points of a flow, at every
history row, in OUT/probes.csv (time, then p_k, u_k, v_k[, w_k] for probe k of the list), as pressure
sensors and velocity probes of an experiment. Each value is the Shepard interpolation of the fluid
particles within a kernel support, sum_j f_j W(x_k - x_j) V_j / sum_j W(x_k - x_j) V_j
(diagnostics.interpolate_fluid), summed over the ranks, so it does not depend on their number; a probe with
no fluid within its support (dry, or behind a wall) reads nan. A restart keeps the rows up to its
checkpoint and writes the rest again.
"""

import numpy as np

from psph.diagnostics import interpolate_fluid
from psph.io.history import start_series

NAME = "probes.csv"


class Probes:
    def __init__(self, scene, out_dir=None, resumed_at=None):
        """out_dir: where probes.csv goes (None on every rank but one); resumed_at: a restart's time."""
        self.points = np.asarray(scene.output.probes, dtype=np.float64).reshape(-1, scene.domain.dimension)
        self.dim = scene.domain.dimension
        self.path = None if out_dir is None else out_dir / NAME
        self.said = ""  # what a restart did to the file's old rows (for the log)
        if self.path is not None:
            names = [f"{q}_{k}" for k in range(len(self.points)) for q in ("p", *"uvw"[: self.dim])]
            self.said = start_series(self.path, "time," + ",".join(names), resumed_at)

    def sample(self, system) -> np.ndarray:
        """(probes, 1 + d): pressure and velocity at every probe (nan where no fluid reaches). Collective."""
        p = system.particles
        values = np.concatenate([p.owned("pressure")[:, None], p.owned("velocity")], axis=1)
        return interpolate_fluid(system, values, self.points)

    def record(self, system, t) -> None:
        """Sample and append a row at time t (rank 0 writes). Collective."""
        values = self.sample(system)
        if self.path is not None:
            with open(self.path, "a") as f:
                f.write(f"{t!r}," + ",".join(f"{v:.10g}" for v in values.ravel()) + "\n")
