"""Progress display: a bar on a terminal, plain lines with the ETA in a log, nothing when disabled."""

import io

from mpi4py import MPI

from psph.progress import Progress, format_duration


class Terminal(io.StringIO):
    def isatty(self):
        return True


def test_plain_lines_carry_time_step_iterations_and_eta():
    out = io.StringIO()
    progress = Progress(MPI.COMM_SELF, 0.0, 2.0, every=0.0, stream=out)
    progress.update(10, 0.5, 0.05, newton=12, ksp=80)
    line = out.getvalue().strip()
    assert line.startswith("t = 0.5 / 2 (25.0%), step 10, dt 0.05, newton 12, ksp 80, ETA ")


def test_terminal_gets_a_bar_and_quiet_gets_nothing():
    term = Terminal()
    progress = Progress(MPI.COMM_SELF, 0.0, 2.0, stream=term)
    progress.update(10, 1.0, 0.05, newton=3)
    progress.close()
    assert "50%" in term.getvalue() and "step 10, dt 0.05, newton 3" in term.getvalue()
    silent = io.StringIO()
    Progress(MPI.COMM_SELF, 0.0, 2.0, enabled=False, every=0.0, stream=silent).update(1, 1.0, 0.1)
    assert silent.getvalue() == ""


def test_durations():
    assert format_duration(59.4) == "59s" and format_duration(61) == "1m01s" and format_duration(3725) == "1h02m05s"
    assert format_duration(float("inf")) == "?"
