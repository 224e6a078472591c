"""Checkpoints and restarts: a continued run equals the uninterrupted one bit for bit (same ranks) or to
round-off / solver tolerance (other ranks); a run killed while writing a checkpoint keeps the last one."""

import json
import textwrap

import numpy as np
import pytest
from mpi4py import MPI

from psph.drivers.fluid import FluidDriver
from psph.io.checkpoint import HDF5_SIGNATURE, SEAL, SEAL_BYTES, latest_checkpoint, read_checkpoint
from psph.io.history import read_history
from tests.conftest import gather_by_gid, periodic_scene
from tests.helpers import CASES, run_psph
from tests.shifting.test_iips import petsc_options

FIELDS = ("position", "velocity", "density", "volume", "mass")
TIMING = ("step_time_s", "iips_time_s", "shifting_time_s")


def scheme_and_method(method):
    """'riemann_ale:neuhauser' -> ('riemann_ale', 'neuhauser'); a bare method runs delta_ale."""
    return method.split(":") if ":" in method else ("delta_ale", method)


def scene(method):
    """A short Taylor-Green run with a checkpoint every 7 steps."""
    scheme, method = scheme_and_method(method)
    iips = {"threshold": 1e-3, "update": "nfts"} if method == "iips" else {}
    return periodic_scene(n=16, initial={"velocity": "taylor_green"}, physics={"scheme": scheme},
                          time={"t_end": 0.05}, shifting={"method": method}, iips=iips,
                          output={"checkpoint_every": 7})


def final_state(driver, comm):
    p = driver.system.particles
    return {k: gather_by_gid(comm, p.owned("gid"), p.owned(k))[1] for k in FIELDS}


def run(sc, comm, out, restart=None):
    with petsc_options(iips_ksp_rtol=1e-12, iips_ksp_atol=1e-30):
        with FluidDriver(sc, comm, out, restart=read_checkpoint(comm, restart) if restart else None) as driver:
            summary = driver.run()
            return final_state(driver, comm), summary


def same_history(a, b):
    rows_a, rows_b = read_history(a / "history.csv"), read_history(b / "history.csv")
    assert len(rows_a) == len(rows_b)
    for ra, rb in zip(rows_a, rows_b):
        assert {k: v for k, v in ra.items() if k not in TIMING} == {k: v for k, v in rb.items() if k not in TIMING}


def kill_mid_checkpoint_script(out):
    """A run that SIGKILLs itself halfway through writing its second checkpoint (half of the particle
    fields in the temporary file, no state, no rename)."""
    return textwrap.dedent(f"""
        import os, signal, sys
        import psph.io.checkpoint as ck
        from psph.cli import main
        written = []
        original = ck.write_particle_file
        def dying(comm, path, start, total, data, attrs, extra=None, **options):
            written.append(path)
            if len(written) == 2:
                original(comm, path, start, total, dict(list(data.items())[: len(data) // 2]), {{}}, **options)
                os.kill(os.getpid(), signal.SIGKILL)
            original(comm, path, start, total, data, attrs, extra, **options)
        ck.write_particle_file = dying
        sys.exit(main(["run", "{CASES / 'taylor_green.toml'}", "--out", "{out}", "--set", "domain.dx=0.05",
                       "--set", "time.t_end=0.06", "--checkpoint-every", "10"]))
        """)


@pytest.mark.parametrize("method", ["delta_plus", "iips", "riemann_ale:neuhauser"])
def test_restart_continues_bit_for_bit(tmp_path, method):
    sc = scene(method)
    mine = tmp_path / "whole" / "checkpoint_best.h5"  # not psph's: neither pruned nor read
    mine.parent.mkdir()
    mine.write_text("mine")
    whole, summary = run(sc, MPI.COMM_SELF, tmp_path / "whole")
    kept = list((tmp_path / "whole").glob("checkpoint_0*"))  # older ones removed once a newer one is complete
    assert len(kept) == 1 and 0 < read_checkpoint(MPI.COMM_SELF, kept[0])[0]["step"] < summary["steps"]
    assert mine.read_text() == "mine"
    # continue in a copy of the directory from the last checkpoint
    import shutil

    shutil.copytree(tmp_path / "whole", tmp_path / "again")
    again, summary2 = run(sc, MPI.COMM_SELF, tmp_path / "again", restart=latest_checkpoint(tmp_path / "again"))
    for k in FIELDS:
        assert np.array_equal(whole[k], again[k]), k
    assert summary2["steps"] == summary["steps"] and summary2["iips_newton"] == summary["iips_newton"]
    same_history(tmp_path / "whole", tmp_path / "again")


