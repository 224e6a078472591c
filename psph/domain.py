"""The computational box: bounds and periodicity."""

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Domain:
    """Axis-aligned box [lower, upper) with per-axis periodicity.

    Along a periodic axis positions are wrapped into [lower, upper); along a non-periodic axis the box
    only bounds where particles may be (walls included) and a particle outside it has escaped.
    """

    lower: tuple
    upper: tuple
    periodic: tuple
    margin: float = 0.0  # how far outside the box particles (walls) may sit along non-periodic axes
    outflow: tuple = ()  # (axis, side) of the open faces, side -1 lower / +1 upper: leaving there is no escape

    @property
    def dim(self) -> int:
        return len(self.lower)

    @property
    def length(self) -> np.ndarray:
        return np.asarray(self.upper, dtype=np.float64) - np.asarray(self.lower, dtype=np.float64)

    def wrap(self, pos: np.ndarray) -> None:
        """Wrap positions into the box along periodic axes, in place."""
        lo = np.asarray(self.lower)
        length = self.length
        for a in range(self.dim):
            if self.periodic[a]:
                pos[:, a] = lo[a] + np.mod(pos[:, a] - lo[a], length[a])
                # mod can return exactly `length` for tiny negative inputs
                pos[pos[:, a] >= self.upper[a], a] = lo[a]

    def outside(self, pos: np.ndarray) -> np.ndarray:
        """Mask of positions outside the box along non-periodic axes (escaped particles), past an outflow
        face excepted."""
        mask = np.zeros(len(pos), dtype=bool)
        for a in range(self.dim):
            if not self.periodic[a]:
                below = pos[:, a] < self.lower[a] - self.margin
                above = pos[:, a] > self.upper[a] + self.margin
                mask |= (below & ((a, -1) not in self.outflow)) | (above & ((a, 1) not in self.outflow))
        return mask

    def past_outflow(self, pos: np.ndarray, tie: float = 0.0) -> np.ndarray:
        """Mask of positions more than `tie` past an outflow face."""
        mask = np.zeros(len(pos), dtype=bool)
        for a, side in self.outflow:
            mask |= pos[:, a] < self.lower[a] - tie if side < 0 else pos[:, a] > self.upper[a] + tie
        return mask

    def with_images(self, pos: np.ndarray, reach: float) -> tuple:
        """(positions, rows): `pos` (wrapped along the periodic axes) followed by the periodic images of those
        within `reach` of a periodic face (corners' and edges' too), and, for every one, the row of `pos` it
        is of: a sum over the particles within `reach` of a point of the box, images included, is then one
        over these positions."""
        out = np.array(pos, dtype=np.float64)
        self.wrap(out)
        rows = np.arange(len(out))
        length = self.length
        for a in range(self.dim):
            if self.periodic[a]:
                low = out[:, a] < self.lower[a] + reach
                high = out[:, a] >= self.upper[a] - reach
                shifted = [out[low] + length[a] * np.eye(self.dim)[a], out[high] - length[a] * np.eye(self.dim)[a]]
                out = np.concatenate([out, *shifted])
                rows = np.concatenate([rows, rows[low], rows[high]])
        return out, rows

    def minimum_image(self, dx: np.ndarray) -> np.ndarray:
        """Displacement vectors reduced to the nearest periodic image (a copy)."""
        out = np.array(dx, dtype=np.float64)
        length = self.length
        for a in range(self.dim):
            if self.periodic[a]:
                out[..., a] -= length[a] * np.round(out[..., a] / length[a])
        return out
