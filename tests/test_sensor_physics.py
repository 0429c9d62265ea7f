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
