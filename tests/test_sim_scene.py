"""Scenes, sensor geometry and the clean image formation (occlusion, shadows, elevation, reproducibility)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sonar_realism.errors import ConfigError
from sonar_realism.sim import SCENES, simulate
from sonar_realism.sim.effects import make_effect
from sonar_realism.sim.render import render
from sonar_realism.sim.scene import Pose, Primitive, Scene, SceneObject, Seabed, build_scene, rotation
from sonar_realism.sim.sensor import M1200D_2100KHZ, SensorConfig, oculus_bearing_table

SMALL = SensorConfig(n_beams=64, n_ranges=160, max_range_m=12.0, elevation_rays=64)


def flat_scene(primitives: tuple[Primitive, ...] = ()) -> Scene:
    heights = np.zeros((200, 200), np.float32)
    seabed = Seabed(-20.0, -20.0, 0.2, heights, np.ones_like(heights))
    objects = tuple(SceneObject(p.object_id, p.kind, p.center, p.material) for p in primitives)
    return Scene("test", 0, seabed, primitives, objects, lambda n: [], "none")


LOOK_EAST = Pose(0.0, 0.0, 2.5, yaw=0.0, tilt=math.radians(15.0))


def test_bearing_table_is_sin_spaced_in_hundredths_like_the_real_one() -> None:
    table = oculus_bearing_table(256, 60.0)
    centi = np.degrees(table) * 100
    np.testing.assert_allclose(centi, np.rint(centi), atol=1e-6)
    steps = set(np.rint(np.diff(centi)).astype(int))
    assert steps <= {22, 23, 24, 25, 26} and len(steps) >= 2  # non-uniform, neighbouring hundredths
    assert centi[0] == pytest.approx(-3000) and centi[-1] == pytest.approx(3000)
    sines = np.diff(np.sin(table))
    assert sines.std() / sines.mean() < 0.05  # equal steps in sin(bearing)
    wide = np.degrees(np.diff(oculus_bearing_table(256, 130.0)))
    assert wide[len(wide) // 2] < 0.45 < 0.9 < wide[0]  # 0.4 deg at boresight, ~0.95 at the edges


def test_sensor_validation_names_the_problem() -> None:
    M1200D_2100KHZ.validate()
    with pytest.raises(ConfigError, match="max_range_m"):
        dataclasses.replace(SMALL, min_range_m=5.0, max_range_m=1.0).validate()
    with pytest.raises(ConfigError, match="n_beams"):
        dataclasses.replace(SMALL, n_beams=1).validate()


def test_every_named_scene_builds_and_renders_in_range() -> None:
    assert {"default", "constructed", "organic", "seabed"} <= set(SCENES)
    for name in SCENES:
        scene = build_scene(name, 1, SMALL.max_range_m)
        amplitude, mask = render(scene, scene.trajectory(3)[1], SMALL)
        assert amplitude.dtype == np.float32 and amplitude.shape == (160, 64)
        assert amplitude.min() >= 0 and amplitude.max() <= 1.0 and amplitude.mean() > 0.02
        assert mask.dtype == np.uint8 and mask.shape == amplitude.shape
        if name == "seabed":
            assert not mask.any() and not scene.objects
        else:
            assert mask.any() and set(np.unique(mask)) - {0} <= {o.object_id for o in scene.objects}
    with pytest.raises(ConfigError, match="known scenes"):
        build_scene("moon", 0, 10.0)


def test_scene_kinds_are_as_named() -> None:
    kinds = {name: {o.kind for o in build_scene(name, 2, 15.0).objects} for name in ("constructed", "organic")}
    assert {"sphere", "barrel", "box", "tire", "pipe"} <= kinds["constructed"]
    assert {"rock", "boulder", "vegetation"} <= kinds["organic"]


def test_same_seed_same_world_other_seed_other_world() -> None:
    a = list(simulate("default", "none", 2, seed=4, sensor=SMALL))
    b = list(simulate("default", "none", 2, seed=4, sensor=SMALL))
    c = list(simulate("default", "none", 2, seed=5, sensor=SMALL))
    for (fa, ma), (fb, mb) in zip(a, b, strict=True):
        np.testing.assert_array_equal(fa.intensity, fb.intensity)
        np.testing.assert_array_equal(ma, mb)
    assert not np.array_equal(a[0][0].intensity, c[0][0].intensity)


def test_seabed_starts_where_the_vertical_beam_meets_it() -> None:
    amplitude, _ = render(flat_scene(), LOOK_EAST, SMALL)
    ranges = SMALL.ranges_m
    boresight = amplitude[:, SMALL.n_beams // 2]
    near_edge = 2.5 / math.sin(math.radians(15.0 + 10.0))
    assert not boresight[ranges < near_edge - 0.15].any()
    assert (boresight[(ranges > near_edge + 0.15)] > 0).all()


def test_object_returns_occlude_and_cast_a_shadow() -> None:
    box = Primitive("box", (6.0, 0.0, 0.5), rotation(), (0.5, 0.6, 0.5), "concrete", 1)
    amplitude, mask = render(flat_scene((box,)), LOOK_EAST, SMALL)
    ranges = SMALL.ranges_m
    centre = SMALL.n_beams // 2
    object_rows = np.nonzero(mask[:, centre])[0]
    assert object_rows.size and 5.2 < ranges[object_rows].min() < 6.0  # the front face, at its range
    front = amplitude[object_rows, centre].max()
    behind = (ranges > 7.0) & (ranges < 9.0)
    assert front > 0.5
    assert not amplitude[behind, centre].any()  # acoustic shadow: nothing returns behind the box
    assert amplitude[behind, 5].mean() > 0.05  # the seabed beside the shadow is lit
    free, _ = render(flat_scene(), LOOK_EAST, SMALL)
    assert free[behind, centre].mean() > 0.05  # ... and so is the same place without the box


def test_unclipped_render_keeps_the_bright_returns_the_clipped_one_saturates() -> None:
    plate = Primitive("box", (6.0, 0.0, 0.5), rotation(), (0.5, 0.6, 0.5), "metal", 1)
    clipped, _ = render(flat_scene((plate,)), LOOK_EAST, SMALL)
    raw, _ = render(flat_scene((plate,)), LOOK_EAST, SMALL, clip=False)
    assert clipped.max() == 1.0 and raw.max() > 1.0
    below = raw < 1.0
    np.testing.assert_array_equal(clipped[below], raw[below])


def test_nearer_object_hides_the_one_behind_it() -> None:
    front = Primitive("box", (5.0, 0.0, 0.8), rotation(), (0.3, 0.8, 0.8), "concrete", 1)
    hidden = Primitive("ellipsoid", (7.0, 0.0, 0.5), np.eye(3), (0.4, 0.4, 0.4), "metal", 2)
    _, mask = render(flat_scene((front, hidden)), LOOK_EAST, SMALL)
    centre = slice(SMALL.n_beams // 2 - 2, SMALL.n_beams // 2 + 2)
    assert (mask[:, centre] == 1).any() and not (mask[:, centre] == 2).any()


def test_material_sets_the_echo_strength() -> None:
    def echo(material: str) -> float:
        sphere = Primitive("ellipsoid", (6.0, 0.0, 0.6), np.eye(3), (0.4, 0.4, 0.4), material, 1)
        amplitude, mask = render(flat_scene((sphere,)), LOOK_EAST, SMALL)
        return float(amplitude[mask > 0].sum())

    assert echo("metal") > echo("rubber") > 0


def test_frames_carry_geometry_pose_and_a_pose_fixed_speckle_seed() -> None:
    frames = list(simulate("constructed", "none", 3, seed=2, sensor=SMALL))
    frame, _ = frames[0]
    assert frame.intensity.dtype == np.float32 and frame.intensity_scale == 1.0
    np.testing.assert_allclose(frame.azimuths_rad, SMALL.azimuths_rad)
    assert frame.meta["scene"] == "constructed" and frame.meta["source"] == "sim"
    assert {"x", "y", "z", "yaw", "tilt"} == set(frame.meta["pose"])
    assert [f.seq for f, _ in frames] == [0, 1, 2] and frames[1][0].stamp_ns > frame.stamp_ns
    assert len({f.meta["speckle_seed"] for f, _ in frames}) == 3  # moving sonar: new speckle per pose


def test_static_scene_keeps_its_speckle_while_noise_changes() -> None:
    from sonar_realism.sim.effects import apply_effects
    from sonar_realism.sim.simulate import frame_for

    scene = build_scene("default", 3, SMALL.max_range_m)
    pose = scene.trajectory(4)[0]
    first, _ = frame_for(scene, pose, SMALL, 0)
    second, _ = frame_for(scene, pose, SMALL, 1)  # next ping, same pose
    speckle = [make_effect("speckle")]
    np.testing.assert_array_equal(apply_effects(first, speckle, np.random.default_rng(0)).intensity,
                                  apply_effects(second, speckle, np.random.default_rng(1)).intensity)
    noise = [make_effect("tvg_noise")]
    assert not np.array_equal(apply_effects(first, noise, np.random.default_rng(0)).intensity,
                              apply_effects(second, noise, np.random.default_rng(1)).intensity)


def test_simulate_with_all_effects_gives_8_bit_frames() -> None:
    frames = list(simulate("organic", "all", 2, seed=0, sensor=SMALL, params={"speckle": {"shape_nu": 3.0}}))
    frame, mask = frames[0]
    assert frame.intensity.dtype == np.uint8 and frame.intensity_scale == 255.0
    assert frame.meta["effects"][0]["name"] == "elevation_spread"
    assert next(e for e in frame.meta["effects"] if e["name"] == "speckle")["params"]["shape_nu"] == 3.0
    assert mask.shape == frame.intensity.shape
    with pytest.raises(ConfigError):
        list(simulate("default", "none", -1))


def test_narrow_high_frequency_mode_keeps_the_scene_in_view() -> None:
    sensor = dataclasses.replace(M1200D_2100KHZ, n_beams=64, n_ranges=128)
    frame, mask = next(iter(simulate("default", "none", 1, seed=0, sensor=sensor)))
    assert np.degrees(frame.fov_rad) == pytest.approx(60.0, abs=0.05)
    assert frame.max_range_m < 6.0 and mask.any()
    assert (frame.intensity > 0).mean() > 0.05  # seabed reached within the shorter range


def test_a_pool_of_processes_gives_the_same_frames_in_the_same_order() -> None:
    sensor = dataclasses.replace(M1200D_2100KHZ, n_beams=32, n_ranges=64)
    one = list(simulate("default", "all", 5, 3, sensor))
    pooled = list(simulate("default", "all", 5, 3, sensor, workers=2))
    assert len(pooled) == 5
    for (frame_a, mask_a), (frame_b, mask_b) in zip(one, pooled, strict=True):
        np.testing.assert_array_equal(frame_a.intensity, frame_b.intensity)
        np.testing.assert_array_equal(mask_a, mask_b)


def test_smooth_noise_has_the_requested_shape_at_every_correlation_length():
    from sonar_realism.sim.scene import _smooth_noise

    rng = np.random.default_rng(0)
    for sigma_cells in (0.1, 1.0, 2.0, 2.5, 40.0):  # <= 2 cells is drawn at full resolution, longer ones coarse
        field = _smooth_noise(rng, (341, 340), sigma_cells)
        assert field.shape == (341, 340)
        assert abs(float(field.std()) - 1.0) < 1e-3
