"""A real scanner on plates and thin cylinders, against closed forms.

Scenes are [[primitive]] boxes (plates facing the scanner) seen from a static scanner at
the origin looking along +x.  Closed forms: a Gaussian beam of 1/e² half-angle w = γ/2 has
the share ½(1 + erf(√2·x/w)) of its energy beyond a straight edge at angular offset x; the
Lambertian energy law is E = w_j·ρ·|cos i|·(R_ref/r)² (simlidar_mi.lidar.sensor).  Sub-ray
shares are compared with the erf within the Vogel layout's own discrepancy D_S (the largest
error of the layout's share over every straight edge, computed from the layout, not from a
scan), and with the layout's exact share to one sub-ray (float32 rays on an edge).
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.config import load_scene
from simlidar_mi.lidar.scan import scan, scan_physical
from simlidar_mi.lidar.sensor import SensorModel, gaussian_share, resolve_sensor, subray_offsets
from simlidar_mi.lidar.survey import build, generate, scan_patterns

C_M_S = 299_792_458.0


def plate(x_m, y0_m=-5.0, y1_m=5.0, *, z0_m=-5.0, z1_m=5.0, depth_m=0.05, extra=""):
    return (f'[[primitive]]\ntype = "box"\nmin_m = [{x_m}, {y0_m}, {z0_m}]\n'
            f'max_m = [{x_m + depth_m}, {y1_m}, {z1_m}]\n{extra}')


def static(azimuth="0.0", elevation="[0.0, 0.5, 1.0]"):
    return (f'[ground]\nenabled = false\n[platform]\nkind = "static"\nposition_m = [0.0, 0.0, 0.0]\n'
            f'elevation_deg = {elevation}\nazimuth_deg = {azimuth}\n')


def run(text, *, sensor=True, seed=0, **kw):
    cfg = load_scene(text=text)
    g = generate(cfg)
    lo, hi = g.bounds_m()
    pats = scan_patterns(cfg, lo, hi, g.near_x_m)
    built = build(cfg, g, pats)
    model = resolve_sensor(cfg) if sensor else None
    if kw:
        return scan_physical(built, pats[0], model, seed=seed, **kw), model
    return scan(built, pats[0], sensor=model, seed=seed), model


def layout_discrepancy(model: SensorModel, n_angles: int = 180) -> float:
    """sup over edge directions and offsets of |layout share − Gaussian share| (D_S)."""
    off, w = subray_offsets(model)
    half = 0.5 * model.divergence_mrad * 1e-3
    worst = 0.0
    for phi in np.linspace(0, np.pi, n_angles, endpoint=False):
        proj = np.sort(off @ np.array([np.cos(phi), np.sin(phi)]))
        cdf_after = np.arange(1, len(proj) + 1) / len(proj)
        exact = 0.5 * (1 + np.vectorize(math.erf)(math.sqrt(2) * proj / half))
        worst = max(worst, np.max(np.abs(cdf_after - exact)), np.max(np.abs(cdf_after - 1 / len(proj) - exact)))
    return float(worst)


# --- divergence alone: geometric hit shares ---------------------------------------------------

def test_plate_edge_swept_across_the_beam_follows_erf():
    gamma_mrad, S, R = 10.0, 256, 10.0
    step_deg = 0.02
    az = np.arange(-0.46, 0.46 + 1e-9, step_deg)
    text = (static(f"[{az[0]}, {az[-1] + step_deg / 2}, {step_deg}]") + plate(R, 0.0, 5.0)
            + f"[sensor]\ndivergence_mrad = {gamma_mrad}\nbeam_samples = {S}\n")
    res, model = run(text)
    share = res.hit_fraction[:, 0].astype(np.float64)
    alpha = np.deg2rad(res.pattern.row_yaw_deg)
    off, w = subray_offsets(model)
    # The sub-ray's azimuth is α + a_u: it meets the plate (y ≥ 0) when a_u > −α.
    layout = np.array([w[off[:, 0] > -a].sum() for a in alpha])
    assert np.max(np.abs(share - layout)) <= 1.0 / S + 1e-6
    closed = np.array([gaussian_share(a, gamma_mrad) for a in alpha])
    d_s = layout_discrepancy(model)
    assert d_s < 2.0 / math.sqrt(S)  # the layout itself: O(1/√S)
    assert np.max(np.abs(share - closed)) <= d_s + 1.0 / S
    # A sub-ray hitting the plate reports the plate's range along the sub-ray (≥ R).
    hit = res.cls[:, 0] == 2
    assert hit.any() and np.all(res.range_m[hit, 0] >= R - 1e-4)
    assert np.all(res.range_m[hit, 0] < R / math.cos(gamma_mrad * 1e-3) + 1e-4)
    assert np.array_equal(res.n_returns[:, 0], hit.astype(np.uint8))


@pytest.mark.parametrize("profile", ["gaussian", "uniform"])
def test_edge_through_the_axis_takes_half_the_beam(profile):
    S = 128
    res, model = run(static() + plate(10.0, 0.0, 5.0) + f'[sensor]\ndivergence_mrad = 8.0\nbeam_samples = {S}\n'
                     f'beam_profile = "{profile}"\n')
    assert res.hit_fraction[0, 0] == pytest.approx(0.5, abs=layout_discrepancy(model) + 1 / S)


def test_chunk_size_does_not_change_results():
    az = "[-0.3, 0.3, 0.05]"
    text = static(az, "[-0.3, 0.3, 0.05]") + plate(10.0, 0.0, 5.0) + plate(12.0, -5.0, 5.0)
    text += "[sensor]\ndivergence_mrad = 10.0\nbeam_samples = 16\n"
    whole, _ = run(text, chunk_rays=1 << 20)
    for chunk in (16, 16 * 7, 16 * 50 + 3):
        part, _ = run(text, chunk_rays=chunk)
        for name in ("range_m", "cls", "element_id", "hit_fraction", "n_returns"):
            assert getattr(part, name).tobytes() == getattr(whole, name).tobytes(), (chunk, name)


def test_range_limits_drop_returns_outside():
    text = static("[-0.3, 0.3, 0.1]") + plate(10.0, 0.0, 5.0) + plate(12.0, -5.0, 5.0)
    near, _ = run(text + "[sensor]\nrange_max_m = 11.0\n")
    assert np.all(near.cls[near.pattern.row_yaw_deg > 0.05] == 2)
    assert np.all(near.cls[near.pattern.row_yaw_deg < -0.05] == 0)      # 12 m plate beyond the limit
    assert np.all(near.n_returns[near.pattern.row_yaw_deg < -0.05] == 0)
    far, _ = run(text + "[sensor]\nrange_min_m = 11.0\n")
    # The near plate still blocks the beam: nothing behind it, no return.
    assert np.all(far.cls[far.pattern.row_yaw_deg > 0.05] == 0)
    assert np.all(far.range_m[far.pattern.row_yaw_deg < -0.05] == pytest.approx(12.0, abs=1e-3))


def test_divergence_on_a_thin_cylinder_matches_the_float64_reference():
    """Hit share of a 2 cm stem 10 m away against float64 sub-rays cast on the exact cylinder
    (reference.ray_cylinder_pairs), and against the strip's erf closed form."""
    from simlidar_mi.lidar.reference import ray_cylinder_pairs
    gamma_mrad, S, R, d_m = 6.0, 256, 10.0, 0.02
    step_deg = 0.01
    az = np.arange(-0.3, 0.3 + 1e-9, step_deg)
    cyl = (f'[[primitive]]\ntype = "cylinder"\np0_m = [{R}, 0.0, -2.0]\np1_m = [{R}, 0.0, 2.0]\n'
           f"diameter_m = {d_m}\n")
    text = static(f"[{az[0]}, {az[-1] + step_deg / 2}, {step_deg}]") + cyl
    res, model = run(text + f"[sensor]\ndivergence_mrad = {gamma_mrad}\nbeam_samples = {S}\n")
    thin, _ = run(text, sensor=False)
    off, w = subray_offsets(model)
    alpha = np.deg2rad(res.pattern.row_yaw_deg)
    ref = np.empty(len(alpha))
    for row, a in enumerate(alpha):
        d = np.array([math.cos(a), math.sin(a), 0.0])
        u = np.cross([0.0, 0.0, 1.0], d)
        u /= np.linalg.norm(u)
        v = np.cross(d, u)
        dirs = d + np.tan(off[:, :1]) * u + np.tan(off[:, 1:]) * v
        dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
        n = len(dirs)
        t = ray_cylinder_pairs(np.zeros((n, 3)), dirs, np.tile([R, 0.0, -2.0], (n, 1)),
                               np.tile([R, 0.0, 2.0], (n, 1)), np.full(n, d_m / 2))
        ref[row] = w[np.isfinite(t)].sum()
    share = res.hit_fraction[:, 0].astype(np.float64)
    # Two silhouette edges, each may flip one float32 sub-ray; the 64-facet mesh's width
    # differs from the cylinder's by < 0.2 %: well under one sub-ray spacing at 10 m.
    assert np.max(np.abs(share - ref)) <= 2.0 / S + 1e-6
    # The reference against the strip's closed form, within two edges' layout discrepancy.
    h = math.atan(d_m / 2 / R)
    closed = np.array([gaussian_share(a + h, gamma_mrad) - gaussian_share(a - h, gamma_mrad) for a in alpha])
    assert np.max(np.abs(ref - closed)) <= 2 * layout_discrepancy(model)
    # What divergence buys: one thin ray says all or nothing.
    thin_share = thin.hit_fraction[:, 0].astype(np.float64)
    assert set(np.unique(thin_share)) <= {0.0, 1.0}
    assert np.mean(np.abs(share - ref)) < 0.1 * np.mean(np.abs(thin_share - ref))


