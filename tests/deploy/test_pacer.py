"""The loop's clock counts skipped deadlines inside the run only (a fake wall clock, values by hand)."""

from __future__ import annotations

import pytest

from bar_policy.deploy import timing


class _Clock:
    """A wall clock the test moves by hand (``time.perf_counter`` of the timing module)."""

    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> _Clock:
    c = _Clock()
    monkeypatch.setattr(timing.time, "perf_counter", c)
    monkeypatch.setattr(timing, "sleep_until", lambda deadline, spin_s: None)
    return c


def test_a_late_tick_inside_the_run_skips_the_deadlines_it_passed(clock: _Clock) -> None:
    # dt 2 ms, 10 deadlines. Tick 0 ends at 7 ms: deadlines 1, 2, 3 (2, 4, 6 ms) passed -> 3 skipped,
    # the next deadline is number 4 (8 ms).
    p = timing.Pacer(0.002, paced=True, n_deadlines=10)
    p.wait()
    clock.now += 0.007
    assert p.tick_done(0.0, 0.007, 0.0) is True
    assert (p.index, p.skipped, p.overruns) == (4, 3, 1)


def test_a_late_last_tick_skips_no_deadline_after_the_run(clock: _Clock) -> None:
    # 3 deadlines (0, 2, 4 ms). Ticks 0 and 1 on time; tick 2 (the last, started at 4 ms) ends at 11 ms:
    # it passed deadlines 3, 4, 5 (6, 8, 10 ms), all after the run's end -> an overrun, 0 skipped.
    p = timing.Pacer(0.002, paced=True, n_deadlines=3)
    for k in range(3):
        clock.now = 100.0 + 0.002 * k
        p.wait()
        clock.now += 0.007 if k == 2 else 0.001
        p.tick_done(0.0, 0.0, 0.0)
    assert (p.index, p.skipped, p.overruns) == (3, 0, 1)
    # Open-ended (no length): the same tick skips all three.
    clock.now = 100.0
    q = timing.Pacer(0.002, paced=True)
    q.index = 2
    clock.now = 100.004
    q.wait()
    clock.now += 0.007
    q.tick_done(0.0, 0.0, 0.0)
    assert (q.index, q.skipped) == (6, 3)
