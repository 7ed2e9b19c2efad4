"""Scenes: a seabed heightfield, objects made of simple solids, and the poses a sonar takes through them.

World frame: x east, y north, z up, metres; the seabed datum is z = 0. Everything random is drawn from the
builder's seed when the scene is built, so a scene is a fixed world: the same seed gives the same seabed,
objects and trajectory, and the simulator sees the same texture from the same pose.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import cv2
import numpy as np

from sonar_realism.errors import ConfigError


@dataclass(frozen=True)
class Material:
    """Acoustic backscatter of a surface: sigma = diffuse * cos(psi)^lambert_exponent + specular * cos(psi)^shininess.

    psi is the incidence angle from the surface normal; exponent 2 is Lambert's law in intensity, rough
    sediments back-scatter closer to exponent 1; metal adds a narrow specular lobe around normal incidence.
    Values are relative to sand.
    """

    diffuse: float
    lambert_exponent: float = 1.0
    specular: float = 0.0
    shininess: float = 40.0


MATERIALS: dict[str, Material] = {
    "sand": Material(1.0, 1.0),
    "mud": Material(0.3, 1.5),
    "gravel": Material(1.6, 0.8),
    "rock": Material(2.0, 1.0, specular=0.5, shininess=10.0),
    "vegetation": Material(0.45, 0.5),
    "metal": Material(1.2, 1.5, specular=12.0, shininess=40.0),
    "concrete": Material(1.8, 1.2, specular=2.0, shininess=20.0),
    "rubber": Material(0.5, 1.5, specular=0.5, shininess=10.0),
    "plastic": Material(0.8, 1.5, specular=3.0, shininess=30.0),
}
MATERIAL_NAMES: tuple[str, ...] = tuple(MATERIALS)


@dataclass(frozen=True)
class Seabed:
    """A heightfield over a square grid with a per-cell albedo (world-fixed sediment patchiness).

    heights[i, j] is the height at (x0 + j*spacing, y0 + i*spacing); normals come from its gradient.
    """

    x0: float
    y0: float
    spacing_m: float
    heights: np.ndarray  # float32 [ny, nx]
    albedo: np.ndarray  # float32 [ny, nx], multiplies the material's backscatter
    material: str = "sand"
    # heights, d/dx, d/dy, albedo packed as one 4-channel image: one cv2.remap samples all four
    fields: np.ndarray = field(init=False, repr=False)
    # lowest and highest height: bounds where the seabed can be seen from a pose without sampling it
    height_range: tuple[float, float] = field(init=False, repr=False)

    def __post_init__(self) -> None:
        gy, gx = np.gradient(self.heights.astype(np.float32), self.spacing_m)
        packed = np.dstack([self.heights, gx, gy, self.albedo]).astype(np.float32)
        object.__setattr__(self, "fields", packed)
        object.__setattr__(self, "height_range", (float(self.heights.min()), float(self.heights.max())))

    def _maps(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        x = np.asarray(x)
        inv = np.float32(1.0 / self.spacing_m)
        map_x = ((x - np.float32(self.x0)) * inv).astype(np.float32).reshape(-1, x.shape[-1])
        map_y = ((np.asarray(y) - np.float32(self.y0)) * inv).astype(np.float32).reshape(-1, x.shape[-1])
        return map_x, map_y

    def height_at(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Bilinear height at world points (edges replicated outside the grid)."""
        map_x, map_y = self._maps(x, y)
        out = cv2.remap(self.heights, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        return out.reshape(np.shape(x))

    def sample(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(height, d height/dx, d height/dy, albedo) at world points, bilinear."""
        map_x, map_y = self._maps(x, y)
        out = cv2.remap(self.fields, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        out = out.reshape(np.shape(x) + (4,))
        return out[..., 0], out[..., 1], out[..., 2], out[..., 3]


PrimitiveKind = Literal["ellipsoid", "cylinder", "box"]


@dataclass(frozen=True)
class Primitive:
    """A solid in world coordinates. `rotation` maps local to world axes.

    ellipsoid: size = semi-axes (a, b, c), centred on `center`;
    cylinder:  size = (radius, radius, length), local z is the axis, from `center` (base) to center + length*z;
    box:       size = half extents, centred on `center`.
    """

    kind: PrimitiveKind
    center: tuple[float, float, float]
    rotation: np.ndarray  # float64 [3, 3]
    size: tuple[float, float, float]
    material: str
    object_id: int

    @property
    def bounding_center(self) -> np.ndarray:
        if self.kind == "cylinder":
            return np.asarray(self.center) + self.rotation[:, 2] * self.size[2] / 2
        return np.asarray(self.center, dtype=np.float64)

    @property
    def bounding_radius(self) -> float:
        if self.kind == "cylinder":
            return math.hypot(self.size[0], self.size[2] / 2)
        if self.kind == "box":
            return math.sqrt(sum(s * s for s in self.size))
        return max(self.size)


@dataclass(frozen=True)
class SceneObject:
    """One named object (its primitives share `object_id`, the value it has in the object mask)."""

    object_id: int
    kind: str
    position: tuple[float, float, float]
    material: str


@dataclass(frozen=True)
class Pose:
    """Sonar pose: position (m), yaw (rad, from +x towards +y) and downward tilt of the boresight (rad)."""

    x: float
    y: float
    z: float
    yaw: float
    tilt: float

    def as_dict(self) -> dict[str, float]:
        return {"x": self.x, "y": self.y, "z": self.z, "yaw": self.yaw, "tilt": self.tilt}


@dataclass(frozen=True)
class Scene:
    name: str
    seed: int
    seabed: Seabed
    primitives: tuple[Primitive, ...]
    objects: tuple[SceneObject, ...]
    trajectory: Callable[[int], list[Pose]]
    trajectory_kind: str
    # Share of the seabed's power left in an object's acoustic shadow: what a recording shows there (sound around
    # or through the object, the elevation beam's lower edge), 0 for a solid occluder in clean physics.
    shadow_floor: float = 0.0


# ----------------------------------------------------------------------------------------------- geometry


def rotation(yaw: float = 0.0, pitch: float = 0.0, roll: float = 0.0) -> np.ndarray:
    """Local-to-world rotation: roll about x, then pitch about y, then yaw about z."""
    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    cr, sr = math.cos(roll), math.sin(roll)
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    return rz @ ry @ rx


def circle_trajectory(center: tuple[float, float], radius_m: float, altitude_m: float, tilt_deg: float,
                      ) -> Callable[[int], list[Pose]]:
    """n poses evenly around a circle, the sonar always looking at `center` (how the paper captured its data)."""

    def poses(n: int) -> list[Pose]:
        out = []
        for i in range(n):
            angle = 2 * math.pi * i / max(n, 1)
            x = center[0] + radius_m * math.cos(angle)
            y = center[1] + radius_m * math.sin(angle)
            # a little heave so the seabed band breathes as on a real vehicle
            z = altitude_m + 0.15 * math.sin(3 * angle)
            out.append(Pose(x, y, z, yaw=angle + math.pi, tilt=math.radians(tilt_deg)))
        return out

    return poses


def transect_trajectory(start: tuple[float, float], end: tuple[float, float], altitude_m: float, tilt_deg: float,
                        ) -> Callable[[int], list[Pose]]:
    """n poses along a straight line, looking along it."""
    yaw = math.atan2(end[1] - start[1], end[0] - start[0])

    def poses(n: int) -> list[Pose]:
        fractions = np.linspace(0.0, 1.0, n) if n > 1 else np.zeros(1)
        return [Pose(start[0] + f * (end[0] - start[0]), start[1] + f * (end[1] - start[1]), altitude_m, yaw,
                     math.radians(tilt_deg)) for f in fractions[:n]]

    return poses


# ----------------------------------------------------------------------------------------------- seabed


def _smooth_noise(rng: np.random.Generator, shape: tuple[int, int], sigma_cells: float) -> np.ndarray:
    """Zero-mean, unit-rms Gaussian random field with correlation length ~sigma_cells.

    Long correlation lengths are drawn on a coarser grid (sigma 2 cells there) and resized: same field
    statistics, a fraction of the cost of a wide blur.
    """
    factor = max(1.0, sigma_cells / 2.0)
    coarse_shape = shape if factor == 1.0 else (max(2, int(math.ceil(shape[0] / factor)) + 1),
                                                 max(2, int(math.ceil(shape[1] / factor)) + 1))
    white = rng.standard_normal(coarse_shape).astype(np.float32)
    sigma = sigma_cells / factor
    if sigma > 0.3:
        white = cv2.GaussianBlur(white, (0, 0), sigma, borderType=cv2.BORDER_REFLECT_101)
    if factor > 1.0:
        white = cv2.resize(white, (shape[1], shape[0]), interpolation=cv2.INTER_CUBIC)
    return (white - white.mean()) / max(float(white.std()), 1e-12)


def make_seabed(rng: np.random.Generator, extent_m: float, center: tuple[float, float] = (0.0, 0.0), *,
                roughness_m: float = 0.01, undulation_m: float = 0.15, ripple_m: float = 0.0,
                patchiness: float = 0.5, material: str = "sand", spacing_m: float | None = None) -> Seabed:
    """A square seabed `extent_m` wide: small-scale roughness, metre-scale undulation, optional sand ripples,
    and an albedo map with darker patches (mud, weed) covering about `patchiness`/2 of the area."""
    if material not in MATERIALS:
        raise ConfigError(f"seabed material {material!r} unknown; known: {', '.join(MATERIAL_NAMES)}")
    spacing = spacing_m or max(0.05, extent_m / 1024)
    n = int(math.ceil(extent_m / spacing)) + 1
    heights = (roughness_m * _smooth_noise(rng, (n, n), 0.15 / spacing)
               + undulation_m * _smooth_noise(rng, (n, n), 3.0 / spacing))
    x0, y0 = center[0] - extent_m / 2, center[1] - extent_m / 2
    if ripple_m > 0:
        xs = x0 + np.arange(n) * spacing
        direction = rng.uniform(0, math.pi)
        grid_x, grid_y = np.meshgrid(xs, y0 + np.arange(n) * spacing)
        phase = (grid_x * math.cos(direction) + grid_y * math.sin(direction)) * 2 * math.pi / 0.7
        heights += (ripple_m * np.sin(phase)).astype(np.float32)
    fine = _smooth_noise(rng, (n, n), 0.4 / spacing)
    coarse = _smooth_noise(rng, (n, n), 2.0 / spacing)
    albedo = np.exp(0.4 * fine + 0.35 * coarse)
    patches = _smooth_noise(rng, (n, n), 0.8 / spacing)
    threshold = np.quantile(patches, 1 - patchiness / 2) if patchiness > 0 else np.inf
    dark = 1.0 / (1.0 + np.exp(-(patches - threshold) * 6.0))  # soft patch edges
    albedo = albedo * (1 - 0.85 * dark)
    return Seabed(x0, y0, spacing, heights.astype(np.float32), albedo.astype(np.float32), material)


# ----------------------------------------------------------------------------------------------- objects


class _ObjectMaker:
    """Places objects on the seabed, giving each its own id (1, 2, ...)."""

    def __init__(self, seabed: Seabed, rng: np.random.Generator) -> None:
        self.seabed = seabed
        self.rng = rng
        self.primitives: list[Primitive] = []
        self.objects: list[SceneObject] = []

    def _ground(self, x: float, y: float) -> float:
        return float(self.seabed.height_at(np.array([[x]]), np.array([[y]]))[0, 0])

    def _new(self, kind: str, x: float, y: float, material: str) -> int:
        object_id = len(self.objects) + 1
        if object_id > 255:
            raise ConfigError("a scene holds at most 255 objects (the mask is uint8)")
        self.objects.append(SceneObject(object_id, kind, (x, y, self._ground(x, y)), material))
        return object_id

    def sphere(self, x: float, y: float, radius: float, material: str = "plastic") -> None:
        oid = self._new("sphere", x, y, material)
        z = self._ground(x, y) + radius * 0.9
        self.primitives.append(Primitive("ellipsoid", (x, y, z), np.eye(3), (radius,) * 3, material, oid))

    def barrel(self, x: float, y: float, radius: float = 0.3, length: float = 0.9, upright: bool = True,
               material: str = "metal") -> None:
        oid = self._new("barrel", x, y, material)
        yaw = self.rng.uniform(0, 2 * math.pi)
        if upright:
            base = (x, y, self._ground(x, y) - 0.05)
            rot = np.eye(3)
        else:
            rot = rotation(yaw=yaw, pitch=math.pi / 2)
            base_xy = np.array([x, y]) - rot[:2, 2] * length / 2
            base = (float(base_xy[0]), float(base_xy[1]), self._ground(x, y) + radius * 0.85)
        self.primitives.append(Primitive("cylinder", base, rot, (radius, radius, length), material, oid))

    def pipe(self, x: float, y: float, radius: float = 0.15, length: float = 4.0, material: str = "metal") -> None:
        oid = self._new("pipe", x, y, material)
        rot = rotation(yaw=self.rng.uniform(0, math.pi), pitch=math.pi / 2)
        base_xy = np.array([x, y]) - rot[:2, 2] * length / 2
        base = (float(base_xy[0]), float(base_xy[1]), self._ground(x, y) + radius * 0.7)
        self.primitives.append(Primitive("cylinder", base, rot, (radius, radius, length), material, oid))

    def box(self, x: float, y: float, half: tuple[float, float, float] = (0.5, 0.4, 0.35),
            material: str = "concrete") -> None:
        oid = self._new("box", x, y, material)
        rot = rotation(yaw=self.rng.uniform(0, math.pi))
        center = (x, y, self._ground(x, y) + half[2] * 0.9)
        self.primitives.append(Primitive("box", center, rot, half, material, oid))

    def tire(self, x: float, y: float, major: float = 0.35, minor: float = 0.11, material: str = "rubber") -> None:
        """A tyre lying flat: a ring of overlapping ellipsoids approximating the torus."""
        oid = self._new("tire", x, y, material)
        z = self._ground(x, y) + minor
        n = 14
        for k in range(n):
            a = 2 * math.pi * k / n
            rot = rotation(yaw=a + math.pi / 2)
            center = (x + major * math.cos(a), y + major * math.sin(a), z)
            segment = major * math.pi / n * 1.25
            self.primitives.append(Primitive("ellipsoid", center, rot, (segment, minor, minor), material, oid))

    def rock(self, x: float, y: float, size: float = 0.35, material: str = "rock", kind: str = "rock") -> None:
        """A rock: an irregular ellipsoid partly buried, with a smaller knob for an irregular outline."""
        oid = self._new(kind, x, y, material)
        axes = size * self.rng.uniform(0.6, 1.3, size=3)
        axes[2] *= 0.7
        rot = rotation(yaw=self.rng.uniform(0, 2 * math.pi), pitch=self.rng.uniform(-0.3, 0.3),
                       roll=self.rng.uniform(-0.3, 0.3))
        z = self._ground(x, y) + axes[2] * 0.5
        self.primitives.append(Primitive("ellipsoid", (x, y, z), rot, tuple(float(a) for a in axes), material, oid))
        offset = rot @ np.array([axes[0] * 0.6, 0.0, axes[2] * 0.2])
        knob = tuple(float(a) for a in axes * self.rng.uniform(0.45, 0.6))
        self.primitives.append(Primitive("ellipsoid", (x + offset[0], y + offset[1], z + offset[2]), rot, knob,
                                         material, oid))

    def boulder(self, x: float, y: float) -> None:
        self.rock(x, y, size=float(self.rng.uniform(0.7, 1.0)), kind="boulder")

    def vegetation(self, x: float, y: float, n_stalks: int = 9, height: float = 0.7) -> None:
        """A clump of thin, leaning stalks (kelp/seagrass): weak, fragmented returns with long thin shadows."""
        oid = self._new("vegetation", x, y, "vegetation")
        for _ in range(n_stalks):
            sx, sy = x + self.rng.normal(0, 0.25), y + self.rng.normal(0, 0.25)
            h = height * self.rng.uniform(0.5, 1.2)
            rot = rotation(yaw=self.rng.uniform(0, 2 * math.pi), pitch=self.rng.uniform(0.0, 0.5))
            top = rot @ np.array([0.0, 0.0, h / 2])
            center = (sx + top[0], sy + top[1], self._ground(sx, sy) + top[2])
            self.primitives.append(Primitive("ellipsoid", center, rot, (0.04, 0.04, h / 2), "vegetation", oid))

    def scatter_positions(self, n: int, radius: float, min_gap: float, center: tuple[float, float] = (0.0, 0.0),
                          ) -> list[tuple[float, float]]:
        """n positions in a disc, about `min_gap` apart (rejection sampling, deterministic under the seed); the
        gap shrinks when the disc is too small to hold n at the full gap."""
        out: list[tuple[float, float]] = []
        gap = min_gap
        while len(out) < n:
            for _ in range(500):
                if len(out) == n:
                    break
                r = radius * math.sqrt(self.rng.uniform())
                a = self.rng.uniform(0, 2 * math.pi)
                p = (center[0] + r * math.cos(a), center[1] + r * math.sin(a))
                if all(math.hypot(p[0] - q[0], p[1] - q[1]) >= gap for q in out):
                    out.append(p)
            gap *= 0.8
        return out


# ----------------------------------------------------------------------------------------------- scenes

# Survey geometry for the default 15 m range; shorter ranges shrink it so the scene stays in view.
REFERENCE_RANGE_M = 15.0
STANDOFF_M = 7.0
ALTITUDE_M = 2.5
TILT_DEG = 15.0
SPREAD_M = 3.0


def _extent(max_range_m: float, radius: float) -> float:
    return 2 * (radius + max_range_m + 1.0)


def _scene(name: str, seed: int, max_range_m: float, place: Callable[[_ObjectMaker, float], None], *,
           seabed_kwargs: dict | None = None, transect: bool = False) -> Scene:
    rng = np.random.default_rng(seed)
    scale = min(1.0, max_range_m / REFERENCE_RANGE_M)
    altitude, standoff = ALTITUDE_M * scale, STANDOFF_M * scale
    if transect:
        length = 20.0
        seabed = make_seabed(rng, _extent(max_range_m, length / 2), **(seabed_kwargs or {}))
        trajectory = transect_trajectory((-length / 2, 0.0), (length / 2, 0.0), altitude, TILT_DEG)
        kind = "transect"
    else:
        seabed = make_seabed(rng, _extent(max_range_m, standoff), **(seabed_kwargs or {}))
        trajectory = circle_trajectory((0.0, 0.0), standoff, altitude, TILT_DEG)
        kind = "circle"
    maker = _ObjectMaker(seabed, rng)
    place(maker, SPREAD_M * max(scale, 0.5))
    return Scene(name, seed, seabed, tuple(maker.primitives), tuple(maker.objects), trajectory, kind)


def _place_constructed(m: _ObjectMaker, spread: float) -> None:
    spots = m.scatter_positions(6, spread, 1.3)
    m.sphere(*spots[0], radius=0.35)
    m.barrel(*spots[1], upright=True)
    m.barrel(*spots[2], upright=False)
    m.box(*spots[3])
    m.tire(*spots[4])
    m.pipe(*spots[5])


def _place_organic(m: _ObjectMaker, spread: float) -> None:
    spots = m.scatter_positions(9, spread * 1.07, 0.9)
    for p in spots[:4]:
        m.rock(*p)
    for p in spots[4:6]:
        m.boulder(*p)
    for p in spots[6:]:
        m.vegetation(*p)


def _place_default(m: _ObjectMaker, spread: float) -> None:
    spots = m.scatter_positions(7, spread, 1.2)
    m.barrel(*spots[0], upright=False)
    m.tire(*spots[1])
    m.box(*spots[2])
    m.sphere(*spots[3], radius=0.3)
    m.boulder(*spots[4])
    m.rock(*spots[5])
    m.vegetation(*spots[6])


def build_default(seed: int, max_range_m: float) -> Scene:
    """A mix of constructed and organic objects on a patchy sandy seabed, circled at a stand-off."""
    return _scene("default", seed, max_range_m, _place_default)


def build_constructed(seed: int, max_range_m: float) -> Scene:
    """Sphere, barrels (upright and lying), concrete box, tyre and pipe on sand, circled at a stand-off."""
    return _scene("constructed", seed, max_range_m, _place_constructed)


def build_organic(seed: int, max_range_m: float) -> Scene:
    """Rocks, boulders and vegetation clumps on a gravelly seabed, circled at a stand-off."""
    return _scene("organic", seed, max_range_m, _place_organic,
                  seabed_kwargs={"roughness_m": 0.02, "material": "gravel", "patchiness": 0.7})


def build_seabed(seed: int, max_range_m: float) -> Scene:
    """Seabed only (rippled sand), along a straight transect."""
    return _scene("seabed", seed, max_range_m, lambda m, spread: None, seabed_kwargs={"ripple_m": 0.008}, transect=True)


SCENES: dict[str, Callable[[int, float], Scene]] = {
    "default": build_default, "constructed": build_constructed, "organic": build_organic, "seabed": build_seabed}


def build_scene(name: str, seed: int, max_range_m: float) -> Scene:
    if name not in SCENES:
        raise ConfigError(f"unknown scene {name!r}; known scenes: {', '.join(SCENES)}")
    return SCENES[name](seed, max_range_m)