def test_without_sensor_effects_outputs_are_the_first_return_scans(tmp_path, scenes_dir):
    """No [sensor], or a [sensor] whose effects are all off (with [materials]), writes the same
    EXR channels and LAS points as the first-return scan (checked against main's files when
    this was written: scan.exr and points.las byte-identical)."""
    import laspy
    from simlidar_mi.io.exr import read_exr
    from simlidar_mi.lidar.survey import run_scan
    scene = scenes_dir / "calibration_cylinder.toml"
    base = run_scan(scene, tmp_path / "base", ["scan.dy_m=0.01"])
    off = run_scan(scene, tmp_path / "off", ["scan.dy_m=0.01", "sensor.max_returns=1",
                                             'sensor.beam_profile="uniform"', "materials.wood=0.9"])
    assert off.result.sensor is None and "sensor" not in off.measures
    a, _ = read_exr(base.files["exr"])
    b, _ = read_exr(off.files["exr"])
    assert sorted(a) == sorted(b)
    for name in a:
        assert a[name].tobytes() == b[name].tobytes(), name
    assert (laspy.read(base.files["las"]).points.array.tobytes()
            == laspy.read(off.files["las"]).points.array.tobytes())


# --- echoes and intensity (the waveform of simlidar_mi.lidar.waveform) ------------------------

