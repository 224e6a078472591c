"""PETSc start-up: initialised once, with the command line's PETSc options, before any PETSc object."""

import atexit
import glob
import importlib.util
import itertools
import os
import sys
import weakref

_state = {"argv": None}
# objects to destroy before PETSc finalises, in the order they were registered (the same on every rank: a
# destroy is collective)
_live = weakref.WeakValueDictionary()
_registered = itertools.count()
# an empty vector on every communicator of several ranks that PETSc objects were made on (petsc_comm)
_anchors = {}


def _find_debian_petsc4py() -> None:
    """Debian installs petsc4py under $PETSC_DIR/lib/python3/dist-packages and adds it to sys.path
    at start-up only when PETSC_DIR is set or /usr/lib/petsc exists; find it when neither holds."""
    if importlib.util.find_spec("petsc4py") is not None:
        return
    for petsc_dir in sorted(glob.glob("/usr/lib/petscdir/petsc*/*-real")):
        site = os.path.join(petsc_dir, "lib", "python3", "dist-packages")
        if os.path.isdir(os.path.join(site, "petsc4py")):
            os.environ.setdefault("PETSC_DIR", petsc_dir)
            sys.path.append(site)
            return


def initialize(options=(), comm=None) -> None:
    """Initialise petsc4py with `options` (e.g. ['-iips_pc_type', 'hypre', '-log_view']); comm: the ranks that
    start together (the command line's world), whose rank 0 reads an options file for all (check_viewer_files).

    Must run before `from petsc4py import PETSc` anywhere in the process; later calls with the same
    options are no-ops, with different options an error.
    """
    _find_debian_petsc4py()
    try:
        import petsc4py
    except ImportError:
        from psph.errors import PsphError

        raise PsphError("petsc4py is not installed: run run_scripts/setup.sh (Debian) or "
                        "`pip install petsc4py` with PETSC_DIR set (see README)") from None

    argv = [sys.argv[0] if sys.argv else "psph"] + list(options)
    if _state["argv"] is None:
        check_viewer_files(options, comm)
        try:
            petsc4py.init(argv)
        except Exception as err:  # petsc4py's Error, once PETSc has printed its own report (a fuzzing audit:
            from psph.errors import UsageError  # -options_file /nonexistent gave a traceback)

            code = getattr(err, "ierr", None)
            given = " ".join(options) or (f"of PETSC_OPTIONS={os.environ['PETSC_OPTIONS']!r}"
                                          if os.environ.get("PETSC_OPTIONS") else "(none)")
            refusal = UsageError(f"PETSc did not start with the options {given}"
                                 + (f": error code {code}" if code is not None else "")
                                 + " (PETSc's report above)")
            # one rank's, maybe: rank 0 alone reads an options file, and the others waited for it for ever (a
            # PETSc-options audit); the command line then ends every rank (cli)
            refusal.collective = False
            raise refusal from None
        _state["argv"] = argv
        check_started_viewer_files(comm)
        _ignore_sigpipe()
        release_freed_memory()
        atexit.register(_destroy_live)
    elif _state["argv"] != argv:
        raise RuntimeError("PETSc is already initialised with other options")


# options naming a file of options, which PETSc's rank 0 reads alone
OPTIONS_FILES = ("-options_file", "-options_file_yaml")
# viewer types whose second field names a file (PETSc's viewer syntax, `[type]:[file][:format][:mode]`)
FILE_VIEWERS = ("", "ascii", "binary", "hdf5", "vtk")


def check_viewer_files(options, comm=None) -> None:
    """Refuse an options file (`-options_file path`) that rank 0 cannot read, on every rank (PETSc's rank 0
    reads it alone: a missing one stopped rank 0 and left the others waiting for ever, a PETSc-options audit),
    and a viewer option (`-log_view :path`, `-iips_ksp_view ascii:path:ascii_info`,
    `-iips_ksp_converged_reason ascii:path`: any option whose value names a file viewer) whose file cannot be
    written, before the run: PETSc opens `-log_view`'s file only in PetscFinalize, after the run, where its
    error cannot change the exit status any more (a fuzzing audit: `-log_view :/bad/x` exited 0 with the
    profile lost), and the others' mid-run, after hours of work. A path holding PETSc's variables
    (`${WORKINGDIRECTORY}`), which PETSc expands, is left to PETSc."""
    from psph.errors import UsageError

    options = list(options)
    for name, value in zip(options, options[1:] + [""]):
        if name in OPTIONS_FILES and "${" not in value and not _rank_0_reads(value, comm):
            if not value or value.startswith("-"):
                raise UsageError(f"{name}: needs a file name")
            raise UsageError(f"{name} {value}: {value!r} is a directory" if os.path.isdir(value) else
                             f"{name} {value}: no file {value!r} to read")
    refused = _unwritable_viewers(options)
    if refused:
        raise UsageError(refused[0][1])


