"""The fuzzers' allocation bound (scripts/fuzz_harness.py): an input may make a decoder allocate at most 64 MiB
more than the process holds when the input starts; more fails like a crash, also when the decoder turns the
MemoryError into its own typed error."""

from __future__ import annotations

import numpy as np
import pytest

from tests.repo_script import load_repo_script

pytest.importorskip("atheris")  # fuzzing extra (pip install .[fuzz]); the harness imports it

harness = load_repo_script("scripts/fuzz_harness.py", "fuzz_harness_under_test")


def test_an_input_within_the_bound_passes_and_the_limit_is_lifted_afterwards():
    harness.bounded(lambda data: np.ones(harness.MAX_ALLOCATION // 2, np.uint8).sum())(b"")
    assert np.ones(2 * harness.MAX_ALLOCATION, np.uint8)[-1] == 1  # libFuzzer's own work is not bound


# Twice the bound, not just over it: threads other tests left behind (zmq, torch) may unmap a stack or an arena
# between the harness reading the address space and the allocation, which once let bound + 8 MiB through on CI.
TOO_MUCH = 2 * harness.MAX_ALLOCATION


@pytest.mark.parametrize("allocate", [lambda: np.ones(TOO_MUCH, np.uint8), lambda: bytearray(TOO_MUCH)],
                         ids=["numpy", "bytearray"])
def test_an_input_that_needs_more_fails_like_a_crash(allocate):
    with pytest.raises(AssertionError, match="more than"):
        harness.bounded(lambda data: allocate())(b"")


def test_a_memory_error_wrapped_in_a_typed_error_is_still_seen():
    def decode(data: bytes) -> None:
        try:
            bytearray(TOO_MUCH)
        except MemoryError as error:
            raise ValueError("not valid msgpack") from error

    with pytest.raises(ValueError) as caught:
        harness.bounded(decode)(b"")
    assert harness.refused_allocation(caught.value)
    assert not harness.refused_allocation(ValueError("an ordinary rejection"))
