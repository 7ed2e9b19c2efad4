"""The renderer's shortcuts give the numbers of the plain whole-grid computation, bit for bit: seabed rows out of
view skipped, shadows and object splats summed on the box they can touch, ellipsoids intersected all together
(their normals to the last bit of a float64)."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest

from sonar_realism.sim import render as render_module
from sonar_realism.sim.render import intersect, render, sonar_axes
from sonar_realism.sim.scene import MATERIAL_NAMES, Pose, Primitive, Scene, SceneObject, Seabed, build_scene, rotation
from sonar_realism.sim.sensor import M1200D_1200KHZ, M1200D_2100KHZ, SensorConfig

SENSOR = dataclasses.replace(M1200D_1200KHZ, n_beams=96, n_ranges=200, elevation_rays=48)


def views() -> list[tuple[Scene, Pose, SensorConfig]]:
    """Every named scene from a few poses, the narrow mode, and poses the row bound must not crop: looking up,
    sonar below the highest seabed point, steep tilt."""
    out = []
    for name in ("default", "constructed", "organic", "seabed"):
        scene = build_scene(name, 2, SENSOR.max_range_m)
        out += [(scene, pose, SENSOR) for pose in scene.trajectory(3)]
    narrow = dataclasses.replace(M1200D_2100KHZ, n_beams=64, n_ranges=150)
    narrow_scene = build_scene("constructed", 1, narrow.max_range_m)
    out.append((narrow_scene, narrow_scene.trajectory(2)[1], narrow))
    scene = build_scene("organic", 3, SENSOR.max_range_m)
    top = float(scene.seabed.heights.max())
    for z, tilt in ((2.5, -0.2), (top - 0.05, 0.3), (3.0, 1.3), (0.4, 0.05)):
        out.append((scene, Pose(1.0, -2.0, z, yaw=0.7, tilt=tilt), SENSOR))
    return out


def test_seabed_rows_out_of_view_are_skipped_without_changing_a_pixel(monkeypatch) -> None:
    cropped = [render(scene, pose, sensor) for scene, pose, sensor in views()]
    bounds = [render_module._seabed_rows(scene.seabed, pose.z, pose.tilt, sensor.ranges_m, sensor.azimuths_rad,
                                         math.radians(sensor.vertical_fov_deg) / 2) for scene, pose, sensor in views()]
    assert sum(first > 0 for first, _ in bounds) >= 10  # the default survey geometry does skip the near rows
    monkeypatch.setattr(render_module, "_seabed_rows", lambda seabed, height, tilt, ranges, *_: (0, ranges.size))
    for (scene, pose, sensor), (amplitude, mask) in zip(views(), cropped, strict=True):
        whole_amplitude, whole_mask = render(scene, pose, sensor)
        np.testing.assert_array_equal(amplitude, whole_amplitude)
        np.testing.assert_array_equal(mask, whole_mask)


def _whole_grid_splat(power: np.ndarray, start: np.ndarray, end: np.ndarray, beam: np.ndarray,
                      total: np.ndarray) -> None:
    """The splat as first written: sums over the whole grid."""
    n_ranges, n_beams = power.shape
    density = total / (end - start)
    first, last = np.floor(start).astype(np.int64), np.floor(end).astype(np.int64)
    same = first == last
    split = ~same
    parts = [(first[same], beam[same], total[same]),
             (first[split], beam[split], density[split] * (first[split] + 1 - start[split])),
             (last[split], beam[split], density[split] * (end[split] - last[split]))]
    flat = np.zeros(n_ranges * n_beams, dtype=np.float64)
    for rows, cols, weight in parts:
        inside = (rows >= 0) & (rows < n_ranges)
        flat += np.bincount(rows[inside] * n_beams + cols[inside], weights=weight[inside], minlength=flat.size)
    middle = split & (last > first + 1)
    if middle.any():
        diff = np.zeros((n_ranges + 1) * n_beams, dtype=np.float64)
        lo = np.clip(first[middle] + 1, 0, n_ranges)
        hi = np.clip(last[middle], 0, n_ranges)
        diff += np.bincount(lo * n_beams + beam[middle], weights=density[middle], minlength=diff.size)
        diff -= np.bincount(hi * n_beams + beam[middle], weights=density[middle], minlength=diff.size)
        flat += np.cumsum(diff.reshape(n_ranges + 1, n_beams), axis=0)[:n_ranges].reshape(-1)
    power += np.maximum(flat, 0.0).reshape(power.shape).astype(np.float32)


@pytest.mark.parametrize("seed", range(6))
def test_splat_on_the_box_it_touches_equals_the_whole_grid_sum(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    # elements inside one bin, across several, hanging over either end of the grid, in a narrow band of beams
    start = rng.uniform(-5.0, 130.0, n)
    end = start + rng.choice([0.2, 1.5, 12.0, 40.0], n) * rng.uniform(0.5, 1.0, n)
    beam = rng.integers(int(rng.integers(0, 30)), 40, n)
    total = rng.exponential(1.0, n)
    base = rng.uniform(0.0, 1.0, (120, 48)).astype(np.float32)
    boxed, whole = base.copy(), base.copy()
    render_module._splat(boxed, start, end, beam, total)
    _whole_grid_splat(whole, start, end, beam, total)
    np.testing.assert_array_equal(boxed, whole)


def _one_by_one(scene: Scene, pose: Pose, sensor: SensorConfig) -> tuple[np.ndarray, ...]:
    """Nearest hits the first way: intersect() primitive after primitive on the whole ray grid."""
    tables = render_module._tables(sensor)
    axes, origin = sonar_axes(pose), np.array([pose.x, pose.y, pose.z])
    directions = tables.ray_dirs @ axes.T
    hit_t = np.full(directions.shape[:2], np.inf)
    hit_normal = np.zeros(directions.shape)
    hit_material = np.zeros(directions.shape[:2], np.int16)
    hit_object = np.zeros(directions.shape[:2], np.uint8)
    for prim in scene.primitives:
        t, normal = intersect(prim, origin, directions)
        better = t < hit_t
        hit_t[better] = t[better]
        hit_normal[better] = normal[better]
        hit_material[better] = MATERIAL_NAMES.index(prim.material)
        hit_object[better] = prim.object_id
    hit = np.isfinite(hit_t)
    points = origin + directions[hit] * hit_t[hit][:, None]
    ground = scene.seabed.height_at(points[None, :, 0], points[None, :, 1])[0]
    idx = np.nonzero(hit)
    buried = points[:, 2] < ground - 0.02
    hit_t[idx[0][buried], idx[1][buried]] = np.inf
    return hit_t, hit_normal, hit_material, hit_object


def crowded_scene() -> Scene:
    """Overlapping ellipsoids (ties and occlusion between them), a cylinder and a box in front, one object behind
    the sonar, one the sonar sits inside."""
    heights = np.zeros((160, 160), np.float32)
    seabed = Seabed(-16.0, -16.0, 0.2, heights, np.ones_like(heights))
    prims = [Primitive("ellipsoid", (5.0 + 0.3 * k, 0.4 * math.sin(k), 0.3), rotation(yaw=0.4 * k, pitch=0.2),
                       (0.5, 0.2, 0.3), "rock", 1 + k % 3) for k in range(8)]
    prims += [Primitive("ellipsoid", (5.0, 0.0, 0.3), np.eye(3), (0.4, 0.4, 0.4), "metal", 4),  # same as below:
              Primitive("ellipsoid", (5.0, 0.0, 0.3), np.eye(3), (0.4, 0.4, 0.4), "plastic", 5),  # tie, first wins
              Primitive("cylinder", (4.0, -1.0, 0.0), rotation(yaw=0.3, pitch=math.pi / 2), (0.2, 0.2, 2.0), "metal",
                        6),
              Primitive("box", (6.5, 1.2, 0.4), rotation(yaw=0.5), (0.4, 0.3, 0.4), "concrete", 7),
              Primitive("ellipsoid", (-4.0, 0.0, 0.5), np.eye(3), (0.5, 0.5, 0.5), "rock", 8),
              Primitive("ellipsoid", (0.0, 0.0, 2.5), np.eye(3), (0.6, 0.6, 0.6), "vegetation", 9),
              Primitive("ellipsoid", (8.0, -0.5, -0.3), np.eye(3), (0.5, 0.5, 0.4), "rock", 10)]  # partly buried
    objects = tuple(SceneObject(p.object_id, p.kind, p.center, p.material) for p in prims)
    return Scene("crowded", 0, seabed, tuple(prims), objects, lambda n: [], "none")


def test_ellipsoids_intersected_together_give_intersects_hits() -> None:
    look = Pose(0.0, 0.0, 2.5, yaw=0.0, tilt=math.radians(15.0))
    cases = [(crowded_scene(), look, SENSOR), (crowded_scene(), dataclasses.replace(look, z=1.8, yaw=0.3), SENSOR)]
    scene = build_scene("default", 5, SENSOR.max_range_m)
    cases += [(scene, pose, SENSOR) for pose in scene.trajectory(4)]
    for scene, pose, sensor in cases:
        tables = render_module._tables(sensor)
        got = render_module._cast_object_rays(scene, np.array([pose.x, pose.y, pose.z]), sonar_axes(pose), tables,
                                              sensor)
        want = _one_by_one(scene, pose, sensor)
        assert np.isfinite(got[0]).sum() > 100
        for a, b in zip(got[:1] + got[2:], want[:1] + want[2:], strict=True):
            np.testing.assert_array_equal(a, b)
        # normals: the same formula; BLAS rounds a 3 x 3 rotation of a stack of vectors by the stack's shape (1 ulp)
        np.testing.assert_allclose(got[1], want[1], rtol=0, atol=1e-15)
    hit_object = render_module._cast_object_rays(crowded_scene(), np.array([0.0, 0.0, 2.5]), sonar_axes(look),
                                                 render_module._tables(SENSOR), SENSOR)[3]
    assert (hit_object == 4).any() and not (hit_object == 5).any()


def test_shadow_box_scales_the_pixels_the_whole_grid_test_shadows() -> None:
    rng = np.random.default_rng(0)
    sensor = SENSOR
    half = math.radians(sensor.vertical_fov_deg) / 2
    ranges = sensor.ranges_m[50:]
    r = ranges.astype(np.float32)[:, None]
    sin_p = rng.uniform(-0.3, 0.3, (ranges.size, sensor.n_beams)).astype(np.float32)
    hit_t = np.full((sensor.elevation_rays, sensor.n_beams), np.inf)
    hit_t[10:30, 20:31] = rng.uniform(4.0, 9.0, (20, 11))
    hit_t[5, 60] = 7.5
    before = rng.uniform(0.5, 1.0, sin_p.shape).astype(np.float32)
    phi = np.arcsin(np.clip(sin_p, -1.0, 1.0))
    index = np.clip(((phi + half) / (2 * half / sensor.elevation_rays)).astype(np.int32), 0, sensor.elevation_rays - 1)
    shadowed = hit_t.astype(np.float32)[index, np.arange(sensor.n_beams)[None, :]] < r - np.float32(sensor.range_bin_m)
    assert shadowed.sum() > 100  # the objects do cast shadows
    for floor in (0.0, 0.25):
        boxed = before.copy()
        render_module._shade(boxed, floor, sin_p, r, hit_t, ranges, half, sensor)
        np.testing.assert_array_equal(boxed, np.where(shadowed, before * np.float32(floor), before))


def test_a_ridge_on_the_seabed_casts_a_shadow_behind_it_and_a_flat_seabed_none() -> None:
    """Sonar 1 m up looking along +x; a 0.15 m ridge at x 4.0-4.3 m hides the ground up to where the line of sight
    over its top meets the seabed again (x = 4.15 / 0.85 = 4.88 m)."""
    sensor = dataclasses.replace(SENSOR, n_beams=32, n_ranges=400, fov_deg=20.0, max_range_m=8.0)
    xs = -10.0 + 0.05 * np.arange(401)
    flat = np.zeros((401, 401), np.float32)  # [y, x]
    ridge = np.where((xs >= 4.0) & (xs <= 4.3), np.float32(0.15), np.float32(0.0))[None, :] * np.ones((401, 1))
    pose = Pose(0.0, 0.0, 1.0, yaw=0.0, tilt=0.25)
    beam = sensor.n_beams // 2
    slant = np.hypot(np.array([3.5, 3.9, 4.5, 4.8, 5.1, 6.0]), 1.0)  # ground x -> slant range
    rows = np.searchsorted(sensor.ranges_m, slant)

    def column(heights: np.ndarray) -> np.ndarray:
        seabed = Seabed(-10.0, -10.0, 0.05, heights.astype(np.float32), np.ones_like(heights, np.float32))
        image, _ = render(Scene("ridge", 0, seabed, (), (), lambda n: [], "none"), pose, sensor)
        return image[rows, beam]

    assert (column(flat) > 0).all()
    lit_before_a, lit_before_b, hidden_a, hidden_b, lit_after_a, lit_after_b = column(ridge)
    assert min(lit_before_a, lit_before_b, lit_after_a, lit_after_b) > 0
    assert hidden_a == 0 and hidden_b == 0
