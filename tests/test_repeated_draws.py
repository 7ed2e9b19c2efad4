"""The draw memo: bit-identical draws and generator states, whatever it remembers."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from sonar_realism.frames import SonarImage
from sonar_realism.sim import repeated_draws
from sonar_realism.sim.effects import apply_effects, make_effect
from sonar_realism.sim.repeated_draws import remembered_draw, remembering_draws

calls: list[int] = []


@remembered_draw
def _uniform_field(rng: np.random.Generator, shape: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    calls.append(1)
    return rng.random(shape, dtype=np.float32), rng.standard_normal(shape, dtype=np.float32)


def _frame(seed: int) -> SonarImage:
    rng = np.random.default_rng(seed)
    intensity = rng.random((96, 64), dtype=np.float32) * 0.5
    return SonarImage(intensity=intensity, ranges_m=np.linspace(0.5, 10.0, 96),
                      azimuths_rad=np.linspace(-0.6, 0.6, 64), meta={"speckle_seed": seed})


def test_a_remembered_draw_is_returned_again_and_the_generator_moves_on_as_it_would() -> None:
    plain = np.random.default_rng(3)
    expected = [_uniform_field(plain, (20, 10)), plain.random(4)]
    calls.clear()
    with remembering_draws():
        for _ in range(3):  # a search: the same seed each evaluation
            rng = np.random.default_rng(3)
            field = _uniform_field(rng, (20, 10))
            after = rng.random(4)
            for got, want in zip(field, expected[0], strict=True):
                np.testing.assert_array_equal(got, want)
            np.testing.assert_array_equal(after, expected[1])
            field[0][:] = -1.0  # a caller writing into its copy does not reach the memo
    assert len(calls) == 1
    with remembering_draws():
        _uniform_field(np.random.default_rng(3), (20, 10))
        _uniform_field(np.random.default_rng(3), (20, 11))  # other arguments: drawn
        _uniform_field(np.random.default_rng(4), (20, 10))  # another state: drawn
    assert len(calls) == 4


def test_nothing_is_remembered_outside_the_block_and_the_memo_keeps_its_size() -> None:
    calls.clear()
    _uniform_field(np.random.default_rng(3), (8, 8))
    _uniform_field(np.random.default_rng(3), (8, 8))
    assert len(calls) == 2 and repeated_draws.current_memo() is None
    with remembering_draws(limit_mb=1):
        with remembering_draws():  # nested: the outer memo serves
            for seed in range(10):
                _uniform_field(np.random.default_rng(seed), (256, 128))  # 256 KB each
            memo = repeated_draws.current_memo()
            assert memo is not None and memo.bytes <= 2 ** 20 and len(memo.entries) == 4
        _uniform_field(np.random.default_rng(9), (256, 128))  # the most recent: still there
        assert len(calls) == 12
        _uniform_field(np.random.default_rng(0), (256, 128))  # the oldest: gone
        assert len(calls) == 13
    assert repeated_draws.current_memo() is None
    with remembering_draws(limit_mb=0), remembering_draws():  # the baseline: an outer block that keeps nothing
        _uniform_field(np.random.default_rng(3), (8, 8))
        _uniform_field(np.random.default_rng(3), (8, 8))
    assert len(calls) == 15


def test_each_thread_has_its_own_memo() -> None:
    seen: list[object] = []
    with remembering_draws():
        worker = threading.Thread(target=lambda: seen.append(repeated_draws.current_memo()))
        worker.start()
        worker.join()
        assert repeated_draws.current_memo() is not None
    assert seen == [None]


@pytest.mark.parametrize("with_seed", [True, False])
def test_every_effect_chain_is_bit_identical_under_the_memo(with_seed: bool) -> None:
    frames = [_frame(s) for s in (1, 2)]
    if not with_seed:
        frames = [f.replace(meta={}) for f in frames]
    names = ["speckle", "tvg_noise", "beam_sidelobes", "range_blur", "interference", "gamma_quantization"]
    candidates = [[make_effect(n) for n in names],
                  [make_effect("speckle", looks=3.4, shape_nu=1.5), make_effect("tvg_noise")],
                  [make_effect("speckle", looks=3.4, shape_nu=9.0, grain_beams=1.1), make_effect("tvg_noise")]]

    def evaluate() -> list[np.ndarray]:
        out = []
        for effects in candidates * 2:  # every candidate twice, each under the same seed
            rng = np.random.default_rng(7)
            out += [apply_effects(f, effects, rng).intensity for f in frames]
        return out

    plain = evaluate()
    with remembering_draws():
        remembered = evaluate()
    for a, b in zip(plain, remembered, strict=True):
        np.testing.assert_array_equal(a, b)
