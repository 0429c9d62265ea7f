"""Echo detection and range noise against closed forms (issue 7, part A).

A Gaussian pulse of FWHM duration τ is a Gaussian in range of FWHM c·τ/2; sampled on bins,
ln W is a parabola for one target, so its vertex (the echo's range) and half-height points
(the echo's width, τ in time) are recovered exactly.  Echo energies are sums of the
sub-ray energies E_j, so they are exact too.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from simlidar_mi.geometry import CLASS_CODES
from simlidar_mi.lidar.noise import apply_range_noise, noise_sigma_m, normal_stream
from simlidar_mi.lidar.waveform import (C_M_S, Echoes, detect_echoes, echo_statistics,
                                        first_return_arrays, range_fwhm_m)

WOOD, LEAF, GROUND = CLASS_CODES["wood"], CLASS_CODES["leaf"], CLASS_CODES["ground"]


def _detect(r, e, *, cls=None, beam_index=None, tau=3.0, threshold=0.02, max_returns=5, **kw):
    """detect_echoes on (B, S) ranges/energies, element id = flat sub-ray index."""
    r = np.atleast_2d(np.asarray(r, float))
    e = np.atleast_2d(np.asarray(e, float))
    cls = np.full(r.shape, WOOD, np.uint8) if cls is None else np.atleast_2d(np.asarray(cls, np.uint8))
    elem = np.arange(r.size, dtype=np.uint32).reshape(r.shape)
    tree = (np.arange(r.size, dtype=np.uint32).reshape(r.shape) // r.shape[1]) + 100
    cos = np.full(r.shape, 0.5)
    beam = np.arange(r.shape[0]) if beam_index is None else beam_index
    return detect_echoes(r, e, cls, elem, tree, cos, beam, pulse_length_ns=tau,
                         detection_threshold=threshold, max_returns=max_returns, **kw)


def test_range_fwhm_is_c_tau_over_two():
    assert range_fwhm_m(3.0) == pytest.approx(299_792_458.0 * 3e-9 / 2, rel=1e-15)
    assert range_fwhm_m(3.0) == pytest.approx(0.449688687, rel=1e-9)


@pytest.mark.parametrize("tau_ns", [1.0, 3.0, 4.5])
@pytest.mark.parametrize("range_m", [0.731, 12.3456789, 287.0001])
def test_one_flat_target_gives_one_exact_echo(tau_ns, range_m):
    e = np.array([0.01, 0.05, 0.2, 0.03, 0.11, 0.07, 0.02])
    ech = _detect(np.full(7, range_m), e, tau=tau_ns)
    assert len(ech) == 1
    assert ech.range_m[0] == pytest.approx(range_m, abs=1e-9)          # log-parabola vertex: exact
    assert ech.energy[0] == pytest.approx(e.sum(), rel=1e-7)           # Σ E_j (float32)
    assert ech.width_ns[0] == pytest.approx(tau_ns, rel=1e-6)          # FWHM c·τ/2 in range = τ
    assert (ech.return_number[0], ech.number_of_returns[0], ech.beam[0]) == (1, 1, 0)
    assert ech.element_id[0] == 2 and ech.cls[0] == WOOD               # the strongest sub-ray
    assert ech.tree_id[0] == 100 and ech.cos_incidence[0] == np.float32(0.5)


def test_two_separated_targets_give_two_echoes_with_their_energies():
    fwhm = range_fwhm_m(3.0)
    r1, r2, e1, e2 = 10.0, 10.0 + 4 * fwhm, 0.3, 0.12
    ech = _detect([r1, r1, r2], [e1 / 2, e1 / 2, e2])
    np.testing.assert_allclose(ech.range_m, [r1, r2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(ech.energy, [e1, e2], rtol=1e-7)
    np.testing.assert_array_equal(ech.return_number, [1, 2])
    np.testing.assert_array_equal(ech.number_of_returns, [2, 2])
    np.testing.assert_array_equal(ech.element_id, [0, 2])
    np.testing.assert_allclose(ech.width_ns, [3.0, 3.0], rtol=1e-6)


@pytest.mark.parametrize("sep_fwhm", [0.3, 0.6, 0.95])
def test_targets_closer_than_c_tau_over_two_merge(sep_fwhm):
    # 0.3 and 0.6 FWHM: one peak (two Gaussians are bimodal only beyond 2σ = 0.85 FWHM);
    # 0.95 FWHM: two peaks that the receiver merges
    fwhm = range_fwhm_m(3.0)
    r1, e1, e2 = 20.0, 0.5, 0.3
    r2 = r1 + sep_fwhm * fwhm
    ech = _detect([r1, r2], [e1, e2])
    assert len(ech) == 1
    assert ech.energy[0] == pytest.approx(e1 + e2, rel=1e-7)
    assert r1 <= ech.range_m[0] <= (r1 + r2) / 2  # the stronger target pulls the peak
    assert ech.element_id[0] == 0 and ech.number_of_returns[0] == 1
    assert ech.width_ns[0] > 3.0  # two pulses side by side are wider than one


def test_chained_peaks_merge_by_single_linkage_only_under_the_basin_rule():
    # three equal targets 0.9 FWHM apart (three peaks): each neighbour pair is closer than c·τ/2
    fwhm = range_fwhm_m(3.0)
    r = 30.0 + np.arange(3) * 0.9 * fwhm
    ech = _detect(r, [0.1, 0.1, 0.1], echo_rule="basin")
    assert len(ech) == 1 and ech.energy[0] == pytest.approx(0.3, rel=1e-7)
    # a receiver's dead time runs from the trigger: the third peak (1.8 FWHM on) is a new echo
    ech = _detect(r, [0.1, 0.1, 0.1])
    assert len(ech) == 2
    np.testing.assert_allclose(ech.energy, [0.2, 0.1], rtol=1e-7)
    assert r[0] <= ech.range_m[0] < (r[0] + r[1]) / 2 and ech.element_id[0] in (0, 1)


def test_merging_never_moves_a_return_past_the_first_surface():
    """Surfaces at 10.00, 10.42 and 10.84 m (3 ns pulse: c·τ/2 = 0.45 m), energies 0.1, 0.08,
    0.1: W has three peaks. Single linkage chains them into one echo at the highest peak
    (10.79 m), losing the first surface; the amplitude rule triggers on the first peak (pulled
    0.05 m deeper by its neighbour's tail), absorbs the second within the dead time and
    reports the third as its own echo."""
    r, e = [10.0, 10.42, 10.84], [0.1, 0.08, 0.1]
    old = _detect(r, e, echo_rule="basin")
    assert len(old) == 1 and old.range_m[0] > 10.75
    ech = _detect(r, e)
    assert len(ech) == 2
    assert 10.0 <= ech.range_m[0] < 10.06 and ech.element_id[0] == 0
    assert 10.75 < ech.range_m[1] < 10.84 and ech.element_id[1] == 2
    np.testing.assert_allclose(ech.energy, [0.18, 0.10], rtol=1e-6)
    np.testing.assert_array_equal(ech.number_of_returns, [2, 2])


@pytest.mark.parametrize("margin, found", [(1.001, True), (0.999, False)])
def test_amplitude_threshold_closed_form(margin, found):
    """Two sub-rays of E/2 each, 6 bins (0.75 FWHM < 2σ) apart: W has one peak, at their
    midpoint (a bin centre), of height A = E·exp(−d²/(8σ²)) = 0.677·E. An echo is reported iff
    A ≥ threshold; the basin rule (integrated energy E ≥ threshold) reports it either way."""
    fwhm = range_fwhm_m(3.0)
    sigma = fwhm / (2 * math.sqrt(2 * math.log(2)))
    d = 0.75 * fwhm
    t = 0.02
    amp_per_e = math.exp(-d * d / (8 * sigma * sigma))
    e = margin * t / amp_per_e
    assert e > t
    r = [12.0, 12.0 + d]
    ech = _detect(r, [e / 2, e / 2], threshold=t)
    assert len(ech) == int(found)
    if found:
        assert ech.range_m[0] == pytest.approx(12.0 + d / 2, abs=1e-9)
        assert ech.energy[0] == pytest.approx(e, rel=1e-7)
    assert len(_detect(r, [e / 2, e / 2], threshold=t, echo_rule="basin")) == 1
    # one target at one range: amplitude = energy, so both rules agree at the threshold
    assert len(_detect([7.0], [t * margin], threshold=t)) == int(found)


def test_unknown_echo_rule_is_refused():
    with pytest.raises(ValueError, match="echo_rule"):
        _detect([5.0], [0.5], echo_rule="loudest")


def test_threshold_drops_the_weak_echo_and_keeps_one_at_the_threshold():
    fwhm = range_fwhm_m(3.0)
    ech = _detect([5.0, 5.0 + 5 * fwhm, 5.0 + 10 * fwhm], [0.5, 0.0199, 0.02], threshold=0.02)
    np.testing.assert_allclose(ech.range_m, [5.0, 5.0 + 10 * fwhm], atol=1e-9)
    np.testing.assert_array_equal(ech.number_of_returns, [2, 2])


def test_max_returns_keeps_the_nearest():
    fwhm = range_fwhm_m(3.0)
    r = 8.0 + np.arange(4) * 4 * fwhm
    ech = _detect(r, [0.05, 0.1, 0.2, 0.9], max_returns=2)
    np.testing.assert_allclose(ech.range_m, r[:2], atol=1e-9)
    np.testing.assert_array_equal(ech.return_number, [1, 2])
    np.testing.assert_array_equal(ech.number_of_returns, [2, 2])


def test_range_window_drops_echoes_outside_it():
    ech = _detect([0.5, 5.0, 50.0], [0.5, 0.5, 0.5], range_min_m=1.0, range_max_m=40.0)
    np.testing.assert_allclose(ech.range_m, [5.0], atol=1e-9)
    assert (ech.return_number[0], ech.number_of_returns[0]) == (1, 1)


def test_escapes_and_zero_energy_give_nothing():
    r = np.array([[np.inf, np.inf], [7.0, np.inf], [3.0, 4.0]])
    e = np.array([[0.0, 0.0], [0.0, 0.0], [0.0, 0.0]])
    assert len(_detect(r, e)) == 0
    assert _detect(r, e).tree_id is not None  # the empty result keeps the tree column


def test_class_and_ids_come_from_the_strongest_sub_ray():
    ech = _detect([[6.0, 6.0, 6.0]], [[0.1, 0.3, 0.2]], cls=[[LEAF, WOOD, LEAF]])
    assert ech.cls[0] == WOOD and ech.element_id[0] == 1


def test_output_sorted_by_beam_and_independent_of_chunking():
    rng = np.random.default_rng(3)
    b, s = 400, 9
    r = rng.uniform(2.0, 30.0, (b, s))
    r[rng.random((b, s)) < 0.3] = np.inf
    e = np.where(np.isfinite(r), rng.uniform(0.0, 0.2, (b, s)), 0.0)
    beams = rng.permutation(10 * b)[:b]  # any order, any gaps
    whole = _detect(r, e, beam_index=beams)
    assert np.all(np.diff(whole.beam) >= 0)
    same = np.diff(whole.beam) == 0
    assert np.all(np.diff(whole.return_number.astype(int))[same] == 1)
    assert np.all(np.diff(whole.range_m)[same] > 0)
    parts = [_detect(r[a:z], e[a:z], beam_index=beams[a:z]) for a, z in ((0, 77), (77, 300), (300, b))]
    # element ids are flat sub-ray indices of each call: compare the rest
    joined = Echoes.concat(parts)
    for name in ("beam", "return_number", "number_of_returns", "range_m", "energy", "width_ns", "cls"):
        np.testing.assert_array_equal(getattr(joined, name), getattr(whole, name), err_msg=name)
    # with nothing dropped, a beam's echoes carry all the energy its sub-rays brought back
    every = _detect(r, e, beam_index=beams, threshold=1e-300, max_returns=255)
    total = np.bincount(every.beam, weights=every.energy.astype(float), minlength=10 * b)[beams]
    np.testing.assert_allclose(total, e.sum(axis=1), rtol=1e-6)


def test_first_return_arrays_and_layers():
    fwhm = range_fwhm_m(3.0)
    # beams 0 and 5 of a 2×3 pattern: two echoes and one; the rest escape
    r = np.array([[4.0, 4.0 + 5 * fwhm], [9.0, np.inf]])
    e = np.array([[0.4, 0.25], [0.6, 0.0]])
    ech = _detect(r, e, beam_index=np.array([0, 5]))
    out = first_return_arrays(ech, (2, 3), escape_m=1000.0)
    exp_range = np.full((2, 3), 1000.0, np.float32)
    exp_range[0, 0], exp_range[1, 2] = 4.0, 9.0
    np.testing.assert_allclose(out["range_m"], exp_range, atol=1e-5)
    np.testing.assert_array_equal(out["n_returns"], [[2, 0, 0], [0, 0, 1]])
    np.testing.assert_array_equal(out["cls"], [[WOOD, 0, 0], [0, 0, WOOD]])
    np.testing.assert_array_equal(out["element_id"], [[0, 0xFFFFFFFF, 0xFFFFFFFF], [0xFFFFFFFF, 0xFFFFFFFF, 2]])
    np.testing.assert_allclose(out["intensity"], [[0.4, 0, 0], [0, 0, 0.6]], rtol=1e-7)
    second = ech.layer((2, 3), 2, escape_m=1000.0)
    assert second["range_m"][0, 0] == pytest.approx(4.0 + 5 * fwhm, abs=1e-5)
    assert np.count_nonzero(second["cls"]) == 1


def test_echo_statistics_counts_beams_and_classes():
    class Res:  # what echo_statistics reads: echoes and shape
        def __init__(self, echoes, shape):
            self.echoes, self.shape = echoes, shape
    fwhm = range_fwhm_m(3.0)
    r = np.array([[4.0, 4.0 + 5 * fwhm], [9.0, np.inf]])
    ech = _detect(r, [[0.4, 0.25], [0.6, 0.0]], cls=[[LEAF, WOOD], [GROUND, 0]], beam_index=np.array([0, 5]))
    stats = echo_statistics([Res(ech, (2, 3)), Res(ech, (2, 3))])
    assert stats["beams"] == 12 and stats["echoes"] == 6
    assert stats["beams_by_n_returns"] == {"0": 8, "1": 2, "2": 2}
    assert stats["share_by_n_returns"]["2"] == pytest.approx(2 / 12)
    assert stats["echoes_by_class_and_return"] == {"ground": {"1": 2}, "wood": {"2": 2}, "leaf": {"1": 2}}
    assert echo_statistics(Res(None, (2, 3))) is None


# ---- noise -------------------------------------------------------------------------------

def _echoes_at(range_m, cos, n):
    return Echoes(np.arange(n, dtype=np.int64), np.ones(n, np.uint8), np.ones(n, np.uint8),
                  np.full(n, range_m), np.ones(n, np.float32), np.full(n, 3.0, np.float32),
                  np.full(n, WOOD, np.uint8), np.zeros(n, np.uint32), None, np.full(n, cos, np.float32))


def test_noise_has_the_stated_mean_and_sd():
    sigma, n = 0.02, 1_000_000
    ech = _echoes_at(1.0, 1.0, n)
    err = apply_range_noise(ech, seed=20131105, range_noise_m=sigma).range_m - 1.0
    assert abs(err.mean()) < sigma / 100
    assert abs(err.std() / sigma - 1) < 0.02
    z = normal_stream(20131105, 0, np.arange(n), 1)
    # a normal, not just the right moments: the share within ±1σ is erf(1/√2) = 0.6827
    assert abs(np.mean(np.abs(z) < 1) - math.erf(1 / math.sqrt(2))) < 0.003


def test_noise_sigma_law():
    r = np.array([0.5, 1.0, 11.0, 11.0, 11.0])
    cos = np.array([1.0, -1.0, 1.0, 0.5, 0.01])
    expected = (0.01 + 0.002 * np.array([0.0, 0.0, 10.0, 10.0, 10.0])) / np.array([1, 1, 1, 0.5, 0.1])
    np.testing.assert_allclose(noise_sigma_m(r, cos, 0.01, 0.002), expected, rtol=1e-15)
    ech = Echoes(np.arange(5, dtype=np.int64) * 7, np.array([1, 2, 1, 3, 1], np.uint8), np.full(5, 3, np.uint8),
                 r, np.ones(5, np.float32), np.ones(5, np.float32), np.full(5, WOOD, np.uint8),
                 np.zeros(5, np.uint32), None, cos.astype(np.float32))
    noisy = apply_range_noise(ech, seed=5, leg=2, range_noise_m=0.01, range_noise_per_m=0.002)
    z = normal_stream(5, 2, ech.beam, ech.return_number)
    np.testing.assert_allclose(noisy.range_m, r + expected * z, rtol=0, atol=1e-7)  # cos as float32
    assert apply_range_noise(ech, seed=5) is ech  # no noise asked: untouched


def test_noise_same_bytes_whatever_the_chunking_and_order():
    n = 20_000
    ech = _echoes_at(12.0, 0.8, n)
    ech.return_number[1::3] = 2
    whole = apply_range_noise(ech, seed=7, leg=1, range_noise_m=0.01).range_m
    chunks = [apply_range_noise(ech.take(slice(a, a + 3001)), seed=7, leg=1, range_noise_m=0.01)
              for a in range(0, n, 3001)]
    assert Echoes.concat(chunks).range_m.tobytes() == whole.tobytes()
    perm = np.random.default_rng(0).permutation(n)
    shuffled = apply_range_noise(ech.take(perm), seed=7, leg=1, range_noise_m=0.01).range_m
    assert shuffled.tobytes() == whole[perm].tobytes()
    for other in ({"seed": 8, "leg": 1}, {"seed": 7, "leg": 0}):
        diff = apply_range_noise(ech, range_noise_m=0.01, **other).range_m
        assert np.mean(diff != whole) > 0.999


def test_noise_keys_are_independent():
    # neighbouring beams and return numbers do not correlate (a hash, not a sequence)
    z1 = normal_stream(1, 0, np.arange(200_000), 1)
    z2 = normal_stream(1, 0, np.arange(200_000), 2)
    assert abs(np.corrcoef(z1, z2)[0, 1]) < 0.01
    assert abs(np.corrcoef(z1[:-1], z1[1:])[0, 1]) < 0.01


def test_width_in_ns_converts_range_fwhm():
    # a flat target at grazing spread: width grows; a point target: exactly τ
    ech = _detect([15.0], [0.3], tau=2.0)
    assert ech.width_ns[0] == pytest.approx(2.0, rel=1e-6)
    assert ech.width_ns[0] * 1e-9 * C_M_S / 2 == pytest.approx(range_fwhm_m(2.0), rel=1e-6)
