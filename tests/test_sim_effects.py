"""Each effect changes the image in its documented signature and nowhere else; seeds reproduce; bad input fails."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import pytest

from sonar_realism.errors import ConfigError
from sonar_realism.frames import SonarImage, uniform_ranges
from sonar_realism.sim import effects as effects_module
from sonar_realism.sim.effects import (
    EFFECTS,
    PIPELINE_ORDER,
    BeamSidelobes,
    Effect,
    ElevationSpread,
    GammaQuantization,
    Interference,
    MotionBlur,
    Multipath,
    RangeBlur,
    RingDown,
    Speckle,
    TvgNoise,
    apply_effects,
    calibrated_parameters,
    make_effect,
    resolve_effects,
)
from sonar_realism.sim.sensor import oculus_bearing_table

N_RANGES, N_BEAMS, MAX_RANGE = 160, 96, 10.0


def make_frame(intensity: np.ndarray, **meta: object) -> SonarImage:
    return SonarImage(intensity.astype(np.float32), uniform_ranges(intensity.shape[-2], MAX_RANGE, 0.2),
                      oculus_bearing_table(intensity.shape[-1], 130.0), intensity_scale=1.0,
                      meta={"sonar_altitude_m": 2.0, "sonar_tilt_rad": math.radians(12.0), **meta})


def point_image(row: int = 80, beam: int = 48, level: float = 1.0) -> np.ndarray:
    image = np.zeros((N_RANGES, N_BEAMS), np.float32)
    image[row, beam] = level
    return image


def rng(seed: int = 0) -> np.random.Generator:
    return np.random.default_rng(seed)


def test_catalogue_is_the_registry_in_pipeline_order() -> None:
    assert set(EFFECTS) == set(PIPELINE_ORDER) and len(PIPELINE_ORDER) == len(EFFECTS)
    assert [EFFECTS[n].ORDER for n in PIPELINE_ORDER] == sorted(EFFECTS[n].ORDER for n in PIPELINE_ORDER)
    assert PIPELINE_ORDER[-1] == "gamma_quantization"
    assert calibrated_parameters() == tuple((n, p, p in EFFECTS[n].LOG_SCALE) for n in EFFECTS
                                            for p in EFFECTS[n].CALIBRATED)


def test_adding_an_effect_is_one_class() -> None:
    @dataclass(frozen=True)
    class Dimmer(Effect, order=95):
        """A test-only stage: halves the amplitude. Registered by its class statement alone, then removed so the
        catalogue the other tests see is unchanged."""

        name: ClassVar[str] = "test_dimmer"
        factor: float = 0.5
        PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {"factor": (0.1, 1.0)}
        VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {"factor": (0.0, 1.0)}
        CALIBRATED: ClassVar[tuple[str, ...]] = ("factor",)

        def apply(self, intensity, frame, rng):
            return intensity * np.float32(self.factor)

    try:
        assert effects_module._REGISTRY["test_dimmer"] is Dimmer
        with pytest.raises(ConfigError, match="registered twice"):
            class Again(Dimmer, order=96):
                """Same name as Dimmer."""
    finally:
        del effects_module._REGISTRY["test_dimmer"]


def test_an_effect_cannot_calibrate_a_parameter_without_bounds() -> None:
    with pytest.raises(ConfigError, match="without bounds"):
        @dataclass(frozen=True)
        class Broken(Effect, order=97):
            """Declares a calibrated parameter it has no search bounds for."""

            name: ClassVar[str] = "test_broken"
            level: float = 1.0
            PARAM_BOUNDS: ClassVar[dict[str, tuple[float, float]]] = {}
            VALID_RANGE: ClassVar[dict[str, tuple[float, float]]] = {"level": (0.0, 2.0)}
            CALIBRATED: ClassVar[tuple[str, ...]] = ("level",)

            def apply(self, intensity, frame, rng):
                return intensity
    assert "test_broken" not in effects_module._REGISTRY


@pytest.mark.parametrize("name", PIPELINE_ORDER)
def test_defaults_validate_and_bounds_are_sane(name: str) -> None:
    cls = EFFECTS[name]
    effect = cls()
    effect.validate()
    fields = {f.name for f in dataclasses.fields(cls)}
    assert set(cls.PARAM_BOUNDS) <= fields
    for param, (low, high) in cls.PARAM_BOUNDS.items():
        valid_low, valid_high = cls.VALID_RANGE[param]
        assert valid_low <= low < high <= valid_high, param
    assert cls.__doc__ and len(cls.__doc__) > 100  # the physics is documented


@pytest.mark.parametrize("name", PIPELINE_ORDER)
def test_same_seed_same_output_and_sample_axis_kept(name: str) -> None:
    base = np.random.default_rng(7).uniform(0.05, 0.6, (N_RANGES, N_BEAMS)).astype(np.float32)
    frame = make_frame(base)
    effect = make_effect(name, **({"rate_per_ping": 3.0} if name == "interference" else {}))
    first = effect.apply(base, frame, rng(3))
    second = effect.apply(base, frame, rng(3))
    np.testing.assert_array_equal(first, second)
    assert first.shape == base.shape and np.isfinite(first.astype(np.float64)).all()
    stacked = np.stack([base, base * 0.5])
    out = effect.apply(stacked, frame, rng(3))
    assert out.shape == stacked.shape


@pytest.mark.parametrize("name", PIPELINE_ORDER)
def test_out_of_range_parameter_is_rejected_with_its_name(name: str) -> None:
    param = next(iter(EFFECTS[name].PARAM_BOUNDS))
    with pytest.raises(ConfigError, match=f"{name}.{param}"):
        make_effect(name, **{param: 1e9})
    with pytest.raises(ConfigError, match=param):
        make_effect(name, **{param: "loud"})


def test_unknown_effect_lists_the_known_ones() -> None:
    with pytest.raises(ConfigError, match="known effects: .*speckle"):
        make_effect("sparkle")
    with pytest.raises(ConfigError, match="unknown key"):
        make_effect("speckle", nu=3.0)
    with pytest.raises(ConfigError, match="more than once"):
        resolve_effects(["speckle", "speckle"])
    with pytest.raises(ConfigError, match="not selected"):
        resolve_effects("speckle", {"tvg_noise": {"noise_amplitude": 0.1}})
    with pytest.raises(ConfigError, match="unknown effect.*bogus; known effects: "):
        resolve_effects("speckle", {"bogus": {"x": 3.0}})


def test_speckle_is_multiplicative_power_preserving_and_k_distributed() -> None:
    flat = np.full((400, 200), 0.5, np.float32)
    frame = make_frame(flat)
    rayleigh = Speckle(shape_nu=1e6, grain_beams=0.0, grain_ranges=0.0).apply(flat, frame, rng())
    power = rayleigh.astype(np.float64) ** 2
    assert power.mean() == pytest.approx(0.25, rel=0.03)
    assert power.var() / power.mean() ** 2 == pytest.approx(1.0, abs=0.06)  # exponential intensity: SI = 1
    heavy = Speckle(shape_nu=2.0, grain_beams=0.0, grain_ranges=0.0).apply(flat, frame, rng())
    heavy_power = heavy.astype(np.float64) ** 2
    assert heavy_power.var() / heavy_power.mean() ** 2 == pytest.approx(1 + 2 / 2.0, rel=0.12)  # K: SI = 1 + 2/nu
    dark = Speckle().apply(np.zeros_like(flat), frame, rng())
    assert not dark.any()  # nothing is added where there is no echo


def test_complex_gaussian_draws_are_independent_standard_normals() -> None:
    re, im = effects_module._complex_gaussian(rng(3), (600, 500))
    assert re.dtype == im.dtype == np.float32 and re.shape == im.shape == (600, 500)
    for part in (re.astype(np.float64), im.astype(np.float64)):
        assert abs(part.mean()) < 0.01 and part.var() == pytest.approx(1.0, abs=0.01)
        assert ((part - part.mean()) ** 4).mean() / part.var() ** 2 == pytest.approx(3.0, abs=0.05)  # Gaussian
        assert abs(np.corrcoef(part[:, 1:].ravel(), part[:, :-1].ravel())[0, 1]) < 0.01  # white
    assert abs(np.corrcoef(re.ravel(), im.ravel())[0, 1]) < 0.01
    power = re.astype(np.float64) ** 2 + im.astype(np.float64) ** 2  # exponential with mean 2: P(> 2x) = e^-x
    for x in (0.1, 1.0, 3.0, 6.0):
        assert (power > 2 * x).mean() == pytest.approx(math.exp(-x), rel=0.05)


def test_speckle_of_several_looks_is_lighter_than_rayleigh_and_one_look_keeps_its_draws() -> None:
    flat = np.full((400, 200), 0.5, np.float32)
    frame = make_frame(flat)
    for looks in (1.5, 2.0, 3.7):
        out = Speckle(shape_nu=1e6, grain_beams=0.0, grain_ranges=0.0, looks=looks).apply(flat, frame, rng())
        power = out.astype(np.float64) ** 2
        assert power.mean() == pytest.approx(0.25, rel=0.03)  # power kept
        assert power.var() / power.mean() ** 2 == pytest.approx(1.0 / looks, rel=0.08)  # SI = 1 / looks
    one = Speckle(shape_nu=3.0, looks=1.0)
    source = rng(5)  # one look: the field, then the texture, as before looks existed
    expected = flat * np.sqrt(one.pattern(source, flat.shape)
                              * effects_module._gamma_texture(source, 3.0, flat.shape))
    np.testing.assert_array_equal(one.apply(flat, frame, rng(5)), expected)


def test_speckle_grain_is_anisotropic_as_configured() -> None:
    flat = np.full((300, 300), 0.5, np.float32)
    out = Speckle(shape_nu=1e6, grain_beams=2.0, grain_ranges=0.4).apply(flat, make_frame(flat), rng()) ** 2
    d = out - out.mean()
    across = (d[:, 1:] * d[:, :-1]).mean() / d.var()
    along = (d[1:, :] * d[:-1, :]).mean() / d.var()
    assert across > 0.6 and along < 0.2


def test_speckle_is_frozen_for_a_given_scene_and_pose() -> None:
    flat = np.full((N_RANGES, N_BEAMS), 0.5, np.float32)
    frozen = make_frame(flat, speckle_seed=1234)
    a = Speckle().apply(flat, frozen, rng(1))
    b = Speckle().apply(flat, frozen, rng(2))
    np.testing.assert_array_equal(a, b)  # same world + pose: same speckle whatever the ping's draws
    moved = Speckle().apply(flat, make_frame(flat, speckle_seed=1235), rng(1))
    assert np.corrcoef(a.ravel(), moved.ravel())[0, 1] < 0.1  # another pose decorrelates it


def test_beam_sidelobes_spread_only_along_constant_range() -> None:
    image = point_image()
    out = BeamSidelobes(sidelobe_db=-20.0, crosstalk_db=-40.0).apply(image, make_frame(image), rng())
    changed_rows = np.nonzero((out != 0).any(axis=1))[0]
    assert changed_rows.tolist() == [80]
    row = out[80].astype(np.float64) ** 2
    assert row.sum() == pytest.approx(1.0 + 10 ** (-40 / 10) * N_BEAMS / N_BEAMS, rel=0.02)  # power preserved
    assert (row > 1e-4).sum() > 10  # smeared over many beams (sidelobes + floor)
    assert row.argmax() == 48


def test_beam_sidelobe_level_sets_the_first_sidelobe() -> None:
    image = point_image()
    frame = make_frame(image)
    effect = BeamSidelobes(mainlobe_deg=2.0, sidelobe_db=-25.0, crosstalk_db=-120.0)
    kernel = effect.kernel(frame)
    centre = kernel.size // 2
    right = kernel[centre:]
    first_null = int(np.argmax(np.diff(right) > 0))  # pattern stops falling at the first null
    sidelobe = right[first_null:].max()
    assert 10 * math.log10(sidelobe / right[0]) == pytest.approx(-25.0, abs=2.0)


def test_wide_beam_sidelobes_leave_no_nan_beside_dark_cells() -> None:
    # A mainlobe of several beams on a frame of bright points in black water: rounding in the wide filter gives
    # tiny negative powers next to the zeros, which must not become NaN amplitudes.
    image = np.zeros((N_RANGES, 256), np.float32)
    image[::7, ::5] = np.random.default_rng(0).uniform(0.2, 1.0, image[::7, ::5].shape)
    frame = make_frame(image)
    for mainlobe_deg in (0.6, 3.0, 5.0):
        out = BeamSidelobes(mainlobe_deg=mainlobe_deg).apply(image, frame, rng())
        assert np.isfinite(out).all() and (out >= 0).all()


def test_range_blur_spreads_only_along_range() -> None:
    image = point_image()
    out = RangeBlur(resolution_m=0.2, sidelobe_db=-20.0).apply(image, make_frame(image), rng())
    changed_beams = np.nonzero((out != 0).any(axis=0))[0]
    assert changed_beams.tolist() == [48]
    column = out[:, 48].astype(np.float64) ** 2
    assert column.sum() == pytest.approx(1.0, rel=0.01)
    assert (column > 1e-4).sum() >= 3 and column.argmax() == 80


def test_tvg_noise_floor_rises_with_range_and_is_redrawn_every_ping() -> None:
    zero = np.zeros((N_RANGES, N_BEAMS), np.float32)
    frame = make_frame(zero)
    effect = TvgNoise(noise_amplitude=0.1, tvg_log_coeff_db=30.0, absorption_db_per_m=0.5)
    out = effect.apply(zero, frame, rng(1)).astype(np.float64)
    rms = np.sqrt((out ** 2).mean(axis=1))
    # at the profile's level (noise_amplitude at the last bin, a little less over the last 20 rows)
    assert rms[-20:].mean() == pytest.approx(np.sqrt((effect.noise_profile(frame)[-20:] ** 2).mean()), rel=0.05)
    assert effect.noise_profile(frame)[-1] == pytest.approx(0.1, rel=1e-6)
    assert rms[:20].mean() < 0.2 * rms[-20:].mean()
    assert np.all(np.diff(effect.noise_profile(frame)) > 0)
    other = effect.apply(zero, frame, rng(2)).astype(np.float64)
    residual = out - out.mean(axis=1, keepdims=True)  # remove the shared range trend before comparing
    other_residual = other - other.mean(axis=1, keepdims=True)
    assert np.corrcoef(residual.ravel(), other_residual.ravel())[0, 1] < 0.1  # electronic noise is not frozen


def test_tvg_beam_noise_contrast_stripes_the_noise_floor_not_the_lit_seabed() -> None:
    image = np.zeros((N_RANGES, N_BEAMS), np.float32)
    image[N_RANGES // 2:] = 0.5  # a lit seabed over a dark water column
    frame = make_frame(image)

    def column_spread(out: np.ndarray, rows: slice) -> float:
        means = out[rows].astype(np.float64).mean(axis=0)
        return float(means.std() / means.mean())

    plain = TvgNoise(noise_amplitude=0.05, tvg_log_coeff_db=20.0)
    striped = TvgNoise(noise_amplitude=0.05, tvg_log_coeff_db=20.0, beam_noise_contrast=0.5)
    water, seabed = slice(N_RANGES // 4, N_RANGES // 2), slice(N_RANGES // 2, None)
    plain_out, striped_out = plain.apply(image, frame, rng(3)), striped.apply(image, frame, rng(3))
    assert column_spread(striped_out, water) > 3 * column_spread(plain_out, water)
    assert column_spread(striped_out, seabed) < 0.02
    # off, the ping draws nothing more: the output is what it was before the parameter existed
    assert np.array_equal(TvgNoise(noise_amplitude=0.05, tvg_log_coeff_db=20.0, beam_noise_contrast=0.0)
                          .apply(image, frame, rng(3)), plain_out)


def test_tvg_residual_ramp_scales_signal_by_range_only() -> None:
    flat = np.full((N_RANGES, N_BEAMS), 0.3, np.float32)
    out = TvgNoise(noise_amplitude=0.0, residual_ramp_db=6.0).apply(flat, make_frame(flat), rng())
    assert out[0] == pytest.approx(0.3, rel=1e-5)
    assert out[-1] == pytest.approx(0.3 * 10 ** (6 / 20), rel=1e-4)
    assert np.allclose(out, out[:, :1])  # no change across beams


def test_elevation_spread_is_a_weighting_that_moves_no_energy() -> None:
    base = np.random.default_rng(0).uniform(0.1, 0.5, (N_RANGES, N_BEAMS)).astype(np.float32)
    base[:, 10] = 0.0
    frame = make_frame(base)
    effect = ElevationSpread(beamwidth_deg=15.0, floor_db=-30.0)
    out = effect.apply(base, frame, rng())
    assert not out[:, 10].any()
    weight = effect.weight(frame)
    np.testing.assert_allclose(out, base * weight, rtol=1e-6)
    assert weight.max() <= 1.0 and weight.min() >= 10 ** (-30 / 20) - 1e-6
    boresight = weight[:, N_BEAMS // 2]
    # the seabed is seen at the beam's centre (phi = 0) at r = altitude / sin(tilt): the pattern peaks there
    peak_range = frame.ranges_m[int(np.argmax(boresight))]
    assert peak_range == pytest.approx(2.0 / math.sin(math.radians(12.0)), rel=0.05)


def _float64_vertical_weight(frame: SonarImage, beamwidth_deg: float, floor_db: float) -> np.ndarray:
    """The pattern weight as first written: float64 throughout, from seabed_elevation()."""
    phi = effects_module.seabed_elevation(frame, frame.meta["sonar_altitude_m"], frame.meta["sonar_tilt_rad"])
    one_way_power = np.sinc(0.886 * np.degrees(phi) / beamwidth_deg) ** 2
    return np.maximum(one_way_power, 10 ** (floor_db / 20)).astype(np.float32)


def test_elevation_spread_weight_in_float32_is_the_float64_pattern_to_5e_6() -> None:
    x = np.linspace(-1.0, 1.0, 100_001, dtype=np.float32)
    assert np.abs(effects_module._arcsin32(x) - np.arcsin(x.astype(np.float64))).max() < 3e-7
    image = np.ones((N_RANGES, N_BEAMS), np.float32)
    (low_bw, high_bw), (low_floor, high_floor) = ElevationSpread.PARAM_BOUNDS.values()
    for altitude, tilt in ((2.0, 0.2), (0.5, 0.05), (3.7, 0.6), (12.0, 0.3)):
        frame = make_frame(image, sonar_altitude_m=altitude, sonar_tilt_rad=tilt)
        for beamwidth, floor_db in ((16.5, -26.0), (low_bw, low_floor), (high_bw, high_floor), (low_bw, high_floor)):
            weight = ElevationSpread(beamwidth_deg=beamwidth, floor_db=floor_db).weight(frame)
            np.testing.assert_allclose(weight, _float64_vertical_weight(frame, beamwidth, floor_db), rtol=0,
                                       atol=5e-6)


def test_elevation_spread_in_float32_leaves_8_bit_frames_as_they_were(monkeypatch) -> None:
    from sonar_realism.sim import simulate
    from sonar_realism.sim.sensor import SensorConfig

    sensor = SensorConfig(n_beams=128, n_ranges=256)
    fast = [frame.intensity for frame, _ in simulate("default", "all", 4, 2, sensor)]
    monkeypatch.setattr(ElevationSpread, "weight",
                        lambda self, frame: _float64_vertical_weight(frame, self.beamwidth_deg, self.floor_db))
    for new, (frame, _) in zip(fast, simulate("default", "all", 4, 2, sensor), strict=True):
        changed = new.astype(np.int16) - frame.intensity
        assert np.abs(changed).max() <= 1 and np.count_nonzero(changed) <= 1e-3 * changed.size


def test_multipath_adds_energy_only_beyond_the_true_range() -> None:
    image = np.zeros((N_RANGES, N_BEAMS), np.float32)
    image[50, 20:40] = 0.8
    frame = make_frame(image)
    effect = Multipath(reflection_coeff=0.5, ghost_offset_m=1.0, n_ghosts=2)
    out = effect.apply(image, frame, rng())
    np.testing.assert_array_equal(out[:51], image[:51])
    shift = 1.0 / frame.range_resolution_m
    ghost_rows = np.nonzero(out[51:].any(axis=1))[0] + 51
    assert ghost_rows.min() >= 50 + math.floor(shift)
    assert set(np.nonzero(out.any(axis=0))[0]) == set(range(20, 40))  # same bearings only
    ghost_power = (out[51:].astype(np.float64) ** 2).sum()
    assert ghost_power == pytest.approx(20 * 0.64 * (0.5 ** 2 + 0.5 ** 4), rel=0.01)


def test_multipath_coherence_speckles_the_ghost_over_the_direct_return_keeping_its_mean_power() -> None:
    image = np.full((N_RANGES, N_BEAMS), 0.5, np.float32)
    frame = make_frame(image)
    smooth = Multipath(reflection_coeff=0.6, ghost_offset_m=1.0).apply(image, frame, rng())
    coherent = Multipath(reflection_coeff=0.6, ghost_offset_m=1.0, coherence=1.0).apply(image, frame, rng())
    overlap = slice(math.ceil(1.0 / frame.range_resolution_m) + 1, None)
    assert np.ptp(smooth[overlap]) < 1e-6  # powers add: a flat scene stays flat
    power = coherent[overlap].astype(np.float64) ** 2
    assert power.mean() == pytest.approx(0.25 * (1 + 0.36), rel=0.03)  # the cross term averages out
    assert power.std() / power.mean() == pytest.approx(2 * 0.6 / 1.36 / math.sqrt(2), rel=0.05)
    before_ghost = math.floor(1.0 / frame.range_resolution_m)
    np.testing.assert_allclose(coherent[:before_ghost], image[:before_ghost], rtol=1e-6)
    untouched = rng()
    Multipath(reflection_coeff=0.6, ghost_offset_m=1.0).apply(image, frame, untouched)
    assert untouched.random() == rng().random()  # no draws without coherence: frames without it are as before


def test_motion_blur_shears_along_bearing_growing_with_range() -> None:
    image = np.zeros((N_RANGES, N_BEAMS), np.float32)
    image[:, 48] = 0.5
    frame = make_frame(image)
    static = MotionBlur(yaw_rate_deg_s=0.0, surge_m_s=0.0, integration_s=0.0).apply(image, frame, rng())
    np.testing.assert_allclose(static, image, atol=1e-6)
    turning = MotionBlur(yaw_rate_deg_s=300.0, surge_m_s=0.0, integration_s=0.0).apply(image, frame, rng())
    centroid = (turning ** 2 * np.arange(N_BEAMS)).sum(axis=1) / np.maximum((turning ** 2).sum(axis=1), 1e-12)
    assert abs(centroid[-1] - 48) > abs(centroid[5] - 48) + 0.5  # far rows move more than near rows
    point = point_image()
    smeared = MotionBlur(yaw_rate_deg_s=60.0, surge_m_s=0.0, integration_s=0.1).apply(point, make_frame(point),
                                                                                        rng())
    assert np.nonzero(smeared.any(axis=1))[0].tolist() == [80]  # rotation alone never mixes ranges


def test_motion_blur_of_discrete_looks_repeats_an_echo_where_the_continuous_window_smears_it() -> None:
    point = point_image()
    frame = make_frame(point)
    column = int(np.argmax(point.max(axis=0)))
    step = math.degrees(frame.fov_rad) / (frame.n_beams - 1)
    window = 10 * step / 60.0  # the sonar turns 10 beams during the window
    continuous = MotionBlur(yaw_rate_deg_s=60.0, surge_m_s=0.0, integration_s=window).apply(point, frame, rng())
    for looks in (0.0, 1.4):  # below 2 the window is continuous
        same = MotionBlur(yaw_rate_deg_s=60.0, surge_m_s=0.0, integration_s=window, looks=looks)
        np.testing.assert_array_equal(same.apply(point, frame, rng()), continuous)
    double = MotionBlur(yaw_rate_deg_s=60.0, surge_m_s=0.0, integration_s=window, looks=2.0).apply(point, frame,
                                                                                                   rng())
    row = np.nonzero(point.any(axis=1))[0][0]
    lit = np.nonzero(double[row] > 0.1 * double[row].max())[0]
    assert lit.min() <= column - 4 and lit.max() >= column + 4  # two copies 10 beams apart, about the echo
    assert double[row, column] < 0.1 * double[row].max()  # with nothing between them
    assert (continuous[row, column - 3:column + 4] > 0).all()  # where the continuous window fills the band
    total = (point ** 2).sum()
    assert (double ** 2).sum() == pytest.approx(total, rel=0.02)  # averaging keeps the power


def test_ring_down_touches_only_the_first_rows() -> None:
    base = np.full((N_RANGES, N_BEAMS), 0.2, np.float32)
    frame = make_frame(base)
    effect = RingDown(amplitude=0.6, decay_m=0.1, beam_ripple=0.2)
    out = effect.apply(base, frame, rng())
    rows = int(np.count_nonzero(effect.band(frame)))
    assert 0 < rows < N_RANGES // 2
    np.testing.assert_array_equal(out[rows:], base[rows:])
    assert out[0].mean() > 0.5 and (out[:rows] >= base[:rows]).all()


def test_a_ring_down_with_a_rise_is_dark_at_the_first_bin_peaks_past_it_and_is_added_to_its_last_bin() -> None:
    base = np.zeros((N_RANGES, N_BEAMS), np.float32)
    frame = make_frame(base)
    plain = RingDown(amplitude=0.5, decay_m=0.5, beam_ripple=0.0)
    risen = dataclasses.replace(plain, rise_m=0.3)
    r = frame.ranges_m - frame.ranges_m[0]
    np.testing.assert_allclose(plain.band(frame)[:10], 0.5 * np.exp(-r[:10] / 0.5), rtol=1e-5)  # rise 0: as before
    band = risen.band(frame)
    peak = int(np.argmax(band))
    assert band[0] == 0.0 and 0 < peak and band[peak] < 0.5
    assert r[peak] == pytest.approx(0.3 * math.log(1 + 0.5 / 0.3), abs=0.07)  # d/dr of (1 - e^(-r/rise)) e^(-r/decay)
    out = risen.apply(base, frame, rng())
    last = int(np.flatnonzero(band)[-1])
    assert out[last].min() > 0 and not out[last + 1:].any()  # the dark first bin does not shorten the band


def test_interference_adds_range_localised_arcs_across_the_fan() -> None:
    base = np.zeros((N_RANGES, N_BEAMS), np.float32)
    frame = make_frame(base)
    np.testing.assert_array_equal(Interference(rate_per_ping=0.0).apply(base, frame, rng()), base)
    out = Interference(rate_per_ping=2.0, thickness_m=0.1, floor_db=-20.0).apply(base, frame, rng(5))
    hit_rows = np.nonzero(out.any(axis=1))[0]
    assert 0 < hit_rows.size < N_RANGES // 4
    assert (out[hit_rows] > 0).mean() > 0.9  # each arc spans the whole fan (sidelobe floor)


def test_gamma_quantization_maps_to_8_bit_with_saturation() -> None:
    values = np.array([[0.0, 0.25, 1.0, 3.0]], np.float32)
    frame = SonarImage(values, np.array([1.0]), np.radians([-3.0, -1.0, 1.0, 3.0]), intensity_scale=1.0)
    out = GammaQuantization(gain=1.0, gamma=0.5).apply(values, frame, rng())
    assert out.dtype == np.uint8
    assert out.tolist() == [[0, 128, 255, 255]]


def test_apply_effects_orders_records_and_converts() -> None:
    base = np.random.default_rng(0).uniform(0.05, 0.6, (N_RANGES, N_BEAMS)).astype(np.float32)
    frame = make_frame(base, speckle_seed=5)
    chosen = [make_effect(n) for n in ("gamma_quantization", "speckle", "tvg_noise")]
    out = apply_effects(frame, chosen, rng(4))
    again = apply_effects(frame, list(reversed(chosen)), rng(4))
    np.testing.assert_array_equal(out.intensity, again.intensity)  # list order does not matter
    assert out.intensity.dtype == np.uint8 and out.intensity_scale == 255.0
    assert [e["name"] for e in out.meta["effects"]] == ["speckle", "tvg_noise", "gamma_quantization"]
    assert out.same_geometry(frame) and out.meta["speckle_seed"] == 5
    linear = apply_effects(frame, [make_effect("range_blur")], rng())
    assert linear.intensity.dtype == np.float32 and linear.intensity.min() >= 0


def test_instances_take_overrides_and_integer_frames_are_normalised() -> None:
    (speckle,) = resolve_effects([Speckle()], {"speckle": {"shape_nu": 4.0}})
    assert speckle.shape_nu == 4.0 and speckle.grain_beams == Speckle().grain_beams
    with pytest.raises(ConfigError, match="speckle.shape_nu"):
        resolve_effects([Speckle()], {"speckle": {"shape_nu": -1.0}})
    base = np.random.default_rng(0).uniform(0.05, 0.6, (N_RANGES, N_BEAMS)).astype(np.float32)
    as_float = make_frame(base)
    as_uint16 = as_float.replace(intensity=np.rint(base * 65535).astype(np.uint16), intensity_scale=65535.0)
    blur = [make_effect("range_blur")]
    np.testing.assert_allclose(apply_effects(as_uint16, blur, rng()).intensity,
                               apply_effects(as_float, blur, rng()).intensity, atol=1e-4)
