"""Image formation in the polar domain: the clean "raw sim" a ray-cast simulator gives.

Sonar frame: x along the boresight, y to port, z up; bearing theta is positive to starboard (left to right in
the image), elevation phi positive up. The boresight is tilted down by `pose.tilt` and turned by `pose.yaw`.

- Seabed: solved per output pixel rather than per ray. For each (range r, beam theta) the elevation phi at
  which the seabed lies at distance r is found in closed form for a flat bottom and refined against the
  heightfield (fixed-point iterations). So every pixel the vertical beam reaches has a seabed return, with no
  elevation striping, whatever the range resolution.
- Objects: rays on a (beam, elevation) grid across the vertical aperture hit the nearest solid (occlusion);
  each hit adds its backscatter to the (range, beam) bin it falls in (elevation ambiguity: returns from all
  elevations at one range pile up; vertical faces become bright arcs).
- Shadows: a seabed pixel is dark when the object ray at its (beam, elevation) stops nearer than it, or when
  nearer seabed on its beam rises above its line of sight (relief: rocks, ripples, the far side of a mound).
- Backscatter: per material (scene.MATERIALS), a power law of cos(incidence) plus a specular lobe; a
  bin sums the power of everything in it, weighted by the fraction of the bin each surface element fills.

Amplitude = sqrt(power) with one fixed scale (flat sand seen at 15 deg grazing ~ 0.35), clipped to [0, 1]
like a ray-cast simulator's output: there is no spreading loss, TVG, speckle or noise here.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from sonar_realism.sim.scene import MATERIAL_NAMES, MATERIALS, Pose, Primitive, Scene, Seabed
from sonar_realism.sim.sensor import SensorConfig

# Power of flat sand at 15 deg grazing incidence maps to amplitude 0.35.
_REFERENCE_POWER = math.sin(math.radians(15.0)) ** MATERIALS["sand"].lambert_exponent
POWER_SCALE = 0.35 ** 2 / _REFERENCE_POWER
SEABED_ITERATIONS = 1
# The seabed geometry factor (area of a range bin) grows without bound at normal incidence; cap it.
_MAX_SEABED_FILL = 4.0
# Longest range extent (bins) one object ray's surface element is spread over (grazing faces).
_MAX_SPLAT_BINS = 32.0

_MATERIAL_TABLE = np.array([[m.diffuse, m.lambert_exponent, m.specular, m.shininess] for m in MATERIALS.values()],
                           dtype=np.float32)


def sonar_axes(pose: Pose) -> np.ndarray:
    """Columns: the sonar's x (boresight), y (port), z (up) axes in world coordinates."""
    cy, sy, ct, st = math.cos(pose.yaw), math.sin(pose.yaw), math.cos(pose.tilt), math.sin(pose.tilt)
    # pitch the boresight down by `tilt` (positive rotation about y tilts x towards -z), then yaw about z
    pitch = np.array([[ct, 0.0, st], [0.0, 1.0, 0.0], [-st, 0.0, ct]])
    yaw = np.array([[cy, -sy, 0.0], [sy, cy, 0.0], [0.0, 0.0, 1.0]])
    return yaw @ pitch


def ray_directions(azimuths: np.ndarray, elevations: np.ndarray) -> np.ndarray:
    """Unit directions in the sonar frame, [..., 3], for broadcastable bearing/elevation arrays."""
    cos_phi = np.cos(elevations)
    return np.stack(np.broadcast_arrays(cos_phi * np.cos(azimuths), -cos_phi * np.sin(azimuths),
                                        np.sin(elevations)), axis=-1)


def ray_directions_elevation_derivative(azimuths: np.ndarray, elevations: np.ndarray) -> np.ndarray:
    """d(direction)/d(elevation) in the sonar frame, [..., 3]."""
    sin_phi = np.sin(elevations)
    return np.stack(np.broadcast_arrays(-sin_phi * np.cos(azimuths), sin_phi * np.sin(azimuths),
                                        np.cos(elevations)), axis=-1)


