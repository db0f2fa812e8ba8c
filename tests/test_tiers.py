"""The suite's tiers (``tiers.py``): what the default run, ``--slow``, ``-m`` and a named test each run."""

from __future__ import annotations

from pathlib import Path

import pytest

SUITE = """
import pytest

def test_fast():
    pass

@pytest.mark.slow
def test_heavy():
    pass

@pytest.mark.parametrize("x", [1, pytest.param(2, marks=pytest.mark.slow)])
def test_param(x):
    pass
"""


@pytest.fixture
def suite(pytester: pytest.Pytester) -> pytest.Pytester:
    """A four-test suite (two of them slow: one test, one parameter) under the tiers plugin."""
    # the path in the conftest itself: pytest-xdist's workers, other processes, import ``tiers`` too
    here = str(Path(__file__).parent)
    pytester.makeconftest(f'import sys\nsys.path.insert(0, {here!r})\npytest_plugins = ["tiers"]')
    pytester.makeini("[pytest]\nmarkers =\n    slow: heavy\n")
    pytester.makepyfile(test_a=SUITE)
    return pytester


def test_the_default_run_leaves_the_slow_tests_out_and_says_so(suite: pytest.Pytester) -> None:
    r = suite.runpytest()
    r.assert_outcomes(passed=2, deselected=2)
    r.stdout.fnmatch_lines(["2 slow tests left out: python -m pytest -q --slow runs them too"])


def test_slow_runs_everything_and_a_mark_expression_chooses(suite: pytest.Pytester) -> None:
    suite.runpytest("--slow").assert_outcomes(passed=4)
    r = suite.runpytest("-m", "slow")
    r.assert_outcomes(passed=2, deselected=2)
    r.stdout.no_fnmatch_line("*slow tests left out*")


def test_a_slow_test_named_by_its_node_id_runs(suite: pytest.Pytester) -> None:
    suite.runpytest("test_a.py::test_heavy").assert_outcomes(passed=1)
    suite.runpytest("test_a.py::test_param").assert_outcomes(passed=2)


def test_a_run_on_two_workers_says_what_it_left_out(suite: pytest.Pytester) -> None:
    """Under pytest-xdist the controller collects nothing: the workers' count reaches its summary."""
    r = suite.runpytest("-n", "2")
    r.assert_outcomes(passed=2)
    r.stdout.fnmatch_lines(["2 slow tests left out: python -m pytest -q --slow runs them too"])