ECHO = "[sensor]\nmax_returns = 4\nintensity = true\n"


def beam_echoes(res, beam=0):
    e = res.echoes
    sel = e.beam == beam
    return e.range_m[sel], e.energy[sel].astype(np.float64), e.number_of_returns[sel]


def test_two_plates_two_echoes_in_the_profile_and_inverse_square_ratio():
    gamma_mrad, S, R1, R2, rho = 8.0, 256, 10.0, 14.0, 0.35
    res, model = run(static() + plate(R1, 0.0, 5.0) + plate(R2) + ECHO
                     + f"divergence_mrad = {gamma_mrad}\nbeam_samples = {S}\n")
    rng, energy, n = beam_echoes(res)
    assert len(rng) == 2 and list(n) == [2, 2] and res.n_returns[0, 0] == 2
    # Sub-rays reach a plate at R/cos a, a ≤ ~γ: well under a millimetre beyond R.
    assert rng == pytest.approx([R1, R2], abs=2e-3)
    off, w = subray_offsets(model)
    f = w[off[:, 0] > 0].sum()               # the layout's share on the near plate
    assert f == pytest.approx(0.5, abs=layout_discrepancy(model))  # the profile integral: ½
    unit = rho * model.r_ref_m ** 2
    assert energy[0] == pytest.approx(f * unit / R1 ** 2, rel=1e-4)
    assert energy[1] == pytest.approx((1 - f) * unit / R2 ** 2, rel=1e-4)
    assert energy[0] / energy[1] == pytest.approx(f / (1 - f) * (R2 / R1) ** 2, rel=1e-4)
    # First-return arrays hold echo 1; intensity is its energy.
    assert res.range_m[0, 0] == pytest.approx(R1, abs=2e-3) and res.cls[0, 0] == 2
    assert res.intensity[0, 0] == pytest.approx(energy[0], rel=1e-6)