def test_killed_while_writing_a_checkpoint_restarts_from_the_last_complete_one(tmp_path):
    script = tmp_path / "dying.py"
    out = tmp_path / "run"
    script.write_text(kill_mid_checkpoint_script(out))
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                          cwd=str(CASES.parent))
    assert proc.returncode == -9, proc.stderr
    assert sorted(p.name for p in out.glob("checkpoint_*")) == ["checkpoint_000010.h5", "checkpoint_000020.h5.tmp"]
    assert latest_checkpoint(out).name == "checkpoint_000010.h5"
    # continued through a link to its directory: --overwrite removes nothing of the run it continues
    link = tmp_path / "link"
    link.symlink_to(out)
    done = run_psph("run", "--restart", latest_checkpoint(out), "--out", link, "--overwrite")
    assert done.returncode == 0, done.stderr
    assert (out / "psph.log").read_text().count("running scene") == 2
    reference = run_psph("run", CASES / "taylor_green.toml", "--out", tmp_path / "reference", "--set", "domain.dx=0.05",
                         "--set", "time.t_end=0.06", "--checkpoint-every", "10")
    assert reference.returncode == 0, reference.stderr
    same_history(out, tmp_path / "reference")


def test_kinematic_restart_continues_bit_for_bit(tmp_path):
    """The kinematic driver (IIPS Procedure B after a pre-procedure) continues from its checkpoint exactly."""
    import shutil

    args = ["--set", "domain.dx=0.05", "--set", "time.t_end=0.1", "--set", "iips.pre_newton=5", "--set",
            "iips.beta=5", "--set", "output.every=0", "--checkpoint-every", "37"]  # 100 steps
    done = run_psph("run", CASES / "kinematic_tgv.toml", "--out", tmp_path / "whole", *args)
    assert done.returncode == 0, done.stderr
    shutil.copytree(tmp_path / "whole", tmp_path / "again")
    checkpoint = latest_checkpoint(tmp_path / "again")
    assert checkpoint.name == "checkpoint_000074.h5"
    last = "snapshot_000001.h5"
    for name in (last, "history.csv", "summary.json"):  # the restart must write them again, not keep the copies
        (tmp_path / "again" / name).unlink()
    done = run_psph("run", "--restart", checkpoint)
    assert done.returncode == 0, done.stderr
    same_history(tmp_path / "whole", tmp_path / "again")
    whole, again = (json.loads((tmp_path / d / "summary.json").read_text()) for d in ("whole", "again"))
    assert again["steps"] == whole["steps"] and again["final"]["L2_grad_c"] == whole["final"]["L2_grad_c"]
    import h5py

    with h5py.File(tmp_path / "whole" / last) as a, h5py.File(tmp_path / "again" / last) as b:
        for k in ("position", "grad_c", "gid"):
            assert np.array_equal(a["particles"][k][()], b["particles"][k][()]), k
    # a restart that halves the step (time.cfl 0.2 -> 0.1) goes on from the checkpoint's time, 0.074, in steps
    # of 0.0005 (counted from step 0, its step 75 ended at 0.0375: the run went back in time, an audit found)
    done = run_psph("run", "--restart", checkpoint, "--out", tmp_path / "finer", "--set", "time.cfl=0.1")
    assert done.returncode == 0, done.stderr
    rows = read_history(tmp_path / "finer" / "history.csv")
    times = [r["time"] for r in rows if r["step"] > 74]  # (a row's time is its step's start)
    assert rows[-1]["step"] == 74 + 52 and times[0] == pytest.approx(0.074) and times[-1] < 0.1, times[:3]
    assert np.allclose(np.diff(times), 0.0005)
    with h5py.File(tmp_path / "finer" / "snapshot_000001.h5") as f:
        assert f.attrs["time"] == 0.1 and f.attrs["step"] == 126


