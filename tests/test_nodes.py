"""The nodes' logic without sockets: translation with provenance, replay timing, the live simulator source,
and the recorder (lossless frames + contact sheet). A tiny real cDFCVAE checkpoint stands in for the
shipped one so the tests take seconds."""

from __future__ import annotations

import hashlib
from pathlib import Path

import cv2
import numpy as np
import pytest

from sonar_realism.config import from_dict
from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_azimuths, uniform_ranges
from sonar_realism.io import read_frames, write_frames
from sonar_realism.runtime.recording import Recording
from sonar_realism.runtime.sources import ReplaySource, SimSource, Trajectory, replay_offsets
from sonar_realism.runtime.translation import TranslationStage


def tiny_checkpoint(folder) -> str:
    import torch

    from sonar_realism.models.cdfcvae import CDFCVAE, CDFCVAEConfig, save_checkpoint

    torch.manual_seed(0)
    model = CDFCVAE(CDFCVAEConfig(grid=(32, 16), widths=(4, 8), latent_dim=8, bottleneck_hw=(2, 2), skips=1))
    return str(save_checkpoint(model, folder / "tiny.safetensors"))


def frame(seq: int, stamp_s: float = 0.0, shape=(40, 24), samples: int = 0) -> SonarImage:
    rng = np.random.default_rng(seq)
    size = (samples, *shape) if samples else shape
    return SonarImage(rng.random(size, dtype=np.float32), uniform_ranges(shape[0], 12.0),
                      uniform_azimuths(shape[1], 2.0), stamp_ns=int(1_700_000_000e9 + stamp_s * 1e9), seq=seq,
                      meta={"source": "test"})


class FakeClock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(scope="module")
def translator(tmp_path_factory):
    from sonar_realism.models.translate import Translator

    path = tiny_checkpoint(tmp_path_factory.mktemp("ckpt"))
    return Translator.from_checkpoint(path, device="cpu"), path


# ---- translator --------------------------------------------------------------------------------------
def test_translation_keeps_input_identity_and_records_provenance(translator):
    model, path = translator
    sha256 = hashlib.sha256(Path(path).read_bytes()).hexdigest()
    assert model.checkpoint_sha256 == sha256  # the loaded translator carries its hash; the node stamps it
    stage = TranslationStage(model, n=3, temperature=1.0, seed=10, checkpoint_sha256=model.checkpoint_sha256,
                             node="tr")
    inputs = [frame(5, 0.0), frame(6, 0.1)]
    outputs = stage(inputs)
    assert [o.seq for o in outputs] == [5, 6]
    for source, out in zip(inputs, outputs, strict=True):
        assert out.intensity.shape == (3, *source.intensity.shape) and out.intensity.dtype == np.float32
        assert out.stamp_ns == source.stamp_ns and out.same_geometry(source)
        assert 0.0 <= out.intensity.min() and out.intensity.max() <= 1.0
        prov = out.meta["provenance"]
        assert prov["input_seq"] == source.seq and prov["input_stamp_ns"] == source.stamp_ns
        assert prov["checkpoint_sha256"] == sha256 and prov["node"] == "tr"
        assert prov["seed"] == 10 + 5 and out.meta["source"] == "test"
    assert stage.last_ms > 0


def test_seeded_translation_is_reproducible_and_unseeded_is_not(translator):
    model, _ = translator
    seeded = TranslationStage(model, n=2, seed=3)
    a, b = seeded([frame(1)])[0], seeded([frame(1)])[0]
    np.testing.assert_array_equal(a.intensity, b.intensity)
    free = TranslationStage(model, n=2, seed=None)
    assert not np.array_equal(free([frame(1)])[0].intensity, free([frame(1)])[0].intensity)


def test_translator_params_are_validated():
    from sonar_realism.runtime.graph import resolve_node_type

    TranslatorParams = resolve_node_type("translator").PARAMS  # noqa: N806 - a class
    with pytest.raises(ConfigError, match="n"):
        from_dict(TranslatorParams, {"n": 0})
    with pytest.raises(ConfigError, match="unknown key"):
        from_dict(TranslatorParams, {"samples": 4})
    with pytest.raises(ConfigError, match="temperature must be a number >= 0, got nan"):
        from_dict(TranslatorParams, {"temperature": float("nan")})
    with pytest.raises(ConfigError, match="checkpoint /nonexistent.safetensors: no such file"):
        from_dict(TranslatorParams, {"checkpoint": "/nonexistent.safetensors"})