def _unwritable_viewers(options) -> list:
    """(name, message) of every option among `options` (names and values in turn) whose value names a file
    viewer (viewer_file), or a file (PLAIN_FILE_OPTIONS), that cannot be written."""
    refused = []
    for name, value in zip(options, options[1:] + [""]):
        fields = viewer_file(value) if name.startswith("-") and not value.startswith("-") else None
        if name in PLAIN_FILE_OPTIONS and value and not value.startswith("-"):
            fields = ["", value]
        if fields is None:
            continue
        path = fields[1]
        folder = os.path.dirname(os.path.abspath(path))
        if not os.path.isdir(folder) or not os.access(folder, os.W_OK | os.X_OK) or os.path.isdir(path):
            refused.append((name, f"{name} {value}: cannot write {path!r}"
                            + ("" if os.path.isdir(folder) else f" (no directory {folder!r})")))
    return refused


def check_started_viewer_files(comm=None) -> None:
    """check_viewer_files' viewer check over every option PETSc started with, those of an options file,
    PETSC_OPTIONS or ~/.petscrc too (a review: `-log_view :/no/dir/x` in an options file failed in
    PetscFinalize after the run, which then hung on 2 ranks and exited 0 on one), judged on rank 0 of comm,
    which writes -log_view's file. The refused options are removed, so that PetscFinalize does not try them
    again, and every rank raises the same UsageError, naming the first. Collective over comm."""
    from petsc4py import PETSc

    from psph.errors import UsageError
    from psph.parallel.comm import on_root

    database = PETSc.Options()
    flat = [item for name, value in database.getAll().items() for item in (f"-{name}", value or "")]
    refused = _unwritable_viewers(flat) if comm is None else on_root(comm, lambda: _unwritable_viewers(flat))
    for name, _ in refused:  # (a review: the second of two still failed in PetscFinalize)
        database.delValue(name[1:])
    if refused:  # (a review: only the first was named, though all were removed)
        raise UsageError("; ".join(message for _, message in refused) + " (option(s) PETSc read from an options "
                         "file, PETSC_OPTIONS or ~/.petscrc)")


# options whose value is a plain file name that PETSc writes: -malloc_view's when it finalises, after the run;
# -log_trace's (FILE.<rank>) at its start
PLAIN_FILE_OPTIONS = ("-malloc_view", "-log_trace")


def viewer_file(value):
    """PETSc's viewer syntax `[type]:[file][:format][:mode]`: its fields, four strings, where `value` names a
    file of a type FILE_VIEWERS lists, plainly (not through PETSc's variables, `${...}`); else None."""
    fields = (value.split(":") + ["", "", ""])[:4] if ":" in value else None
    if fields is None or fields[0] not in FILE_VIEWERS or not fields[1] or "${" in fields[1] \
            or fields[1] in ("stdout", "stderr"):  # (PETSc's names for the streams, not files: a review)
        return None
    return fields


def _rank_0_reads(path, comm=None) -> bool:
    """Whether rank 0 of `comm` (the ranks starting PETSc together; None: this process alone), the one PETSc
    reads an options file on, can read `path` (a readable file or pipe: not a directory). Collective over
    comm: a rank that does not see rank 0's file system would otherwise stop alone while rank 0 went on into
    PETSc's start."""
    from psph.parallel.comm import on_root

    def readable():
        return os.access(path, os.R_OK) and not os.path.isdir(path)

    return readable() if comm is None else on_root(comm, readable)


# glibc's mallopt parameters
M_TRIM_THRESHOLD, M_MMAP_THRESHOLD, M_MMAP_MAX = -1, -3, -4
MMAP_THRESHOLD = 32 * 2**20  # the largest threshold glibc's own dynamic rule reaches on 64-bit machines
TRIM_THRESHOLD = 64 * 2**20


def release_freed_memory() -> bool:
    """Let glibc give freed memory back to the system again, after PETSc's libraries were loaded; returns
    whether it could (False without glibc).

    Debian's PETSc links SuperLU_DIST, whose library constructor calls mallopt(M_MMAP_MAX, 0) and
    mallopt(M_TRIM_THRESHOLD, -1) (found with gdb, `break mallopt`, while petsc4py loads): from then on
    every allocation of the process comes from the heap and nothing freed is returned, so the resident size
    only grows, and a large array that replaces a slightly smaller one cannot reuse its place (a 3-D static
    IIPS run of 64 000 particles kept the pair storage of its first Newton iteration, 380 MiB, beside the
    second's). Blocks of MMAP_THRESHOLD and more are mapped on their own again, and given back when freed;
    the heap is trimmed when TRIM_THRESHOLD is free at its top. Calling mallopt at all turns glibc's
    dynamic thresholds off, which SuperLU_DIST's calls have already done."""
    import ctypes
    import platform

    if platform.libc_ver()[0] != "glibc":
        return False
    mallopt = ctypes.CDLL(None).mallopt
    return all(mallopt(param, value) == 1 for param, value in (
        (M_MMAP_THRESHOLD, MMAP_THRESHOLD), (M_MMAP_MAX, 65536), (M_TRIM_THRESHOLD, TRIM_THRESHOLD)))