def test_restart_errors_are_one_line(tmp_path):
    bad = tmp_path / "not_a_checkpoint.h5"
    bad.write_bytes(b"garbage")
    done = run_psph("run", "--restart", bad)
    assert done.returncode == 2 and done.stderr.startswith("psph: error: cannot restart from") \
        and "Traceback" not in done.stderr
    done = run_psph("run", "--restart", bad, "--set", "domain.dx=0.1")
    assert done.returncode == 2 and "may change only time.*, output.* and neighbours.*" in done.stderr
    done = run_psph("run", "--restart", bad, "--set", "time.integrator=rk4")  # (an I/O audit: it was accepted)
    assert done.returncode == 2 and "a restart continues with the checkpoint's time integrator" in done.stderr
    done = run_psph("run", CASES / "static_perturbed.toml", "--out", tmp_path / "s", "--checkpoint-every", "5")
    assert done.returncode == 2 and "checkpoint_every: checkpoints are written by time-dependent runs" in done.stderr
    assert not (tmp_path / "s").exists()


@pytest.mark.mpi
@pytest.mark.parametrize("method,tol", [("delta_plus", 1e-11), ("iips", 1e-7)])
def test_restart_on_the_same_and_on_more_ranks(comm, mpi_tmp_path, method, tol):
    """Same ranks: bit for bit. A checkpoint of size - 1 ranks (1 -> 2, 2 -> 3) continued on all ranks, and
    one of all ranks continued on size - 1 (2 -> 1, 3 -> 2): equal to the uninterrupted run to round-off
    (explicit) or the KSP tolerance (IIPS)."""
    sc = scene(method)
    whole, _ = run(sc, comm, mpi_tmp_path / "whole")
    again, _ = run(sc, comm, mpi_tmp_path / "again", restart=latest_checkpoint(mpi_tmp_path / "whole"))
    for k in FIELDS:
        assert np.array_equal(whole[k], again[k]), k
    if comm.size == 1:
        return
    fewer = comm.Split(0 if comm.rank < comm.size - 1 else MPI.UNDEFINED, comm.rank)
    if fewer != MPI.COMM_NULL:
        run(sc, fewer, mpi_tmp_path / "fewer")
    comm.Barrier()
    more, _ = run(sc, comm, mpi_tmp_path / "more", restart=latest_checkpoint(mpi_tmp_path / "fewer"))
    continued = {"more": more}
    if fewer != MPI.COMM_NULL:
        continued["less"], _ = run(sc, fewer, mpi_tmp_path / "less", restart=latest_checkpoint(mpi_tmp_path / "whole"))
        fewer.Free()
    comm.Barrier()
    for name, state in continued.items():
        for k in FIELDS:
            scale = max(np.abs(whole[k]).max(), 1.0)
            assert np.abs(state[k] - whole[k]).max() < tol * scale, (name, k)


def test_the_latest_checkpoint_is_the_largest_step_and_only_psph_s(tmp_path):
    """Past step 999999 the names grow a digit: the latest is found by step, not by name; a user's
    checkpoint_best.h5 is no candidate (nor pruned: test_restart_continues_bit_for_bit)."""
    from psph.io.checkpoint import checkpoint_name

    for step in (999990, 1000000):
        (tmp_path / checkpoint_name(step)).write_bytes(b"")
    (tmp_path / "checkpoint_best.h5").write_bytes(b"")
    (tmp_path / "checkpoint_2000000.h5.tmp").write_bytes(b"")
    assert latest_checkpoint(tmp_path).name == "checkpoint_1000000.h5"


