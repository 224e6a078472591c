"""psph: distributed-memory SPH with implicit iterative particle shifting (IIPS) on PETSc."""

__version__ = "0.1.0"
