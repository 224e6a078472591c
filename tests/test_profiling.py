"""psph.profiling's phases: what -log_view and the benchmarks' time splits read."""

import time

import pytest

from psph import profiling


@pytest.fixture(autouse=True)
def fresh_totals():
    profiling.reset()
    yield
    profiling.reset()


def test_a_nested_phase_counts_in_its_parent_and_not_in_its_parents_own_time():
    with profiling.phase("outer"):
        time.sleep(0.02)
        with profiling.phase("inner"):
            time.sleep(0.03)
    totals, own = profiling.totals(), profiling.exclusive()
    assert totals["outer"][1] == totals["inner"][1] == 1
    assert totals["outer"][0] >= totals["inner"][0] + 0.02 and totals["inner"][0] >= 0.03
    assert own["outer"] == pytest.approx(totals["outer"][0] - totals["inner"][0], abs=1e-12)
    assert own["inner"] == totals["inner"][0]


def test_a_phase_left_by_an_exception_is_closed_and_counted():
    with pytest.raises(ValueError):
        with profiling.phase("outer"):
            with profiling.phase("failing"):
                raise ValueError
    with profiling.phase("after"):  # no phase left open: this one nests in nothing
        time.sleep(0.01)
    assert profiling.totals()["failing"][1] == 1 and profiling.totals()["outer"][1] == 1
    assert profiling.exclusive()["after"] == profiling.totals()["after"][0]
    assert not profiling._children
