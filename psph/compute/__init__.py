"""Compute kernels: numba functions over flat arrays and CSR neighbour lists; they never communicate."""
