"""Big flat meshes built inside one shape group with an identity instance (faster Embree
build) must scan exactly as the same meshes at the top level."""
import numpy as np
import pytest

from simlidar_mi.lidar.scan import scan
from simlidar_mi.lidar.survey import build, generate, load_scene, scan_patterns
from simlidar_mi.scene import build as build_mod


def _scan(cfg, threshold, monkeypatch):
    monkeypatch.setattr(build_mod, "GROUP_MIN_TRIANGLES", threshold)
    geometry = generate(cfg)
    lo, hi = geometry.bounds_m()
    pattern = scan_patterns(cfg, lo, hi, geometry.near_x_m)[0]
    built = build(cfg, geometry, [pattern])
    return built, scan(built, pattern, cfg["scene"]["variant"])


@pytest.mark.parametrize("n_trees", [1, 2])
def test_grouped_meshes_scan_like_top_level(n_trees, monkeypatch):
    cfg = load_scene("scenes/apple_orchard.toml", [f"orchard.n_trees={n_trees}", "orchard.tree.iterations=4",
                                                   "scan.dy_m=0.01", "scan.dtheta_deg=0.5"])
    top, a = _scan(cfg, 10**12, monkeypatch)
    grouped, b = _scan(cfg, 1, monkeypatch)
    assert top.instance_proto is None and grouped.instance_proto is not None
    assert grouped.n_instances == 0  # the identity instance is not a placed tree
    assert (a.cls == 2).sum() > 100
    for name in ("range_m", "cls", "element_id", "hit_fraction"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    if n_trees == 1:
        assert a.tree_id is None and b.tree_id is None
    else:
        np.testing.assert_array_equal(a.tree_id, b.tree_id)
        assert set(np.unique(b.tree_id[b.cls == 2])) == {0, 1}
