"""engine_split.run_pair: the second half in a forked child, the same answers, and a safe fallback."""

import os

import numpy as np
import pytest

from facecap.solvers.engine import split as engine_split


def _work(seed, n):
    return np.random.default_rng(seed).normal(size=(n, 3)).sum(axis=0)


def test_pair_matches_serial():
    a, b = engine_split.run_pair(_work, (1, 1000), (2, 200000))
    np.testing.assert_array_equal(a, _work(1, 1000))
    np.testing.assert_array_equal(b, _work(2, 200000))


@pytest.mark.skipif(not engine_split.fork_available(), reason="no fork on this platform")
def test_second_half_runs_in_a_child_and_a_failing_child_is_redone_here():
    parent = os.getpid()
    where = engine_split.run_pair(lambda _: os.getpid(), (0,), (1,))
    assert where[0] == parent and where[1] != parent

    def fails_in_child(x):
        if os.getpid() != parent:
            raise RuntimeError("child failure")
        return x * 2

    assert engine_split.run_pair(fails_in_child, (3,), (4,)) == (6, 8)

    def dies_in_child(x):
        if os.getpid() != parent:
            os._exit(3)
        return x + 1

    assert engine_split.run_pair(dies_in_child, (3,), (4,)) == (4, 5)


def test_an_error_in_the_parent_half_is_raised():
    def boom(x):
        if x == 0:
            raise ValueError("first half")
        return x

    with pytest.raises(ValueError, match="first half"):
        engine_split.run_pair(boom, (0,), (1,))


@pytest.mark.skipif(not engine_split.fork_available(), reason="no fork on this platform")
@pytest.mark.parametrize("let_finish", [True, False])
def test_a_failing_parent_job_kills_or_waits_for_the_child(tmp_path, let_finish):
    """run_beside: when the job here raises, the child is killed, or with ``let_finish`` allowed to
    complete (the CLI's weights CSV is then written whole, no temporary file left)."""
    import time

    out = tmp_path / "written.txt"

    def slow_write():
        time.sleep(1.0)
        out.write_text("done")

    def fails():
        raise ValueError("here")

    with pytest.raises(ValueError, match="here"):
        engine_split.run_beside(fails, slow_write, let_finish=let_finish)
    time.sleep(0.2 if let_finish else 1.5)  # a killed child would have written by now
    assert out.exists() == let_finish


def test_interrupts_held_over_a_fork_are_raised_once_released():
    """A Ctrl-C (or SIGTERM) that comes while a child is forked is noted, not raised inside the fork's
    handlers (where it would be printed and lost), and raised as KeyboardInterrupt on release."""
    import os
    import signal

    from facecap.solvers.engine.split import HeldInterrupts

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    held = HeldInterrupts().hold()
    os.kill(os.getpid(), signal.SIGINT)
    os.kill(os.getpid(), signal.SIGTERM)
    assert held.came == [signal.SIGINT, signal.SIGTERM]  # noted, nothing raised
    with pytest.raises(KeyboardInterrupt):
        held.release()
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
    quiet = HeldInterrupts().hold()
    quiet.release()  # nothing came: nothing raised, the handlers back
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before