# ---- replay ------------------------------------------------------------------------------------------
def test_replay_offsets_follow_recorded_time_scaled_by_speed_and_cut_to_the_window():
    frames = [frame(i, stamp_s=0.5 * i) for i in range(10)]  # 2 Hz recording, 4.5 s long
    assert [o for o, _ in replay_offsets(iter(frames), speed=1.0)] == [0.5 * i for i in range(10)]
    assert [o for o, _ in replay_offsets(iter(frames), speed=2.0)][:3] == [0.0, 0.25, 0.5]
    assert {o for o, _ in replay_offsets(iter(frames), speed=0.0)} == {0.0}
    window = list(replay_offsets(iter(frames), speed=1.0, start_s=1.0, stop_s=2.0))
    assert [f.seq for _, f in window] == [2, 3, 4] and [o for o, _ in window] == [0.0, 0.5, 1.0]


def test_replay_offsets_never_go_backwards_when_stamps_do():
    frames = [frame(0, 0.0), frame(1, 1.0), frame(2, 0.5), frame(3, 2.0)]
    assert [o for o, _ in replay_offsets(iter(frames), speed=1.0)] == [0.0, 1.0, 1.0, 2.0]


def test_replay_source_paces_loops_renumbers_and_restamps(tmp_path):
    write_frames([frame(i, stamp_s=0.1 * i) for i in (3, 4, 5)], tmp_path / "rec")
    clock = FakeClock()
    once = ReplaySource(tmp_path / "rec", speed=1.0, clock=clock)
    items = [once.next() for _ in range(4)]
    assert items[3] is None
    assert [round(due - 100.0, 6) for due, _ in items[:3]] == [0.0, 0.1, 0.2]
    assert [f.seq for _, f in items[:3]] == [3, 4, 5]

    looped = ReplaySource(tmp_path / "rec", speed=0.0, loop=True, restamp=True, clock=clock)
    frames = [looped.next()[1] for _ in range(7)]
    assert [f.seq for f in frames] == list(range(7))
    assert [f.meta["recorded_seq"] for f in frames] == [3, 4, 5, 3, 4, 5, 3]
    assert looped.passes == 3 and frames[0].meta["recorded_stamp_ns"] == frame(3, 0.3).stamp_ns
    assert frames[0].stamp_ns > frame(3, 0.3).stamp_ns  # restamped with the publish time


def test_replay_source_rejects_bad_settings(tmp_path):
    with pytest.raises(ConfigError):
        ReplaySource(tmp_path, speed=-1.0)
    with pytest.raises(ConfigError):
        ReplaySource(tmp_path, start_s=2.0, stop_s=1.0)


# ---- simulator source --------------------------------------------------------------------------------
def test_sim_source_counts_paces_and_publishes_masks_on_the_same_grid():
    clock = FakeClock()
    source = SimSource(count=3, rate_hz=10.0, clock=clock)
    items = [source.next() for _ in range(4)]
    assert items[3] is None
    assert [round(due - 100.0, 6) for due, _, _ in items[:3]] == [0.0, 0.1, 0.2]
    for seq, (_, sim_frame, mask) in enumerate(items[:3]):
        assert sim_frame.seq == seq and mask.seq == seq and sim_frame.stamp_ns > 0
        assert mask.intensity.dtype == np.uint8 and mask.same_geometry(sim_frame)


def test_sim_source_trajectory_parameters_change_what_the_sonar_sees():
    circle = SimSource(count=1, trajectory=Trajectory("circle", radius_m=5.0)).next()[1]
    transect = SimSource(count=1, trajectory=Trajectory("transect", length_m=30.0)).next()[1]
    assert not np.array_equal(circle.intensity, transect.intensity)
    with pytest.raises(ConfigError, match="trajectory"):
        SimSource(count=1, trajectory=Trajectory("spiral"))