def _ignore_sigpipe() -> None:
    """Give SIGPIPE back to Python. PETSc's signal handler (installed by PetscInitialize) aborts the run
    with "Caught signal number 13 Broken Pipe" when the reader of psph's output leaves (`psph run ... |
    head`); ignored, as Python has it, a write into the closed pipe raises BrokenPipeError, which the
    command line ends quietly (psph.cli)."""
    import signal
    import threading

    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGPIPE, signal.SIG_IGN)


def destroy_at_exit(obj) -> None:
    """Call obj.destroy() when Python exits, if obj is still alive then. petsc4py finalises PETSc after the
    interpreter has shut down, destroying the objects still alive: a KSP holding a Python matrix (the
    matrix-free IIPS operator) then calls into the dead interpreter, and the process ends with a
    segmentation fault. Python's own exit handlers run before that."""
    _live[next(_registered)] = obj


def _destroy_live() -> None:
    for key in sorted(_live.keys()):
        obj = _live.get(key)
        if obj is not None:
            obj.destroy()


def petsc():
    """The PETSc module, initialising with no options if nobody did."""
    if _state["argv"] is None:
        initialize(())
    from petsc4py import PETSc

    return PETSc


def petsc_comm(comm):
    """`comm`, for creating a PETSc object on it: the first call for a communicator of several ranks also creates an
    empty PETSc vector on it that lives until release_comm frees the communicator, or exit, which keeps PETSc's own
    duplicate of the communicator alive. Collective on first use (call it where the object is created).

    PETSc duplicates a communicator (MPI_Comm_dup, collective) for the first object made on it, and frees the
    duplicate with the last object. Whether the last object has gone can differ between ranks: a Python
    wrapper of a PETSc object caught in a reference cycle lives until the cyclic collector runs, which it
    does at different moments on different ranks. The next object made on the communicator then calls
    MPI_Comm_dup on some ranks only, and the ranks wait in different collectives (tests/parallel/
    test_petsc_comm.py; README "Known issues": the 3-rank test runs that hung). Kept alive, the duplicate is
    made once, when every rank makes the first object."""
    if comm.size > 1:
        from mpi4py import MPI

        key = MPI._handleof(comm)  # psph frees its communicators by release_comm, which drops the key
        if key not in _anchors:
            _anchors[key] = petsc().Vec().createMPI((0, None), comm=comm)
            destroy_at_exit(_anchors[key])
    return comm


def release_comm(comm) -> None:
    """Free `comm`, a communicator psph duplicated for itself, with its petsc_comm vector, if it has one (so
    that a handle MPI reuses for a later communicator finds no stale vector). Collective; every other PETSc
    object made on `comm` must have been destroyed by then (a driver's close)."""
    from mpi4py import MPI

    if comm == MPI.COMM_NULL:  # freed already
        return
    anchor = _anchors.pop(MPI._handleof(comm), None)
    if anchor is not None:
        anchor.destroy()
    comm.Free()


def is_initialized() -> bool:
    return _state["argv"] is not None


def unused_options() -> list:
    """The command line's PETSc options that nothing has read so far (a misspelling, or an option of a
    solver the scene does not have), as "-name value" strings. petsc4py 3.18 does not wrap PETSc's
    PetscOptionsLeftGet, so it is called through ctypes on the PETSc library this process has loaded
    (found in /proc/self/maps); [] where that is not possible."""
    import ctypes

    PETSc = petsc()
    try:
        with open("/proc/self/maps") as maps:
            path = next(line.split()[-1] for line in maps if "/libpetsc" in line and ".so" in line)
        lib = ctypes.CDLL(path)
        get, restore = lib.PetscOptionsLeftGet, lib.PetscOptionsLeftRestore
    except (OSError, StopIteration, AttributeError):
        return []
    import numpy as np

    count = (ctypes.c_int64 if np.dtype(PETSc.IntType).itemsize == 8 else ctypes.c_int32)()
    names, values = ctypes.POINTER(ctypes.c_char_p)(), ctypes.POINTER(ctypes.c_char_p)()
    if get(None, ctypes.byref(count), ctypes.byref(names), ctypes.byref(values)):
        return []
    left = [f"-{names[k].decode()}" + (f" {values[k].decode()}" if values[k] else "") for k in range(count.value)]
    restore(None, ctypes.byref(count), ctypes.byref(names), ctypes.byref(values))
    return left