def test_a_restarted_runs_summary_keeps_its_packing_report(tmp_path):
    """summary.json's `packing` (the start's Colagrossi packing) was dropped by a restart, which packs nothing
    (a diagnostics audit): the checkpoint carries it."""
    import shutil

    from psph.scene.load import load_scene

    sc = load_scene(CASES / "hydrostatic_tank.toml", ["domain.dx=0.1", "time.t_end=0.05", "packing.iterations=10",
                                                      "output.every=0", "output.checkpoint_every=3"])
    _, summary = run(sc, MPI.COMM_SELF, tmp_path / "whole")
    assert summary["packing"]["converged"] and summary["packing"]["frame_particles"] > 0
    shutil.copytree(tmp_path / "whole", tmp_path / "again")
    _, again = run(sc, MPI.COMM_SELF, tmp_path / "again", restart=latest_checkpoint(tmp_path / "again"))
    assert again["packing"] == json.loads(json.dumps(summary["packing"]))


def test_one_flipped_bit_anywhere_in_a_checkpoint_is_refused_or_harmless(tmp_path):
    """Fletcher32 covers the datasets' chunks, not HDF5's own metadata: of one-bit flips of a checkpoint, 57
    changed the restart's fields unnoticed, 8 raised a traceback, some crashed HDF5 or hung (a fuzzing audit).
    Written with libver = "latest" (superblock version 3), the metadata is checksummed too (at every 37th
    byte, by hand: 602 refused, 152 harmless; without: 5 unnoticed, 1 traceback, 1 crash), but HDF5's reader
    still crashed on 2 flips of about 3000 (the audit, every 5th byte). The CRC32 seal in the user block is
    checked on the raw bytes first: a flip at every 97th byte is refused in one line (UsageError) before HDF5
    reads the file, or, in the seal's unused padding, leaves what the restart reads as it was; no other
    exception, no crash (each read in a forked child)."""
    import os

    from psph.errors import UsageError

    sc = periodic_scene(n=10, initial={"velocity": "taylor_green"}, physics={"scheme": "delta_ale"},
                        time={"t_end": 0.02}, shifting={"method": "delta_plus"}, iips={"update": "none"},
                        output={"checkpoint_every": 3})
    run(sc, MPI.COMM_SELF, tmp_path / "run")
    path = latest_checkpoint(tmp_path / "run")
    raw = path.read_bytes()
    # the seal, then the superblock (its version: 0 without libver)
    assert raw.startswith(SEAL) and raw[SEAL_BYTES:SEAL_BYTES + 8] == HDF5_SIGNATURE and raw[SEAL_BYTES + 8] >= 2
    state, particles, _ = read_checkpoint(MPI.COMM_SELF, path)
    reference = {k: particles.owned(k).copy() for k in particles.names}
    outcomes = []
    for offset in range(0, len(raw), 97):
        damaged = bytearray(raw)
        damaged[offset] ^= 4
        bad = tmp_path / "bad.h5"
        bad.write_bytes(damaged)
        read, write = os.pipe()
        pid = os.fork()
        if pid == 0:  # (the child reports in one word and leaves without Python's or MPI's exit handlers)
            os.close(read)
            try:
                got, p, _ = read_checkpoint(MPI.COMM_SELF, bad)
                same = got == state and all(np.array_equal(p.owned(k), v, equal_nan=True) for k, v in reference.items())
                word = "same" if same else "changed"
            except UsageError:
                word = "refused"
            except BaseException:
                word = "exception"
            os.write(write, word.encode())
            os._exit(0)
        os.close(write)
        os.waitpid(pid, 0)
        outcomes.append((offset, os.read(read, 16).decode() or "crash"))
        os.close(read)
    counts = {word: sum(1 for _, w in outcomes if w == word) for word in ("same", "refused", "changed", "exception",
                                                                          "crash")}
    assert counts["refused"] > 0 and counts["same"] + counts["refused"] == len(outcomes), \
        [o for o in outcomes if o[1] not in ("same", "refused")]
    assert [o for o, w in outcomes if w == "same"] == [o for o in range(0, SEAL_BYTES, 97) if o > raw.index(b"\n")]