def test_sim_source_with_the_shipped_calibration_gives_that_sensors_views_each_different():
    source = SimSource(count=2, effects="all", calibration="oculus")
    first, second = source.next()[1], source.next()[1]
    assert first.meta["source"] == "sim-calibrated" and first.intensity.dtype == np.uint8
    assert first.intensity.shape[1] == 256 and first.seq == 0 and second.seq == 1
    assert first.intensity.shape != second.intensity.shape or not np.array_equal(first.intensity, second.intensity)
    with pytest.raises(ConfigError, match="scene, sensor and trajectory"):
        SimSource(count=1, scene="organic", calibration="oculus")
    with pytest.raises(ConfigError, match="nowhere.json"):
        SimSource(count=1, calibration="nowhere.json")


# ---- recorder ----------------------------------------------------------------------------------------
@pytest.mark.parametrize("name", ["frames", "frames.npz"])
def test_recording_is_lossless_and_draws_a_contact_sheet(tmp_path, name):
    mixed = name == "frames"  # an NPZ holds one shape: multi-sample and plain frames only mix in a folder
    frames = [frame(i, 0.1 * i, samples=3 if i % 2 and mixed else 0) for i in range(7)]
    frames[1] = frames[1].replace(meta={"provenance": {"input_seq": 1, "checkpoint_sha256": "ab"}})
    recording = Recording(tmp_path / name, tmp_path / "sheet.png", sheet_tiles=4, fan_width_px=64)
    for f in frames:
        recording.add(f)
    summary = recording.close()
    assert summary["frames"] == 7 and recording.close()["frames"] == 7  # close() twice is harmless
    back = list(read_frames(tmp_path / name))
    assert len(back) == 7
    for original, restored in zip(frames, back, strict=True):
        np.testing.assert_array_equal(original.intensity, restored.intensity)
        assert restored.seq == original.seq and restored.stamp_ns == original.stamp_ns
        assert restored.same_geometry(original)
    assert back[1].meta["provenance"]["input_seq"] == 1
    sheet = cv2.imread(str(tmp_path / "sheet.png"))
    assert sheet is not None and sheet.shape[1] >= 4 * 64 and sheet.std() > 0  # 4 tiles (every 2nd frame)


def test_a_frame_whose_meta_cannot_be_written_is_refused_alone(tmp_path):
    from sonar_realism.errors import FrameError

    recording = Recording(tmp_path / "frames", None)
    recording.add(frame(0, 0.1))
    with pytest.raises(FrameError, match="meta: frame seq 1"):
        recording.add(frame(1, 0.2).replace(meta={"sound_speed_mps": float("nan")}))
    recording.add(frame(2, 0.3))
    assert recording.close()["frames"] == 2
    assert [f.seq for f in read_frames(tmp_path / "frames")] == [0, 2]

def test_a_single_sample_axis_is_translated_and_several_samples_are_refused(translator):
    from sonar_realism.errors import FrameError

    model, _ = translator
    stage = TranslationStage(model, n=2, seed=1)
    plain, with_axis = frame(3), frame(3, samples=1)
    np.testing.assert_array_equal(stage([with_axis])[0].intensity, stage([plain])[0].intensity)
    with pytest.raises(FrameError, match="samples"):
        stage([frame(4, samples=2)])


def test_a_restarted_recording_goes_on_after_what_is_on_disk(tmp_path):
    write_frames([frame(i, 0.1) for i in range(5)], tmp_path / "frames")
    index = tmp_path / "frames" / "frames.jsonl"
    index.write_bytes(index.read_bytes() + b'{"file": "frames/0000')  # a last line cut short by a SIGKILL
    recording = Recording(tmp_path / "frames", None, resume=True)
    for i in range(3, 8):  # 3 and 4 come again over a lossless edge: written before the crash, not acknowledged
        recording.add(frame(i, 0.2))
    assert recording.close()["frames"] == 8 and recording.already_written == 2
    assert [f.seq for f in read_frames(tmp_path / "frames")] == list(range(8))
    fresh = Recording(tmp_path / "frames", None)  # not a restart: the folder is written anew
    fresh.add(frame(9, 0.3))
    assert fresh.close()["frames"] == 1 and [f.seq for f in read_frames(tmp_path / "frames")] == [9]
