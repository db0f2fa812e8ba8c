"""The wall-clock budget's look-ahead: no epoch starts that would end past ``max_minutes``."""

from __future__ import annotations

from bar_policy.training.progress import next_would_overrun


def test_an_epoch_that_would_end_past_the_budget_does_not_start() -> None:
    # The first GPU track runs overshot 7.6 min (456 s) by one 41 s epoch and an 8 s evaluation: at 441 s
    # the old check (elapsed > budget) let a next epoch run to 482 s. 441 + 41 + 8 = 490 > 456: stop.
    assert next_would_overrun(441.0, 41.0 + 8.0, 456.0)
    # 400 + 49 = 449 <= 456: that epoch ends inside the budget and runs.
    assert not next_would_overrun(400.0, 49.0, 456.0)
    # Exactly on the budget is inside it (ends at 456 s, not past it).
    assert not next_would_overrun(407.0, 49.0, 456.0)


def test_no_budget_never_stops() -> None:
    assert not next_would_overrun(1e9, 1e9, 0.0)
