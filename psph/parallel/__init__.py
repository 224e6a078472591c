"""Parallel layer: decomposition, migration, halo exchange, ordering, reductions (all collective)."""