@pytest.mark.parametrize("gap_m, n_echoes", [(0.2, 1), (0.6, 2)])
def test_plates_closer_than_half_the_pulse_merge(gap_m, n_echoes):
    tau_ns = 3.0
    merge_m = C_M_S * tau_ns * 1e-9 / 2     # 0.4497 m
    assert (gap_m < merge_m) == (n_echoes == 1)
    R1, R2 = 10.0, 10.0 + gap_m
    res, model = run(static() + plate(R1, 0.0, 5.0) + plate(R2) + ECHO
                     + f"pulse_length_ns = {tau_ns}\ndivergence_mrad = 8.0\nbeam_samples = 128\n")
    rng, energy, _ = beam_echoes(res)
    assert len(rng) == n_echoes
    off, w = subray_offsets(model)
    f = w[off[:, 0] > 0].sum()
    unit = 0.35 * model.r_ref_m ** 2
    total = f * unit / R1 ** 2 + (1 - f) * unit / R2 ** 2
    assert energy.sum() == pytest.approx(total, rel=1e-4)   # every sub-ray's energy is in an echo
    if n_echoes == 1:
        assert R1 - 1e-3 <= rng[0] <= R2 + 1e-3


def test_intensity_follows_the_cosine_law_with_incidence():
    R, rho = 10.0, 0.5
    res, model = run(static(elevation="[0.0, 60.0, 10.0]") + plate(R, z0_m=-5.0, z1_m=30.0,
                     extra=f"reflectance = {rho}\n") + "[sensor]\nintensity = true\n")
    theta = np.deg2rad(res.pattern.col_angle_deg)
    r = res.range_m[0].astype(np.float64)
    assert r == pytest.approx(R / np.cos(theta), rel=1e-5)
    # E·r²/(ρ·R_ref²) is the cosine of the incidence angle (here θ).
    assert res.intensity[0] * r ** 2 / (rho * model.r_ref_m ** 2) == pytest.approx(np.cos(theta), rel=1e-4)
    assert res.echoes.cos_incidence == pytest.approx(np.cos(theta), rel=1e-5)


def test_intensity_falls_as_inverse_square_of_range():
    energy = []
    for R in (5.0, 10.0, 20.0):
        res, model = run(static() + plate(R) + "[sensor]\nintensity = true\n")
        energy.append(res.intensity[0, 0] * R ** 2)
    assert energy == pytest.approx([0.35 * model.r_ref_m ** 2] * 3, rel=1e-5)


def test_intensity_is_linear_in_reflectance():
    R = 10.0
    rhos = [0.1, 0.3, 0.9]
    text = static("[-10.0, 15.0, 10.0]")  # three beams: at y −1.76, 0 and +1.76 m on the plates
    for j, rho in enumerate(rhos):
        text += plate(R, -3.0 + 2.0 * j, -1.0 + 2.0 * j, extra=f"reflectance = {rho}\n")
    res, model = run(text + "[sensor]\nintensity = true\n")
    cos_yaw = np.cos(np.deg2rad(res.pattern.row_yaw_deg))
    r = res.range_m[:, 0].astype(np.float64)
    per_rho = res.intensity[:, 0] * r ** 2 / (cos_yaw * model.r_ref_m ** 2)
    assert per_rho == pytest.approx(rhos, rel=1e-4)


def test_materials_reflectance_by_label_and_the_energy_constant():
    # A 10 % target at normal incidence filling the beam at range_at_10pct_m returns the threshold.
    text = static() + plate(40.0, extra='label = "leaf"\n') + "[materials]\nleaf = 0.1\n[sensor]\nintensity = true\n"
    res, model = run(text)
    assert res.intensity[0, 0] == pytest.approx(model.detection_threshold, rel=1e-5) and res.cls[0, 0] == 3
    res, _ = run(text.replace("40.0", "40.5"))  # farther: weaker than the threshold, no echo
    assert res.n_returns[0, 0] == 0 and res.cls[0, 0] == 0 and len(res.echoes) == 0


