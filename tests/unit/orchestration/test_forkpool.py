"""hadal.forkpool: calls drawn in forked children give what a plain loop gives, in order; failures behave as here."""

from __future__ import annotations

import os
import signal
import sys

import pytest

from hadal.forkpool import ForkPool, can_fork

pytestmark = pytest.mark.skipif(not can_fork(), reason="ForkPool forks on Linux only (elsewhere it is a plain loop)")


def _pid_and_square(x: int) -> tuple[int, int]:
    return os.getpid(), x * x


def test_results_in_order_and_equal_to_a_plain_loop():
    items = list(range(12))
    with ForkPool(3) as pool:
        for x in items:
            pool.submit(_pid_and_square, x)
        out = pool.results()
    assert [v for _, v in out] == [x * x for x in items]
    # the first call always goes to a child (none is busy yet); which of the others do depends on timing
    assert out[0][0] != os.getpid()


def test_one_worker_is_a_plain_loop_here():
    with ForkPool(1) as pool:
        for x in range(4):
            pool.submit(_pid_and_square, x)
        out = pool.results()
    assert {p for p, _ in out} == {os.getpid()} and [v for _, v in out] == [0, 1, 4, 9]


def _boom(x: int) -> int:
    if x == 1:
        raise ValueError(f"bad item {x}")
    return x


def test_an_error_in_a_child_is_raised_here_as_a_plain_loop_would():
    with pytest.raises(ValueError, match="bad item 1"), ForkPool(2) as pool:
        pool.submit(_boom, 1)  # the first call goes to the (free) child
        pool.submit(_boom, 2)
        pool.results()


def _die_in_child(parent_pid: int) -> str:
    if os.getpid() != parent_pid:
        os.kill(os.getpid(), signal.SIGKILL)  # a child killed without an answer (e.g. by the OOM killer)
    return "done here"


def test_a_child_killed_without_an_answer_has_its_call_rerun_here():
    with ForkPool(2) as pool:
        pool.submit(_die_in_child, os.getpid())
        assert pool.results() == ["done here"]


def _unpicklable(_: int):
    return lambda: None


def test_an_unpicklable_result_is_computed_here():
    with ForkPool(2) as pool:
        pool.submit(_unpicklable, 0)
        (out,) = pool.results()
    assert callable(out)


def test_pending_output_is_not_printed_twice(capfd):
    """A fork copies this process's unflushed stdout buffer; the pool flushes it first, so it appears once."""
    sys.stdout.write("pending line\n")  # buffered, not yet flushed
    with ForkPool(2) as pool:
        pool.submit(_pid_and_square, 3)
        pool.results()
    sys.stdout.flush()
    assert capfd.readouterr().out.count("pending line") == 1


def test_workers_must_be_positive():
    with pytest.raises(ValueError, match="at least 1"):
        ForkPool(0)
