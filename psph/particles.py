"""Particle container: structure of arrays, owned particles first, then halo copies."""

from dataclasses import dataclass, field
from enum import IntEnum

import numpy as np


class Kind(IntEnum):
    """What a particle is. Only FLUID particles are unknowns of the shifting; the others stay fixed."""

    FLUID = 0
    WALL = 1
    BODY = 2
    INLET = 3
    OUTLET = 4
    FREE_SURFACE = 5
    FRAME = 6  # fixed particles closing a free surface during the particle packing (removed after it)


# solvers' working state (IIPS's best, first and backtracked steps): checkpoints keep these fields, snapshots
# leave them out (FieldSpec.scratch; a checkpoint's fields get the flag back by name)
SCRATCH_FIELDS = ("iips_best_shift", "iips_first_step", "iips_step")


@dataclass(frozen=True)
class FieldSpec:
    """A per-particle field: `shape` is () for scalars, ("d",) for vectors, ("d", "d") for tensors.
    scratch: a solver's working state, which checkpoints keep and snapshots (what ParaView shows) leave out."""

    name: str
    shape: tuple = ()
    dtype: type = np.float64
    scratch: bool = field(default=False, compare=False)

    def array_shape(self, n: int, dim: int) -> tuple:
        return (n,) + tuple(dim if s == "d" else int(s) for s in self.shape)


CORE_FIELDS = (
    FieldSpec("position", ("d",)),
    FieldSpec("gid", (), np.int64),
    FieldSpec("kind", (), np.int8),
    FieldSpec("volume", ()),
)


class ParticleSet:
    """Fields of the particles one rank holds: rows [0, n_owned) are owned, [n_owned, n_local) halo.

    Every field is a numpy array with one row per local particle. Fields are registered with
    `add_field`; asking for an unknown field raises KeyError naming it.
    """

    def __init__(self, dim: int, specs=CORE_FIELDS):
        self.dim = dim
        self.n_owned = 0
        self.n_halo = 0
        self.specs: dict[str, FieldSpec] = {}
        self._arrays: dict[str, np.ndarray] = {}
        for spec in specs:
            self.add_field(spec)

    # ----------------------------------------------------------------- fields
    def add_field(self, spec: FieldSpec, fill=0) -> None:
        """Register a field (no-op if already there with the same spec)."""
        if spec.name in self.specs:
            if self.specs[spec.name] != spec:
                raise ValueError(f"field {spec.name!r} already registered with another shape or type")
            self.specs[spec.name] = spec  # (a checkpoint's field learns that it is scratch)
            return
        self.specs[spec.name] = spec
        self._arrays[spec.name] = np.full(spec.array_shape(self.n_local, self.dim), fill, dtype=spec.dtype)

    def remove_field(self, name: str) -> None:
        """Forget field `name` (no-op if absent)."""
        self.specs.pop(name, None)
        self._arrays.pop(name, None)

    def __contains__(self, name: str) -> bool:
        return name in self._arrays

    def __getitem__(self, name: str) -> np.ndarray:
        """All local rows (owned + halo) of field `name`."""
        try:
            return self._arrays[name]
        except KeyError:
            raise KeyError(f"no particle field {name!r} (have: {', '.join(sorted(self._arrays))})") from None

    def __setitem__(self, name: str, value) -> None:
        arr = self[name]
        arr[...] = value

    def owned(self, name: str) -> np.ndarray:
        """Owned rows of field `name` (a view)."""
        return self[name][: self.n_owned]

    @property
    def names(self) -> tuple:
        return tuple(self._arrays)

    @property
    def n_local(self) -> int:
        return self.n_owned + self.n_halo

    # ------------------------------------------------------------ resizing
    def set_owned(self, arrays: dict) -> None:
        """Replace the owned particles by `arrays` (one entry per field); drops the halo."""
        missing = set(self._arrays) - set(arrays)
        if missing:
            raise KeyError(f"set_owned misses fields {sorted(missing)}")
        n = len(arrays["gid"])
        for name, spec in self.specs.items():
            arr = np.ascontiguousarray(arrays[name], dtype=spec.dtype)
            if arr.shape != spec.array_shape(n, self.dim):
                raise ValueError(f"field {name!r}: shape {arr.shape}, expected {spec.array_shape(n, self.dim)}")
            self._arrays[name] = arr
        self.n_owned = n
        self.n_halo = 0

    def append_owned(self, arrays: dict, fill=None) -> None:
        """Append owned particles (drops the halo): fields in `arrays` take those values, the others
        fill[name] (default 0)."""
        n = len(arrays["gid"])
        fill = fill or {}
        rows = {}
        for name, spec in self.specs.items():
            extra = arrays.get(name)
            if extra is None:
                extra = np.full(spec.array_shape(n, self.dim), fill.get(name, 0), dtype=spec.dtype)
            rows[name] = np.concatenate([self._arrays[name][: self.n_owned], np.asarray(extra, dtype=spec.dtype)])
        self.set_owned(rows)

    def set_halo(self, arrays: dict, n_halo: int) -> None:
        """Append `n_halo` halo rows: fields in `arrays` take those values, the others zeros."""
        for name, spec in self.specs.items():
            owned = self._arrays[name][: self.n_owned]
            halo = arrays.get(name)
            if halo is None:
                halo = np.zeros(spec.array_shape(n_halo, self.dim), dtype=spec.dtype)
            self._arrays[name] = np.concatenate([owned, np.asarray(halo, dtype=spec.dtype)])
        self.n_halo = n_halo

    def owned_arrays(self) -> dict:
        """Copies of the owned rows of every field."""
        return {name: arr[: self.n_owned].copy() for name, arr in self._arrays.items()}

    def permute_owned(self, order: np.ndarray) -> None:
        """Reorder owned rows (drops the halo)."""
        self.set_owned({name: arr[: self.n_owned][order] for name, arr in self._arrays.items()})