def test_range_noise_statistics_and_chunking():
    """≥ 100 k beams on a plate: noise mean < σ/100, SD within 2 % of σ, with σ from the
    former law (noise_model = "range": (range_noise_m + range_noise_per_m·(r − 1 m))/|cos i|);
    same seed → same bytes whatever the chunk size, another seed → other ranges."""
    sigma0, per_m = 0.02, 0.001
    grid = "[-2.0, 2.0, 0.0125]"   # 320 × 321 beams
    base = static("[-2.0, 2.0, 0.0125]", grid) + plate(10.0)
    exact, _ = run(base + "[sensor]\nintensity = true\n")
    law = f'[sensor]\nnoise_model = "range"\nrange_noise_m = {sigma0}\nrange_noise_per_m = {per_m}\n'
    noisy, _ = run(base + law, seed=7)
    assert noisy.echoes is not None and len(noisy.echoes) == exact.range_m.size >= 100_000
    r0 = exact.echoes.range_m
    sigma = (sigma0 + per_m * (r0 - 1.0)) / np.maximum(exact.echoes.cos_incidence, 0.1)
    z = (noisy.echoes.range_m - r0) / sigma
    assert abs(z.mean()) < 0.01 and z.std() == pytest.approx(1.0, abs=0.02)
    small, _ = run(base + law, seed=7, chunk_rays=997)
    assert small.echoes.range_m.tobytes() == noisy.echoes.range_m.tobytes()
    assert small.range_m.tobytes() == noisy.range_m.tobytes()
    other, _ = run(base + law, seed=8)
    assert np.mean(other.echoes.range_m == noisy.echoes.range_m) < 0.01


@pytest.mark.parametrize("range_m, rho", [(10.0, 0.5), (20.0, 0.15), (25.0, 0.2), (30.0, 0.1)])
def test_range_noise_follows_snr_on_plates(range_m, rho):
    """The default "snr" law on plates at several ranges and reflectances (thin beams at
    < 1.5° from the normal, so one sub-ray per beam and echo width τ): the echo's energy is
    E = ρ·|cos i|·(R_ref/r)² (closed form from the plate's geometry), SNR = threshold_snr·E/t,
    σ = range_noise_m·sqrt(max(noise_ref_snr/SNR, 1)): SNR 800 at 10 m, ρ 0.5 (the floor,
    3 cm), 60 / 51 / 18 beyond (3.9 / 4.2 / 7.1 cm). The measured SD of (noisy − exact)/σ over
    n ≈ 12 k beams has standard error 1/sqrt(2n) = 0.0064: 4 of those is the tolerance; the
    mean is within 4/sqrt(n). The former law (no ρ, 1/cos i: 3 cm on every plate) misses the
    last three by 1.3× to 2.4×, and no floor would put the first at 1.1 cm."""
    grid = "[-1.5, 1.5, 0.0275]"   # 110 × 110 beams
    body = static(grid, grid) + plate(range_m, extra=f"reflectance = {rho}\n")
    exact, model = run(body + "[sensor]\nintensity = true\n")
    noisy, nm = run(body + "[sensor]\nrange_noise_m = 0.03\n", seed=11)
    assert nm.noise_model == "snr" and (nm.noise_ref_snr, nm.threshold_snr) == (100.0, 10.0)
    r0, cos = exact.echoes.range_m, np.abs(exact.echoes.cos_incidence.astype(np.float64))
    assert len(noisy.echoes) == len(r0) >= 12_000 and cos.min() > 0.999
    energy = rho * cos * (model.r_ref_m / r0) ** 2
    snr = 10.0 * energy / model.detection_threshold
    sigma = 0.03 * np.sqrt(np.maximum(100.0 / snr, 1.0))
    z = (noisy.echoes.range_m - r0) / sigma
    n = len(z)
    assert abs(z.mean()) < 4 / np.sqrt(n)
    assert z.std() == pytest.approx(1.0, abs=4 / np.sqrt(2 * n))


