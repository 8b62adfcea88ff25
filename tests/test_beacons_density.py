"""Beacons at any beam density (windows in metres and degrees, not beams)."""

from __future__ import annotations

import numpy as np
import pytest

from fingerloc.angles import dist_as
from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.beacons import ReflectorScene, run_beacon_bench, simulate_reflector_scan
from fingerloc.features.laser import extract_laser_features

from ._cli import run_cli as run


@pytest.mark.parametrize(("step_deg", "fov_deg"), [(0.25, 270.0), (1.0, 360.0), (0.5, 180.0)])
def test_reflector_found_at_any_beam_density(step_deg, fov_deg):
    res = run_beacon_bench(ReflectorScene(step_deg=step_deg, fov_deg=fov_deg), n_scans=40, seed=3)
    assert res["found_rate"] >= 0.9
    assert res["false_per_scan"] <= 0.5
    assert res["mean_error_deg"] < 1.0


def test_the_old_beam_window_misses_the_reflector():
    # a background window of 12 beams (3 deg at 0.25 deg a beam) is narrower than the reflector (4.9 deg)
    old = {"beacon_window_m": 0.001, "beacon_window_deg": 3.0}
    assert run_beacon_bench(ReflectorScene(glossy_ratio=0.0), n_scans=20, params=old)["found_rate"] <= 0.1


def test_widest_reflector_near_the_scanner():
    # 15 cm at 0.5 m covers 17 deg (69 beams at 0.25 deg): still narrower than the metres window
    scene = ReflectorScene(diameter=0.15, distance=0.5, glossy_ratio=0.0)
    assert run_beacon_bench(scene, n_scans=20, seed=1)["found_rate"] >= 0.9


def test_glossy_strip_is_not_a_beacon_but_a_reflector_is():
    scene = ReflectorScene(reflector_intensity=1100.0 * 1.9, glossy_width=0.0)  # "reflector" as dim as glossy paint
    res = run_beacon_bench(scene, n_scans=30, seed=2)
    assert res["found_rate"] <= 0.1 and res["false_per_scan"] <= 0.1


def test_one_reflector_is_one_beacon_despite_dim_beams_inside():
    rng = np.random.default_rng(5)
    scan, phi = simulate_reflector_scan(ReflectorScene(glossy_width=0.0, dropout=0.0), rng)
    inten = np.array(scan.intensities)
    on = np.flatnonzero(inten > 3000)
    inten[on[1::4]] = 1100.0  # every fourth reflector beam dim
    from fingerloc.sensors import Scan

    b = extract_laser_features(Scan(scan.ranges, scan.bearings, max_range=30.0, intensities=inten)).beacons
    assert b.size == 1 and abs(dist_as(b[0], phi)) < np.deg2rad(1.0)


def test_beacon_parameters_are_checked():
    rng = np.random.default_rng(0)
    scan, _ = simulate_reflector_scan(ReflectorScene(), rng)
    for name in ("beacon_window_m", "beacon_window_deg", "beacon_gap_deg", "beacon_min_width"):
        with pytest.raises(InvalidParameterError, match=name):
            extract_laser_features(scan, **{name: -1.0})
    with pytest.raises(InvalidParameterError, match="beacon_window"):
        extract_laser_features(scan, beacon_window=12)  # the old beam count is gone


def test_bench_beacons_command(tmp_path, capsys):
    import json

    out = tmp_path / "b.json"
    code, text, err = run(capsys, "bench", "beacons", "--scans", "10", "--json", out)
    assert code == 0, err
    js = json.loads(out.read_text())
    assert js["beams"] == 1081 and js["scans"] == 10 and "found in" in text
    code, _, err = run(capsys, "bench", "beacons", "--param", "window=3")
    assert code == 2 and "--param" in err


def test_beacon_options_reach_the_detector(capsys):
    from fingerloc.cli.features import FeatureOptions
    from fingerloc.pipeline.files import _features as _feature_params

    opts = FeatureOptions(beacon_threshold=900.0, beacon_params=(("beacon_ratio", 3.0), ("beacon_window_m", 0.2)))
    assert _feature_params(opts) == {"beacon_threshold": 900.0, "beacon_ratio": 3.0, "beacon_window_m": 0.2}
    code, _, err = run(capsys, "features", "x.log", "--beacon-ratio", "0.5")
    assert code == 2 and "--beacon-ratio" in err and len(err.strip().splitlines()) == 1
    code, _, err = run(capsys, "features", "x.log", "--beacon-threshold", "inf")
    assert code == 2 and "--beacon-threshold" in err
