"""Wood measures V_L, A_L, A_PR, A_PR_exact against closed forms."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simlidar_mi.errors import ConfigError
from simlidar_mi.geometry import Branches
from simlidar_mi.plants.measures import wood_measures
from simlidar_mi.plants.apple import AppleTreeParams, apple_tree


def cylinders(p0, p1, d, tree_id=None) -> Branches:
    p0 = np.atleast_2d(np.asarray(p0, float))
    p1 = np.atleast_2d(np.asarray(p1, float))
    n = len(p0)
    tid = np.zeros(n, np.int32) if tree_id is None else np.asarray(tree_id, np.int32)
    return Branches(p0, p1, np.broadcast_to(np.asarray(d, float), (n,)).copy(),
                    np.ones(n, np.int32), tid)


def test_single_vertical_cylinder():
    d, h = 0.05, 1.0
    m = wood_measures(cylinders([0, 0, 0], [0, 0, h], d)).total
    assert m.n_branches == 1
    assert m.a_pr_m2 == pytest.approx(d * h, rel=1e-15)
    assert m.a_pr_exact_m2 == pytest.approx(d * h, rel=1e-15)
    assert m.a_l_m2 == pytest.approx(math.pi * d * h, rel=1e-15)
    assert m.v_l_m3 == pytest.approx(math.pi * d * d * h / 4, rel=1e-15)


def test_cylinder_along_the_view_is_a_disc():
    d, h = 0.05, 0.7
    m = wood_measures(cylinders([0, 0, 0], [h, 0, 0], d)).total
    assert m.a_pr_exact_m2 == pytest.approx(math.pi * d * d / 4, rel=1e-15)
    assert m.a_pr_m2 == pytest.approx(d * h)      # eq. 3 as the paper sums it


@pytest.mark.parametrize("direction", [(1, 0, 1), (-1, 0, 1), (1, 1, 0), (0, 1, -1)])
def test_cylinder_at_45_degrees(direction):
    d, h = 0.03, 0.8
    a = np.asarray(direction, float) / np.linalg.norm(direction)
    cos = abs(a[0])                                  # view (1, 0, 0)
    m = wood_measures(cylinders([1, 2, 3], np.array([1, 2, 3]) + h * a, d)).total
    expect = d * h * math.sqrt(1 - cos ** 2) + math.pi * d * d / 4 * cos
    assert m.a_pr_exact_m2 == pytest.approx(expect, rel=1e-14)
    if cos:
        assert m.a_pr_exact_m2 == pytest.approx((d * h + math.pi * d * d / 4) / math.sqrt(2))


def test_view_direction_is_normalised_and_changes_the_exact_area_only():
    b = cylinders([0, 0, 0], [0, 0, 1.0], 0.05)
    a = wood_measures(b, view_dir=(0, 0, -3))       # looking down the cylinder
    assert a.view_dir == (0.0, 0.0, -1.0)
    assert a.total.a_pr_exact_m2 == pytest.approx(math.pi * 0.05 ** 2 / 4)
    assert a.total.a_pr_m2 == wood_measures(b).total.a_pr_m2
    for bad in [(0, 0, 0), (1, math.nan, 0), (1, 0)]:
        with pytest.raises(ConfigError, match="view_dir"):
            wood_measures(b, view_dir=bad)


def test_per_tree_totals_and_dict():
    b = cylinders([[0, 0, 0], [0, 0, 0], [5, 0, 0]], [[0, 0, 1], [0, 0, 2], [5, 0, 1]],
                  [0.1, 0.2, 0.3], tree_id=[0, 0, 3])
    r = wood_measures(b)
    assert sorted(r.per_tree) == [0, 3]
    assert r.per_tree[0].n_branches == 2 and r.per_tree[3].n_branches == 1
    assert r.per_tree[0].a_pr_m2 == pytest.approx(0.1 + 0.4)
    assert r.per_tree[3].a_pr_m2 == pytest.approx(0.3)
    for f in ("v_l_m3", "a_l_m2", "a_pr_m2", "a_pr_exact_m2"):
        assert getattr(r.total, f) == pytest.approx(sum(getattr(t, f)
                                                        for t in r.per_tree.values()))
    d = r.to_dict()
    json.dumps(d)
    assert d["n_branches"] == 3 and d["A_PR_m2"] == pytest.approx(0.8)
    assert set(d) == {"n_branches", "V_L_m3", "A_L_m2", "A_PR_m2", "A_PR_exact_m2",
                      "view_dir", "per_tree"}
    assert [row["tree_id"] for row in d["per_tree"]] == [0, 3]


def test_empty_and_zero_length():
    r = wood_measures(Branches.empty())
    assert r.total.n_branches == 0 and r.total.a_l_m2 == 0.0 and r.per_tree == {}
    z = wood_measures(cylinders([1, 1, 1], [1, 1, 1], 0.05)).total
    assert z.n_branches == 1 and z.a_pr_exact_m2 == 0.0 and z.v_l_m3 == 0.0


def test_deterministic_apple_tree_closed_form():
    # order o: 7·3**(o-1) cylinders, h = h0/2**(o-1), d = N·dm/o
    n, h0, dm = 5, 0.4, 0.005
    t = apple_tree(AppleTreeParams(n, h0_m=h0, d_min_m=dm))
    m = wood_measures(t).total
    orders = np.arange(1, n + 1)
    count, h, d = 7 * 3.0 ** (orders - 1), h0 / 2.0 ** (orders - 1), n * dm / orders
    assert m.v_l_m3 == pytest.approx(np.sum(count * np.pi * d * d * h / 4), rel=1e-12)
    assert m.a_l_m2 == pytest.approx(np.sum(count * np.pi * d * h), rel=1e-12)
    assert m.a_pr_m2 == pytest.approx(np.sum(count * d * h), rel=1e-12)
    assert m.a_pr_exact_m2 <= m.a_pr_m2 + np.sum(count * np.pi * d * d / 4)