@dataclass(frozen=True)
class _SensorTables:
    """Per-sensor constants of the image formation, computed once per SensorConfig."""

    ranges: np.ndarray
    azimuths: np.ndarray
    elevations: np.ndarray
    ray_dirs: np.ndarray  # sonar-frame ray directions [E, B, 3]
    ray_ups: np.ndarray  # their derivative along elevation [E, B, 3]


@functools.lru_cache(maxsize=8)
def _tables(sensor: SensorConfig) -> _SensorTables:
    azimuths, elevations = sensor.azimuths_rad, sensor.elevations_rad
    return _SensorTables(sensor.ranges_m, azimuths, elevations,
                         ray_directions(azimuths[None, :], elevations[:, None]),
                         ray_directions_elevation_derivative(azimuths[None, :], elevations[:, None]))


def render(scene: Scene, pose: Pose, sensor: SensorConfig, clip: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Clean amplitude [n_ranges, n_beams] float32 and the object mask (uint8 object id, 0 = none). With `clip`
    the amplitude is clipped to [0, 1] as a ray-cast simulator's output is; without, the returns keep their
    dynamic range (the calibrated sensor sets its level and saturation in its own output mapping)."""
    axes = sonar_axes(pose)
    origin = np.array([pose.x, pose.y, pose.z])
    tables = _tables(sensor)
    azimuths, ranges = tables.azimuths, tables.ranges

    hit_t, hit_normal, hit_material, hit_object = _cast_object_rays(scene, origin, axes, tables, sensor)
    power = _seabed_power(scene, origin, axes, azimuths, ranges, sensor, hit_t)
    mask = np.zeros((sensor.n_ranges, sensor.n_beams), dtype=np.uint8)
    _add_object_power(power, mask, hit_t, hit_normal, hit_material, hit_object, axes, tables, sensor)
    amplitude = np.sqrt(power * np.float32(POWER_SCALE))
    return (np.minimum(amplitude, 1.0, out=amplitude) if clip else amplitude), mask


# ----------------------------------------------------------------------------------------------- seabed


def _seabed_rows(seabed: Seabed, height_m: float, tilt: float, ranges: np.ndarray, azimuths: np.ndarray,
                 half_aperture: float) -> tuple[int, int]:
    """Range rows [first, last) outside which no beam can see the seabed from this height and tilt.

    A pixel sees the seabed when its elevation phi = delta + asin(q), q = (ground - height) / (r * norm), lies in
    the aperture; with the ground anywhere between the seabed's lowest and highest point that bounds r per beam.
    Rows outside carry no seabed power, so they are not computed. Bounds are widened by a margin far beyond the
    float32 round-off of the per-pixel test; geometries the bound does not cover (sonar not above every point of
    the seabed, tilt near vertical) keep every row.
    """
    low, high = seabed.height_range
    n_ranges = ranges.size
    ct, st = math.cos(tilt), math.sin(tilt)
    b = np.cos(azimuths) * st
    delta = np.arctan2(b, ct)
    if height_m <= high or ct <= 0.0 or float(delta.min()) - half_aperture <= -math.pi / 2 + 1e-3:
        return 0, n_ranges
    norm = np.sqrt(ct * ct + b * b)
    # phi >= -half_aperture needs q >= sin(-half_aperture - delta); phi <= half_aperture needs q <= sin(half - delta)
    q_low = np.sin(np.maximum(-half_aperture - delta, -math.pi / 2))
    q_high = np.sin(np.minimum(half_aperture - delta, math.pi / 2))
    with np.errstate(divide="ignore"):
        near = np.where(q_low < 0, (height_m - high) / (norm * -q_low), np.inf)
        far = np.where(q_high < 0, (height_m - low) / (norm * -q_high), np.inf)
    margin = 1e-3 * (ranges[-1] - ranges[0]) + 2 * (ranges[-1] - ranges[0]) / max(n_ranges - 1, 1)
    first = int(np.searchsorted(ranges, float(near.min()) * (1 - 1e-3) - margin))
    last = int(np.searchsorted(ranges, float(far.max()) * (1 + 1e-3) + margin, side="right"))
    return min(first, n_ranges), max(min(last, n_ranges), min(first, n_ranges))


def _seabed_power(scene: Scene, origin: np.ndarray, axes: np.ndarray, azimuths: np.ndarray, ranges: np.ndarray,
                  sensor: SensorConfig, hit_t: np.ndarray) -> np.ndarray:
    """Seabed power [n_ranges, n_beams], computed on the rows where the seabed can be in view (zero elsewhere)."""
    half_aperture = math.radians(sensor.vertical_fov_deg) / 2
    first, last = _seabed_rows(scene.seabed, float(origin[2]), pose_tilt(axes), ranges, azimuths, half_aperture)
    power = np.zeros((ranges.size, azimuths.size), dtype=np.float32)
    if last > first:
        power[first:last] = _seabed_band(scene, origin, axes, azimuths, ranges[first:last], sensor, hit_t)
    return power


def _seabed_band(scene: Scene, origin: np.ndarray, axes: np.ndarray, azimuths: np.ndarray, ranges: np.ndarray,
                 sensor: SensorConfig, hit_t: np.ndarray) -> np.ndarray:
    """Seabed power on the rows at `ranges` (solved per pixel; shadows from the object rays' hits)."""
    seabed = scene.seabed
    r = ranges.astype(np.float32)[:, None]
    cos_t = np.cos(azimuths).astype(np.float32)[None, :]
    sin_t = np.sin(azimuths).astype(np.float32)[None, :]
    ct, st = math.cos(pose_tilt(axes)), math.sin(pose_tilt(axes))
    # world z of a ray = r * (sin(phi) * cos(tilt) - cos(phi) * cos(theta) * sin(tilt)) = R sin(phi - delta) r
    a = np.float32(ct)
    b = cos_t * np.float32(st)
    norm = np.sqrt(a * a + b * b)
    # phi = delta + asin(q) with delta = atan2(b, a); sin/cos of phi from the identities, no trigonometry per pixel
    cos_d, sin_d = a / norm, b / norm
    # horizontal heading of the boresight and of the port axis
    fwd = axes[:2, 0] / max(np.linalg.norm(axes[:2, 0]), 1e-12)
    port = np.array([-fwd[1], fwd[0]])
    along_cos, along_sin = cos_t * np.float32(ct), np.float32(st)

    inv_r = np.float32(1.0) / (r * norm)
    ground: np.ndarray | np.float32 = np.float32(0.0)
    for iteration in range(SEABED_ITERATIONS + 1):
        q = (ground - np.float32(origin[2])) * inv_r
        root = np.sqrt(np.maximum(np.float32(1.0) - q * q, np.float32(0.0)))  # = cos(phi - delta)
        sin_p = sin_d * root + cos_d * q
        cos_p = cos_d * root - sin_d * q
        # sonar-frame direction -> world: forward component lies along the tilted boresight
        along = cos_p * along_cos + sin_p * along_sin
        across = -cos_p * sin_t
        dir_x = along * np.float32(fwd[0]) + across * np.float32(port[0])
        dir_y = along * np.float32(fwd[1]) + across * np.float32(port[1])
        x = np.float32(origin[0]) + r * dir_x
        y = np.float32(origin[1]) + r * dir_y
        if iteration < SEABED_ITERATIONS:
            ground = seabed.height_at(x, y)
    ground, grad_x, grad_y, albedo = seabed.sample(x, y)
    half_aperture = math.radians(sensor.vertical_fov_deg) / 2
    visible = (np.abs(q) <= 1.0) & (np.abs(sin_p) <= np.float32(math.sin(half_aperture)))

    # incidence: direction from the sonar (world) against the heightfield normal (-gx, -gy, 1)/|.|
    dir_z = (ground - np.float32(origin[2])) / r
    cos_inc = (grad_x * dir_x + grad_y * dir_y - dir_z) / np.sqrt(1.0 + grad_x * grad_x + grad_y * grad_y)
    cos_inc = np.minimum(np.maximum(cos_inc, np.float32(0.0)), np.float32(1.0))

    material = MATERIALS[seabed.material]
    backscatter = _power_law(cos_inc, material.lambert_exponent) * np.float32(material.diffuse)
    if material.specular > 0:
        backscatter += np.float32(material.specular) * _power_law(cos_inc, material.shininess)
    # surface per bin: r*|d phi/d r| = |q| / cos(phi - delta) (elevation span that lands in one bin, as a
    # length at range r, over the bin length); capped near normal incidence where it diverges
    fill = np.abs(q) / np.maximum(root, np.float32(1e-3))
    fill = np.minimum(fill * np.float32(1.0 / _reference_fill()), np.float32(_MAX_SEABED_FILL))
    power = backscatter * albedo * fill

    _self_shadow(visible, dir_z, q)
    power *= visible
    _shade(power, scene.shadow_floor, sin_p, r, hit_t, ranges, half_aperture, sensor)
    return power


def _shade(power: np.ndarray, floor: float, sin_p: np.ndarray, r: np.ndarray, hit_t: np.ndarray, ranges: np.ndarray,
           half_aperture: float, sensor: SensorConfig) -> None:
    """Scale `power` by `floor` where the object ray at the pixel's (beam, elevation) stopped nearer (acoustic
    shadow).

    Only pixels beyond the nearest hit (one bin of slack), on the beams some ray hit, can be in one: the test
    runs on that box alone.
    """
    blocked = np.isfinite(hit_t)
    if not blocked.any():
        return
    beams = np.flatnonzero(blocked.any(axis=0))
    first_beam, last_beam = int(beams[0]), int(beams[-1]) + 1
    first_row = int(np.searchsorted(ranges, float(hit_t[blocked].min()) - sensor.range_bin_m))
    box = (slice(first_row, None), slice(first_beam, last_beam))
    phi = np.arcsin(np.minimum(np.maximum(sin_p[box], np.float32(-1.0)), np.float32(1.0)))
    step = 2 * half_aperture / sensor.elevation_rays
    elevation_index = np.clip(((phi + half_aperture) / step).astype(np.int32), 0, sensor.elevation_rays - 1)
    blocker = hit_t.astype(np.float32)[elevation_index, np.arange(first_beam, last_beam)[None, :]]
    shadowed = blocker < r[first_row:] - np.float32(sensor.range_bin_m)
    power[box] *= np.where(shadowed, np.float32(floor), np.float32(1.0))


def _self_shadow(visible: np.ndarray, sin_elevation: np.ndarray, q: np.ndarray) -> None:
    """Clear `visible` where nearer seabed along the same beam rises above the line of sight (a rock's or a
    ripple's shadow): a point is lit only if its world elevation angle from the sonar is at least the largest
    one of every nearer point on that beam (the running maximum down the range rows)."""
    solved = np.where(np.abs(q) <= 1.0, sin_elevation, np.float32(-2.0))
    horizon = np.maximum.accumulate(solved, axis=0)
    visible &= solved >= horizon - np.float32(1e-6)


def _power_law(cos_inc: np.ndarray, exponent: float) -> np.ndarray:
    if exponent == 1.0:
        return cos_inc.copy()
    return np.power(cos_inc, np.float32(exponent))


def pose_tilt(axes: np.ndarray) -> float:
    """Downward tilt of the boresight recovered from the sonar axes."""
    return math.asin(max(-1.0, min(1.0, -axes[2, 0])))


def _reference_fill() -> float:
    """Seabed fill at 15 deg grazing: tan(15 deg) (flat bottom, boresight), so sand there has fill 1."""
    return math.tan(math.radians(15.0))


# ----------------------------------------------------------------------------------------------- objects


def _cast_object_rays(scene: Scene, origin: np.ndarray, axes: np.ndarray, tables: _SensorTables,
                      sensor: SensorConfig) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Nearest object hit per (elevation, beam) ray: distance (inf = none), world normal, material, object id.

    Each primitive is tested on the rays near its bounding sphere. Ellipsoids (most primitives: tyre segments,
    stalks, rocks) are tested all together in one vectorised pass over every (ray, ellipsoid) pair; the nearest
    hit per ray wins (the earlier primitive on a tie), and normals are computed for the winners only.
    """
    azimuths, elevations = tables.azimuths, tables.elevations
    n_el, n_beams = elevations.size, azimuths.size
    hit_t = np.full((n_el, n_beams), np.inf, dtype=np.float64)
    hit_normal = np.zeros((n_el, n_beams, 3), dtype=np.float64)
    hit_material = np.zeros((n_el, n_beams), dtype=np.int16)
    hit_object = np.zeros((n_el, n_beams), dtype=np.uint8)
    if not scene.primitives:
        return hit_t, hit_normal, hit_material, hit_object
    directions = tables.ray_dirs @ axes.T  # world, [E, B, 3]
    ray_ids = np.arange(n_el * n_beams).reshape(n_el, n_beams)

    others: list[tuple[int, np.ndarray, np.ndarray]] = []  # (primitive, ray ids, distances) of non-ellipsoids
    ellipsoids = _EllipsoidPairs(origin)
    for index, window in enumerate(_ray_windows(scene.primitives, origin, axes, tables, sensor)):
        if window is None:
            continue
        prim = scene.primitives[index]
        if prim.kind == "ellipsoid":
            ellipsoids.add(prim, index, ray_ids[window].ravel(), directions[window])
        else:
            others.append((index, ray_ids[window].ravel(), intersect(prim, origin, directions[window])[0].ravel()))
    pairs = ellipsoids.intersect()
    rays = np.concatenate([pairs.rays] + [o[1] for o in others])
    distances = np.concatenate([pairs.t] + [o[2] for o in others])
    owners = np.concatenate([pairs.owners] + [np.full(o[1].size, o[0], dtype=np.int32) for o in others])
    candidates = np.flatnonzero(np.isfinite(distances))
    if candidates.size == 0:
        return hit_t, hit_normal, hit_material, hit_object
    candidates = candidates[np.lexsort((owners[candidates], distances[candidates], rays[candidates]))]
    sorted_rays = rays[candidates]
    winners = candidates[np.r_[True, sorted_rays[1:] != sorted_rays[:-1]]]  # first (nearest) candidate per ray
    hit_t.reshape(-1)[rays[winners]] = distances[winners]

    flat_normal = hit_normal.reshape(-1, 3)
    flat_dirs = directions.reshape(-1, 3)
    won_pairs = winners[winners < pairs.rays.size]
    local_normals = pairs.local_normals(won_pairs)
    for index in np.unique(owners[winners]):
        prim = scene.primitives[int(index)]
        ids = rays[winners[owners[winners] == index]]
        if prim.kind == "ellipsoid":
            flat_normal[ids] = local_normals[pairs.owners[won_pairs] == index] @ prim.rotation.T
        else:
            flat_normal[ids] = intersect(prim, origin, flat_dirs[ids])[1]
        hit_material.reshape(-1)[ids] = MATERIAL_NAMES.index(prim.material)
        hit_object.reshape(-1)[ids] = prim.object_id

    # hits below the seabed are buried parts of objects: they neither return nor cast shadows
    hit = np.isfinite(hit_t)
    points = origin + directions[hit] * hit_t[hit][:, None]
    ground = scene.seabed.height_at(points[None, :, 0], points[None, :, 1])[0]
    buried = points[:, 2] < ground - 0.02
    idx = np.nonzero(hit)
    hit_t[idx[0][buried], idx[1][buried]] = np.inf
    return hit_t, hit_normal, hit_material, hit_object


def _ray_windows(primitives: tuple[Primitive, ...], origin: np.ndarray, axes: np.ndarray, tables: _SensorTables,
                 sensor: SensorConfig) -> list[tuple[slice, slice] | None]:
    """Per primitive, the (elevation rows, beams) of the rays that can reach its bounding sphere; None if none can."""
    azimuths, elevations = tables.azimuths, tables.elevations
    beam_margin = float(np.max(np.diff(azimuths))) if azimuths.size > 1 else math.pi
    el_step = float(elevations[1] - elevations[0]) if elevations.size > 1 else math.pi
    local = (np.array([p.bounding_center for p in primitives]) - origin) @ axes  # sonar frame, [P, 3]
    distance = np.linalg.norm(local, axis=1)
    radius = np.array([p.bounding_radius for p in primitives])
    in_range = (distance - radius <= sensor.max_range_m) & (distance + radius >= sensor.min_range_m)
    outside = distance > radius
    safe = np.where(outside, distance, 1.0)
    spread = np.arcsin(np.where(outside, radius / safe, 0.0))
    bearing = np.arctan2(-local[:, 1], local[:, 0])
    elevation = np.arcsin(np.clip(local[:, 2] / safe, -1.0, 1.0))
    edge = np.abs(elevation) + spread
    widen = np.where(edge < 1.5, spread / np.maximum(np.cos(edge), 0.05), math.pi)
    b0 = np.searchsorted(azimuths, bearing - widen - beam_margin)
    b1 = np.searchsorted(azimuths, bearing + widen + beam_margin)
    e0 = np.searchsorted(elevations, elevation - spread - el_step)
    e1 = np.searchsorted(elevations, elevation + spread + el_step)
    windows: list[tuple[slice, slice] | None] = []
    for k in range(len(primitives)):
        if not in_range[k] or (outside[k] and (b0[k] >= b1[k] or e0[k] >= e1[k])):
            windows.append(None)
        elif not outside[k]:  # the sonar is inside the bounding sphere: every ray
            windows.append((slice(0, elevations.size), slice(0, azimuths.size)))
        else:
            windows.append((slice(int(e0[k]), int(e1[k])), slice(int(b0[k]), int(b1[k]))))
    return windows


class _EllipsoidPairs:
    """(ray, ellipsoid) pairs gathered primitive by primitive, then intersected in one vectorised pass.

    The arithmetic per pair is intersect()'s for an ellipsoid, so distances and normals are the same numbers.
    """

    def __init__(self, origin: np.ndarray) -> None:
        self.origin = origin
        self._rays: list[np.ndarray] = []
        self._dirs: list[np.ndarray] = []
        self._origins: list[np.ndarray] = []
        self._semi_axes: list[np.ndarray] = []
        self._owners: list[int] = []

    def add(self, prim: Primitive, index: int, rays: np.ndarray, directions: np.ndarray) -> None:
        self._rays.append(rays)
        self._dirs.append((directions @ prim.rotation).reshape(-1, 3))  # local frame
        self._origins.append(prim.rotation.T @ (self.origin - np.asarray(prim.center)))
        self._semi_axes.append(np.asarray(prim.size))
        self._owners.append(index)

    def intersect(self) -> _EllipsoidPairs:
        """Distance to the first hit per pair (inf = none): fills rays, t, owners."""
        counts = [r.size for r in self._rays]
        self.rays = np.concatenate(self._rays) if counts else np.zeros(0, dtype=np.int64)
        self.owners = np.repeat(np.array(self._owners, dtype=np.int32), counts)
        self.dirs = np.concatenate(self._dirs) if counts else np.zeros((0, 3))
        semi_axes = np.array(self._semi_axes).reshape(-1, 3)
        scaled_origins = np.array(self._origins).reshape(-1, 3) / semi_axes
        self._pair_origins = np.repeat(np.array(self._origins).reshape(-1, 3), counts, axis=0)
        self._pair_semi_axes = np.repeat(semi_axes, counts, axis=0)
        self.t = _ellipsoid_distance(np.repeat(scaled_origins, counts, axis=0), self.dirs / self._pair_semi_axes,
                                     np.repeat([float(o @ o) - 1.0 for o in scaled_origins], counts))
        return self

    def local_normals(self, pairs: np.ndarray) -> np.ndarray:
        """Unit normals (ellipsoid frame) at the hits of the given pairs."""
        return _ellipsoid_local_normal(self._pair_origins[pairs], self.dirs[pairs], self.t[pairs],
                                       self._pair_semi_axes[pairs])


def _add_object_power(power: np.ndarray, mask: np.ndarray, hit_t: np.ndarray, hit_normal: np.ndarray,
                      hit_material: np.ndarray, hit_object: np.ndarray, axes: np.ndarray, tables: _SensorTables,
                      sensor: SensorConfig) -> None:
    hit = np.isfinite(hit_t) & (hit_t >= sensor.min_range_m) & (hit_t < sensor.max_range_m)
    if not hit.any():
        return
    elevations = tables.elevations
    beam_idx = np.nonzero(hit)[1]
    t = hit_t[hit]
    directions = tables.ray_dirs[hit] @ axes.T
    cos_inc = np.clip(-(directions * hit_normal[hit]).sum(axis=1), 0.0, 1.0)
    props = _MATERIAL_TABLE[hit_material[hit]]
    backscatter = props[:, 0] * cos_inc ** props[:, 1] + props[:, 2] * cos_inc ** props[:, 3]
    el_step = float(elevations[1] - elevations[0]) if elevations.size > 1 else math.radians(sensor.vertical_fov_deg)
    # a ray carries r*d_phi/d_r of surface per bin: the discrete form of the seabed's r*|d phi/d r|
    power_per_ray = backscatter * t * el_step / sensor.range_bin_m / _reference_fill()
    # the surface element a ray stands for spans |dt/dphi| * d_phi in range: t * |n.e_phi| / |n.d| * d_phi;
    # spreading its power over that extent keeps a surface continuous instead of striped by the ray spacing
    up = tables.ray_ups[hit] @ axes.T
    normal = hit_normal[hit]
    extent = t * el_step * np.abs((normal * up).sum(axis=1)) / np.maximum(cos_inc, 0.05)
    width = np.clip(extent / sensor.range_bin_m, 1.0, _MAX_SPLAT_BINS)
    centre = (t - sensor.min_range_m) / sensor.range_bin_m
    _splat(power, centre - width / 2, centre + width / 2, beam_idx, power_per_ray)
    range_idx = np.clip(centre.astype(np.int64), 0, sensor.n_ranges - 1)
    mask.reshape(-1)[range_idx * sensor.n_beams + beam_idx] = hit_object[hit]


def _splat(power: np.ndarray, start: np.ndarray, end: np.ndarray, beam: np.ndarray, total: np.ndarray) -> None:
    """Add `total` spread uniformly over range-bin coordinates [start, end) of each beam (bin k spans [k, k+1)).

    The sums run on the box of beams the rays hit, from their nearest bin to the last (the running sum along
    range carries its round-off to the end of each column): the same numbers as over the whole grid, a
    fraction of the passes.
    """
    n_ranges = power.shape[0]
    density = total / (end - start)
    first, last = np.floor(start).astype(np.int64), np.floor(end).astype(np.int64)
    top = int(np.clip(first.min(), 0, n_ranges))
    beam_lo = int(beam.min())
    box_beams = int(beam.max()) + 1 - beam_lo
    box_rows = n_ranges - top
    col = beam - beam_lo
    same = first == last
    split = ~same
    # (range bins, beams, power): elements inside one bin, then the partial first and last bins of the others
    parts = [(first[same], col[same], total[same]),
             (first[split], col[split], density[split] * (first[split] + 1 - start[split])),
             (last[split], col[split], density[split] * (end[split] - last[split]))]
    flat = np.zeros(box_rows * box_beams, dtype=np.float64)
    for rows, cols, weight in parts:
        inside = (rows >= top) & (rows < n_ranges)
        flat += np.bincount((rows[inside] - top) * box_beams + cols[inside], weights=weight[inside],
                            minlength=flat.size)
    # whole bins strictly between first and last: a difference array along range, then a cumulative sum
    middle = split & (last > first + 1)
    if middle.any():
        diff = np.zeros((box_rows + 1) * box_beams, dtype=np.float64)
        lo = np.clip(first[middle] + 1, top, n_ranges) - top
        hi = np.clip(last[middle], top, n_ranges) - top
        diff += np.bincount(lo * box_beams + col[middle], weights=density[middle], minlength=diff.size)
        diff -= np.bincount(hi * box_beams + col[middle], weights=density[middle], minlength=diff.size)
        flat += np.cumsum(diff.reshape(box_rows + 1, box_beams), axis=0)[:box_rows].reshape(-1)
    # cumsum round-off can dip below 0
    power[top:, beam_lo:beam_lo + box_beams] += np.maximum(flat, 0.0).reshape(box_rows, box_beams).astype(np.float32)


# ----------------------------------------------------------------------------------------------- ray tests


def intersect(prim: Primitive, origin: np.ndarray, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance to the first hit (inf where missed) and world normal for rays from `origin` along `directions`."""
    rot = prim.rotation
    o = rot.T @ (origin - np.asarray(prim.center))
    d = directions @ rot  # = (rot.T @ d) per ray
    if prim.kind == "ellipsoid":
        t, n_local = _ellipsoid(o, d, np.asarray(prim.size))
    elif prim.kind == "cylinder":
        t, n_local = _cylinder(o, d, prim.size[0], prim.size[2])
    else:
        t, n_local = _box(o, d, np.asarray(prim.size))
    return t, n_local @ rot.T


def _ellipsoid_distance(scaled_origin: np.ndarray, scaled_dirs: np.ndarray, offset: np.ndarray | float) -> np.ndarray:
    """Distance along unit rays to a unit sphere, in coordinates scaled by the semi-axes: origin o/s, directions
    d/s, offset |o/s|^2 - 1 (one ellipsoid, or one per ray)."""
    a = (scaled_dirs * scaled_dirs).sum(-1)
    b = 2 * (scaled_dirs * scaled_origin).sum(-1)
    disc = b * b - 4 * a * offset
    root = np.sqrt(np.maximum(disc, 0))
    t = (-b - root) / (2 * a)
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def _ellipsoid(o: np.ndarray, d: np.ndarray, semi_axes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    scaled_origin = o / semi_axes
    t = _ellipsoid_distance(scaled_origin, d / semi_axes, float(scaled_origin @ scaled_origin) - 1.0)
    return t, _ellipsoid_local_normal(o, d, np.where(np.isfinite(t), t, 0), semi_axes)


def _ellipsoid_local_normal(o: np.ndarray, d: np.ndarray, t: np.ndarray, semi_axes: np.ndarray) -> np.ndarray:
    point = o + d * t[..., None]
    normal = point / semi_axes ** 2
    return normal / np.maximum(np.linalg.norm(normal, axis=-1, keepdims=True), 1e-12)


def _cylinder(o: np.ndarray, d: np.ndarray, radius: float, length: float) -> tuple[np.ndarray, np.ndarray]:
    dx, dy, dz = d[..., 0], d[..., 1], d[..., 2]
    a = dx * dx + dy * dy
    b = 2 * (o[0] * dx + o[1] * dy)
    c = o[0] ** 2 + o[1] ** 2 - radius ** 2
    disc = b * b - 4 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        t_side = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        z_side = o[2] + t_side * dz
        t_side = np.where((disc >= 0) & (a > 1e-12) & (t_side > 0) & (z_side >= 0) & (z_side <= length),
                          t_side, np.inf)
        best, normal = t_side, np.zeros(d.shape)
        side_point = o + d * np.where(np.isfinite(t_side), t_side, 0)[..., None]
        normal[..., 0], normal[..., 1] = side_point[..., 0] / radius, side_point[..., 1] / radius
        for cap_z, sign in ((0.0, -1.0), (length, 1.0)):
            t_cap = (cap_z - o[2]) / dz
            px, py = o[0] + t_cap * dx, o[1] + t_cap * dy
            ok = (t_cap > 0) & (px * px + py * py <= radius * radius) & np.isfinite(t_cap) & (t_cap < best)
            best = np.where(ok, t_cap, best)
            normal[ok] = (0.0, 0.0, sign)
    return best, normal


def _box(o: np.ndarray, d: np.ndarray, half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / d
        t1 = (-half - o) * inv
        t2 = (half - o) * inv
    t_near = np.minimum(t1, t2)
    t_far = np.maximum(t1, t2)
    t_near = np.where(np.isnan(t_near), -np.inf, t_near)
    t_far = np.where(np.isnan(t_far), np.inf, t_far)
    enter = t_near.max(-1)
    leave = t_far.min(-1)
    t = np.where((leave >= enter) & (enter > 0), enter, np.inf)
    axis = t_near.argmax(-1)
    normal = np.zeros(d.shape)
    np.put_along_axis(normal, axis[..., None], -np.sign(np.take_along_axis(d, axis[..., None], -1)), -1)
    return t, normal
