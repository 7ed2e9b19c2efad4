import os

import pytest

from sonar_realism.parallel import parallel_imap, parallel_map


def test_the_workers_give_the_serial_results_in_order() -> None:
    items = list(range(9))
    assert parallel_map(lambda x: (x * x, os.getpid()), items, 1) == [(x * x, os.getpid()) for x in items]
    squares = parallel_map(lambda x: (x * x, os.getpid()), items, 3)
    assert [s for s, _ in squares] == [x * x for x in items]
    assert os.getpid() not in {pid for _, pid in squares}, "the work ran in the caller, not in forked workers"


def test_a_closure_reaches_the_workers_without_pickling() -> None:
    world = {"unpicklable": lambda x: x + 1}
    assert list(parallel_imap(lambda x: world["unpicklable"](x), range(5), 2, chunksize=2)) == [1, 2, 3, 4, 5]


def test_workers_do_not_fork_again_and_a_streaming_pool_leaves_others_serial() -> None:
    inner = parallel_map(lambda x: parallel_map(lambda y: os.getpid(), range(3), 2), range(2), 2)
    assert all(len(set(pids)) == 1 for pids in inner), "a worker forked a pool of its own"
    stream = parallel_imap(lambda x: x, range(4), 2)
    assert next(stream) == 0
    assert parallel_map(lambda x: os.getpid(), range(3), 2) == [os.getpid()] * 3
    assert list(stream) == [1, 2, 3]
    assert os.getpid() not in parallel_map(lambda x: os.getpid(), range(3), 2), "the pool did not come back"


def test_an_error_in_a_worker_reaches_the_caller() -> None:
    def fail(x: int) -> int:
        if x == 2:
            raise ValueError("item 2")
        return x

    with pytest.raises(ValueError, match="item 2"):
        parallel_map(fail, range(4), 2)