def test_run_scan_with_a_sensor_writes_its_echoes_and_measures(tmp_path, scenes_dir):
    import json
    from simlidar_mi.lidar.survey import run_scan
    out = run_scan(scenes_dir / "calibration_cylinder.toml", tmp_path / "s",
                   ["scan.dy_m=0.02", "sensor.divergence_mrad=5.0", "sensor.beam_samples=16",
                    "sensor.max_returns=3", "sensor.intensity=true", "sensor.range_noise_m=0.005"])
    res = out.result
    m = json.loads(out.files["measures"].read_text())
    assert m["sensor"]["beam_samples"] == 16 and m["sub_rays_per_beam"] == 16
    assert m["sensor"]["effects"] == ["divergence", "echoes", "intensity", "noise"]
    by_n = np.bincount(res.n_returns.ravel())
    assert m["echoes"]["beams_by_n_returns"] == {str(i): int(c) for i, c in enumerate(by_n)}
    assert m["echoes"]["echoes"] == len(res.echoes) == int(res.n_returns.sum())
    # A beam grazing the cylinder's edge sees it and the ground behind: two echoes.
    assert by_n[2] > 0 and by_n[1] > by_n[2]
    again = run_scan(scenes_dir / "calibration_cylinder.toml", None,
                     ["scan.dy_m=0.02", "sensor.divergence_mrad=5.0", "sensor.beam_samples=16",
                      "sensor.max_returns=3", "sensor.intensity=true", "sensor.range_noise_m=0.005"])
    assert again.result.echoes.range_m.tobytes() == res.echoes.range_m.tobytes()  # same seed, same bytes


# --- detection: the waveform's threshold (default) against the nearest sub-ray -------------

@pytest.mark.parametrize("k_threshold, kept", [(0.8, False), (1.25, True), (0.01, False)])
def test_detection_waveform_drops_a_partial_hit_below_the_threshold_nearest_keeps_it(k_threshold, kept):
    """A plate covering a share f of a Gaussian beam at r = 10 m, normal incidence, returns
    E = f·ρ·R_ref²/r² (cos i and r_j vary by < 1e-4 across 8 mrad).  With ρ chosen so that
    E = k·threshold, "waveform" (the default, even with max_returns = 1) keeps the return
    iff k ≥ 1; "nearest" always returns the plate."""
    R, S = 10.0, 64
    geo = static() + plate(R, 0.025, 5.0)             # edge 2.5 mrad off the axis: f ≈ 0.1
    sensor = f"[sensor]\ndivergence_mrad = 8.0\nbeam_samples = {S}\n"
    near, model = run(geo + sensor + 'detection = "nearest"\n')
    f = float(near.hit_fraction[0, 0])
    assert f == pytest.approx(gaussian_share(-math.atan(0.025 / R), 8.0), abs=layout_discrepancy(model) + 1 / S)
    assert 0.05 < f < 0.2
    assert not model.needs_energy and near.echoes is None
    rho = k_threshold * model.detection_threshold / (f * (model.r_ref_m / R) ** 2)
    geo = static() + plate(R, 0.025, 5.0, extra=f"reflectance = {rho}\n")
    near, _ = run(geo + sensor + 'detection = "nearest"\n')
    wave, wmodel = run(geo + sensor)                   # the default reading
    assert wmodel.detection == "waveform" and wmodel.needs_energy and wmodel.max_returns == 1
    assert near.cls[0, 0] == 2 and near.range_m[0, 0] == pytest.approx(R, abs=1e-3)
    assert near.n_returns[0, 0] == 1
    assert wave.hit_fraction[0, 0] == near.hit_fraction[0, 0]   # geometry is the same
    if kept:
        assert wave.cls[0, 0] == 2 and wave.n_returns[0, 0] == 1
        assert wave.range_m[0, 0] == pytest.approx(R, abs=1e-3)
        assert float(wave.echoes.energy[0]) == pytest.approx(k_threshold * model.detection_threshold, rel=1e-4)
    else:
        assert wave.cls[0, 0] == 0 and wave.n_returns[0, 0] == 0 and len(wave.echoes) == 0
        assert wave.range_m[0, 0] == near.pattern.escape_m


def test_detection_waveform_on_a_full_plate_matches_nearest():
    """A plate filling the beam far above the threshold: both readings return it, at the same
    range to well under the bin (FWHM/8 = 5.6 cm at 3 ns)."""
    text = static("[-0.2, 0.2, 0.1]") + plate(10.0) + "[sensor]\ndivergence_mrad = 8.0\nbeam_samples = 16\n"
    near, _ = run(text + 'detection = "nearest"\n')
    wave, _ = run(text)
    assert np.all(near.cls == 2) and np.all(wave.cls == 2)
    assert np.all(wave.n_returns == 1)
    # nearest: the nearest sub-ray (≈ 10 m); waveform: the echo's peak, the energy-weighted
    # middle of r_j = 10/cos a_j, a_j ≤ ~5 mrad: both within 0.2 mm of 10 m
    assert np.allclose(near.range_m, 10.0, atol=2e-4) and np.allclose(wave.range_m, 10.0, atol=2e-4)
