"""Recursive coordinate bisection (RCB) of the particles over the ranks of a communicator."""

from dataclasses import dataclass

import numpy as np

from psph.parallel.comm import allreduce_max, allreduce_min, allreduce_sum


@dataclass(frozen=True)
class Split:
    """Node of the bisection tree: ranks [rank_lo, rank_hi) split at `value` along `axis`."""

    rank_lo: int
    rank_hi: int
    rank_mid: int
    axis: int
    value: float


@dataclass(frozen=True)
class Decomposition:
    """The RCB tree and the box of every rank.

    boxes[r] = (lower, upper) of rank r; faces on the outer boundary of a non-periodic axis extend to
    +-inf, so a particle that leaves the domain there still has an owner (and is reported as escaped).
    """

    splits: tuple
    boxes: tuple

    def rank_of(self, pos: np.ndarray) -> np.ndarray:
        """Owner rank of every position (positions wrapped along periodic axes)."""
        n = len(pos)
        lo = np.zeros(n, dtype=np.int64)
        hi = np.full(n, len(self.boxes), dtype=np.int64)
        for s in self.splits:  # parents come before children
            mine = (lo == s.rank_lo) & (hi == s.rank_hi)
            left = mine & (pos[:, s.axis] < s.value)
            right = mine & ~left
            hi[left] = s.rank_mid
            lo[right] = s.rank_mid
        return lo


def _weighted_splits(comm, coords, weights, lo, hi, target, iterations=60):
    """Per node, a coordinate below which the global weight is `target` (bisection; collective).

    Nodes that match keep their value; ties of equal coordinates can make an exact match impossible,
    in which case the bracket's midpoint after `iterations` halvings is used.
    """
    value = np.full(len(coords), np.nan)
    for _ in range(iterations):
        mid = 0.5 * (lo + hi)
        below = allreduce_sum(comm, np.array([w[c < m].sum() for c, w, m in zip(coords, weights, mid)]))
        matched = np.isnan(value) & (np.abs(below - target) < 0.5)
        value[matched] = mid[matched]
        if not np.isnan(value).any():
            break
        too_many = below > target
        hi = np.where(too_many, mid, hi)
        lo = np.where(too_many, lo, mid)
    return np.where(np.isnan(value), 0.5 * (lo + hi), value)


def _split_axes(comm, pos, nodes):
    """Per node, the axis along which its particles spread furthest (collective).

    The particles' extent, not the box's: a thin layer at the bottom of a tall tank is cut across
    its length, not into thin slabs whose boundary every sloshing wave crosses (a parallel audit).
    A node without particles on any rank falls back to its box's longest side.
    """
    d = pos.shape[1]
    lows = np.array([pos[m].min(axis=0) if m.any() else np.full(d, np.inf) for *_, m in nodes]).reshape(-1, d)
    highs = np.array([pos[m].max(axis=0) if m.any() else np.full(d, -np.inf) for *_, m in nodes]).reshape(-1, d)
    extent = allreduce_max(comm, highs) - allreduce_min(comm, lows)
    return [int(np.argmax(e)) if np.isfinite(e).all() else int(np.argmax(b_hi - b_lo))
            for e, (_, _, b_lo, b_hi, _) in zip(extent, nodes)]


def _bisect_levels(comm, pos, domain, weights):
    """Build the split list level by level; every rank takes part in every split (collective)."""
    lower = np.asarray(domain.lower, dtype=np.float64)
    upper = np.asarray(domain.upper, dtype=np.float64)
    # a node: ranks [r_lo, r_hi), its box, and which local particles lie in it
    nodes = [(0, comm.size, lower, upper, np.ones(len(pos), dtype=bool))]
    splits, leaves = [], {}
    while nodes:
        for r_lo, r_hi, b_lo, b_hi, _ in nodes:
            if r_hi - r_lo == 1:
                leaves[r_lo] = (b_lo, b_hi)
        todo = [nd for nd in nodes if nd[1] - nd[0] > 1]
        if not todo:
            break
        axes = _split_axes(comm, pos, todo)
        totals = allreduce_sum(comm, np.array([weights[m].sum() for *_, m in todo], dtype=np.float64))
        fractions = np.array([((r_lo + r_hi) // 2 - r_lo) / (r_hi - r_lo) for r_lo, r_hi, *_ in todo])
        values = _weighted_splits(
            comm, [pos[m, a] for (*_, m), a in zip(todo, axes)], [weights[m] for *_, m in todo],
            np.array([nd[2][a] for nd, a in zip(todo, axes)]), np.array([nd[3][a] for nd, a in zip(todo, axes)]),
            np.round(totals * fractions))
        nodes = []
        for (r_lo, r_hi, b_lo, b_hi, member), a, v in zip(todo, axes, values):
            r_mid = (r_lo + r_hi) // 2
            splits.append(Split(r_lo, r_hi, r_mid, a, float(v)))
            left_hi, right_lo = b_hi.copy(), b_lo.copy()
            left_hi[a] = right_lo[a] = v
            below = pos[:, a] < v
            nodes += [(r_lo, r_mid, b_lo, left_hi, member & below), (r_mid, r_hi, right_lo, b_hi, member & ~below)]
    boxes = []
    for r in range(comm.size):
        b_lo, b_hi = (np.array(v, dtype=np.float64) for v in leaves[r])
        for a in range(domain.dim):
            if not domain.periodic[a]:
                if b_lo[a] <= lower[a]:
                    b_lo[a] = -np.inf
                if b_hi[a] >= upper[a]:
                    b_hi[a] = np.inf
        boxes.append((b_lo, b_hi))
    return tuple(splits), tuple(boxes)


def recursive_bisection(comm, pos: np.ndarray, domain, weights=None) -> Decomposition:
    """Balance particle counts (or `weights`) over the ranks by recursive coordinate bisection.

    Each split cuts the current node's particles across their longest extent at the weighted median.
    Collective; the positions are this rank's particles (wrapped into the domain).
    """
    if weights is None:
        weights = np.ones(len(pos), dtype=np.float64)
    splits, boxes = _bisect_levels(comm, pos, domain, np.asarray(weights, dtype=np.float64))
    return Decomposition(splits=splits, boxes=boxes)
