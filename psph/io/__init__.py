"""Output: snapshots, XDMF, history and summary files."""
