"""``timing.FrozenHeap``: the start-up's objects out of the collector's scans while the control loop runs,
the loop's own garbage still freed, and the runtime's loop inside it."""

from __future__ import annotations

import gc
import weakref

from bar_policy.deploy import run_loop
from bar_policy.deploy.policy import load_policy
from bar_policy.deploy.runtime import Runtime, RuntimeConfig
from bar_policy.deploy.safety import SafetyConfig
from bar_policy.deploy.targets.sim import SimTarget
from bar_policy.deploy.timing import FrozenHeap
from bar_policy.tasks.reach.commands import SampledCommands


class _Node:
    """An object that can hold itself (a reference cycle: only the collector frees it)."""

    def __init__(self) -> None:
        self.me: _Node | None = None


def test_what_is_alive_at_entry_is_frozen_and_the_blocks_cycles_are_still_freed():
    """Inside: the objects alive at entry are in the permanent generation (at least the module's), collection
    is on, and a cycle made and dropped inside is freed by a collection; after: nothing frozen."""
    with FrozenHeap():
        assert gc.get_freeze_count() > 0 and gc.isenabled()
        made = _Node()
        made.me = made
        ref = weakref.ref(made)
        del made
        gc.collect()
        assert ref() is None
    assert gc.get_freeze_count() == 0


def test_the_control_loop_runs_with_the_heap_frozen(make_policy, monkeypatch):
    """A 0.1 s run on the sim target (synchronous: its 5 ticks all run, however loaded the machine): every
    tick sees the heap frozen, and after the run nothing is."""
    frozen: list[int] = []
    tick = Runtime._tick

    def spy(self, *args, **kwargs):
        frozen.append(gc.get_freeze_count())
        return tick(self, *args, **kwargs)

    monkeypatch.setattr(Runtime, "_tick", spy)
    assert run_loop.FrozenHeap is FrozenHeap
    pol = load_policy(make_policy())
    cfg = RuntimeConfig(duration=0.1, start_mode="policy", safety=SafetyConfig(ramp_time=0.0))
    Runtime(pol, SimTarget("arms"), SampledCommands(pol.obs_manager.command_names, seed=0), cfg).run()
    assert len(frozen) == 5 and min(frozen) > 0
    assert gc.get_freeze_count() == 0


def test_a_heap_frozen_before_the_block_stays_frozen_after_it():
    """An outer freeze (a caller's, or an outer block) is not undone by an inner block's exit."""
    with FrozenHeap():
        outer = gc.get_freeze_count()
        with FrozenHeap():
            pass
        assert gc.get_freeze_count() >= outer > 0
    assert gc.get_freeze_count() == 0
