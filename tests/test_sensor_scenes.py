"""The shipped physical-sensor scenes load and scan (shrunk by overrides) with the effects
they advertise: echoes, intensities, beam times."""
import laspy
import numpy as np
import pytest

from simlidar_mi.lidar.survey import load_scene, run_scan

SCENES = {
    "orchard_lms511": ["orchard.n_trees=1", "scan.dy_m=0.05", "sensor.beam_samples=8"],
    "orchard_vlp16_tractor": ["orchard.n_trees=1", "platform.waypoints_m=[[0.5, -0.5, 1.5], [0.5, 1.5, 1.5]]"],
    "forest_airborne_echoes": ["platform.start_xy_m=[150.0, 150.0]", "platform.end_xy_m=[150.0, 152.0]",
                               "forest.domain_m=[120.0, 180.0, 120.0, 180.0]"],
}


@pytest.mark.parametrize("name", sorted(SCENES))
def test_sensor_scene_scans_with_its_effects(name, tmp_path):
    cfg = load_scene(f"scenes/{name}.toml", SCENES[name])
    assert cfg["sensor"]["preset"] and cfg["sensor"]["intensity"]
    run = run_scan(cfg, tmp_path)
    m = run.measures
    assert m["sensor"]["max_returns"] == cfg["sensor"]["max_returns"] >= 2
    assert m["echoes"]["echoes"] > 100
    las = laspy.read(tmp_path / "points.las")
    assert len(las.points) == m["echoes"]["echoes"]  # one point per echo
    rn, nr = np.asarray(las.return_number), np.asarray(las.number_of_returns)
    assert rn.min() == 1 and np.all(rn <= nr) and nr.max() >= 2
    assert las.intensity.max() > 0
    if name == "orchard_vlp16_tractor":  # moving, spinning: every beam its own time and origin
        assert np.ptp(las.gps_time) > 1.0
        assert m["platform"] == "rotating"
