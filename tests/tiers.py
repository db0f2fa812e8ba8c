"""The suite's two tiers, a pytest plugin (``tests/conftest.py`` loads it).

``python -m pytest -q`` runs every test but those marked ``slow`` (the heavy CPU runs: the MJX step's
equivalences, training programs lowered or trained twice, identifications, whole-song evaluations, the
second and third signal of a subprocess's stop); ``--slow`` runs those too, and ``-m slow`` only those (CI
runs the default tier, then ``-m slow``). A ``-m`` expression, or a test named by its node id
(``file.py::test``), chooses for itself. The summary says how many were left out and how to run them.
"""

from __future__ import annotations

from typing import Any

import pytest

SLOW_LEFT_OUT = pytest.StashKey[int]()
"""How many ``slow`` tests this run left out."""


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--slow", action="store_true", help="also run the tests marked slow (the default run leaves them out)"
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Leave out the ``slow`` tests unless ``--slow``, a ``-m`` expression, or a node id named them."""
    if config.getoption("--slow") or config.getoption("markexpr"):
        return
    named = {a.split("[")[0] for a in config.args if "::" in a}
    keep, slow = [], []
    for item in items:
        if item.get_closest_marker("slow") is not None and item.nodeid.split("[")[0] not in named:
            slow.append(item)
        else:
            keep.append(item)
    if slow:
        config.hook.pytest_deselected(items=slow)
        items[:] = keep
        config.stash[SLOW_LEFT_OUT] = len(slow)


def pytest_sessionfinish(session: pytest.Session) -> None:
    """On a pytest-xdist worker: hand the count to the controller, which collects nothing itself."""
    out = getattr(session.config, "workeroutput", None)
    if out is not None:
        out["slow_left_out"] = session.config.stash.get(SLOW_LEFT_OUT, 0)


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node: Any, error: Any) -> None:
    """On the pytest-xdist controller: each worker collects the whole suite; any one's count is the run's."""
    n = getattr(node, "workeroutput", {}).get("slow_left_out", 0)
    node.config.stash[SLOW_LEFT_OUT] = max(node.config.stash.get(SLOW_LEFT_OUT, 0), n)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter, config: pytest.Config) -> None:
    n = config.stash.get(SLOW_LEFT_OUT, 0)
    if n:
        tests = "test" if n == 1 else "tests"
        terminalreporter.write_line(f"{n} slow {tests} left out: python -m pytest -q --slow runs them too")
