"""Compute kernels: numba functions over flat arrays and CSR neighbour lists; they never communicate.

numba's on-disk cache (cache=True) of a function is keyed on its own file's time stamp only, not on the
files of the functions it inlines: after an edit of smoothing.py (or a `git pull` that changes it), the
kernels of sums.py would be loaded compiled with the old kernel functions. The cache therefore goes in a
directory named after a hash of this package's sources that use numba, and numba's version, set here
before any kernel is defined (unless NUMBA_CACHE_DIR is set): in $XDG_CACHE_HOME (or ~/.cache)
psph/numba-HASH, or, where that cannot be written (a read-only install with no home, where numba's own
choice, beside the sources, failed every command), in the temporary directory.
"""

import hashlib
import os
import tempfile
from pathlib import Path


def _cache_dir(digest: str):
    """The first usable of the user's cache and the temporary directory, with psph's subdirectory for
    `digest`; None if neither is. psph's directory must be this user's and writable by no one else: numba's
    index files are pickles, and a directory another user made first in the shared temporary directory
    could hand this process theirs."""
    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    uid = os.getuid()
    for base in (os.path.join(home, "psph"), os.path.join(tempfile.gettempdir(), f"psph-{uid}")):
        path = os.path.join(base, f"numba-{digest}")
        try:
            os.makedirs(path, mode=0o700, exist_ok=True)
            mine = [os.stat(p) for p in (base, path)]
        except OSError:
            continue
        if all(s.st_uid == uid and not s.st_mode & 0o022 for s in mine) and os.access(path, os.W_OK | os.X_OK):
            return path
    return None


def _use_versioned_cache() -> None:
    import numba
    from numba.core import config

    if os.environ.get("NUMBA_CACHE_DIR"):  # the user's choice
        return
    digest = hashlib.sha256(numba.__version__.encode())
    for source in sorted(Path(__file__).parent.glob("*.py")):
        text = source.read_bytes()
        if b"from numba" in text or b"import numba" in text:  # (not warmup.py, which only calls them)
            digest.update(source.name.encode() + b"\0" + text)
    path = _cache_dir(digest.hexdigest()[:16])
    if path is not None:
        config.CACHE_DIR = path


_use_versioned_cache()
