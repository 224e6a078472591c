"""Solvers built on PETSc objects (every one with an options prefix)."""
