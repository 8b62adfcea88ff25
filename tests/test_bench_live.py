"""``bench live``'s pieces: the tiled run of the latency map, and evo's APE against a direct computation."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.live import ape_translation, percentile, tiled_run
from fingerloc.pipeline.readers import read_run

from ._cli import run_cli

pytest.importorskip("evo", reason="evo is a test extra (pip install -e '.[test]')")


def test_tiled_run_lays_copies_on_a_grid_and_keeps_time_going(rooms_log):
    run = read_run(rooms_log)
    tiled = tiled_run(run, 3, 5, gap_m=10.0)
    assert len(tiled) == 15 and tiled.kind == "carmen"
    p, q = run.poses[:5], tiled.poses
    dx, dy = np.ptp(p[:, :2], axis=0) + 10.0
    for k, (ox, oy) in enumerate([(0.0, 0.0), (dx, 0.0), (0.0, dy)]):  # two columns
        np.testing.assert_allclose(q[5 * k : 5 * k + 5, 0], p[:, 0] + ox, atol=1e-12)
        np.testing.assert_allclose(q[5 * k : 5 * k + 5, 1], p[:, 1] + oy, atol=1e-12)
        np.testing.assert_array_equal(q[5 * k : 5 * k + 5, 2], p[:, 2])
        for a, b in zip(tiled.scans[5 * k : 5 * k + 5], run.scans[:5], strict=True):
            np.testing.assert_array_equal(a.ranges, b.ranges)
    assert np.all(np.diff(tiled.timestamps) > 0)
    assert tiled.names[5] == "copy1:" + run.names[0]
    with pytest.raises(InvalidParameterError, match="copies must be >= 1"):
        tiled_run(run, 0, 5)


def test_ape_is_the_rms_of_the_position_errors(tmp_path):
    rng = np.random.default_rng(0)
    ref = np.column_stack([np.cumsum(rng.normal(0, 1, (40, 2)), axis=0), rng.uniform(-3, 3, 40)])
    est = ref + rng.normal(0, [0.3, 0.2, 0.5], ref.shape)
    res = ape_translation(ref, est, folder=tmp_path)
    err = np.hypot(*(est[:, :2] - ref[:, :2]).T)
    assert res["steps"] == 40
    assert res["rmse_m"] == pytest.approx(math.sqrt(np.mean(err**2)), rel=1e-9)
    assert res["max_m"] == pytest.approx(err.max(), rel=1e-9)
    assert (tmp_path / "reference.tum").exists() and (tmp_path / "estimate.tum").exists()
    assert ape_translation(np.zeros((0, 3)), np.zeros((0, 3)))["rmse_m"] is None
    with pytest.raises(InvalidParameterError, match="3 reference and 2 estimated"):
        ape_translation(ref[:3], est[:2])


def test_percentile_interpolates_as_numpy():
    assert percentile([1.0, 2.0, 3.0, 4.0], 95.0) == pytest.approx(3.85)


def test_bench_live_is_a_command(capsys):
    code, out, _ = run_cli(capsys, "bench", "live", "--help")
    assert code == 0 and "--places" in out and "APE" in out


def test_the_latency_section_times_the_three_variants_on_a_tiled_map(tmp_path):
    from fingerloc.experiments.live import latency

    from ._doors import rooms_log_with_doors

    log = rooms_log_with_doors(tmp_path / "rooms-corrected.log")
    import fingerloc as fl

    cheap = fl.Config().with_(calibration={"tune": False, "scan_gamma": 1.0})
    res = latency(log, places=7, steps=3, warmup=1, config=cheap)
    assert res["places_per_copy"] == 3 and res["copies"] == 3 and res["places"] == 9
    assert set(res["variants"]) == {"default", "every_heading", "no_heading"} and res["steps"] == 3
    assert res["variants"]["every_heading"]["same_place_as_every_heading"] == 3
    assert all(0 <= v["same_place_as_every_heading"] <= 3 for v in res["variants"].values())
    for v in res["variants"].values():
        # each step's CPU time is its observation's plus its filter's: so are the means
        assert v["cpu"]["mean_ms"] == pytest.approx(v["cpu_observe"]["mean_ms"] + v["cpu_filter"]["mean_ms"], rel=1e-9)


def test_the_ape_section_is_evo_over_the_right_steps(tmp_path):
    import fingerloc as fl
    from fingerloc.experiments.live import ape

    from ._doors import rooms_log_with_doors

    log = rooms_log_with_doors(tmp_path / "rooms-corrected.log")
    cheap = fl.Config().with_(calibration={"tune": False, "scan_gamma": 1.0})
    res = ape(log, seed=1, config=cheap)
    track = fl.make_map(fl.read_run(log), cheap).track(fl.read_run(log), filter="pose", seed=1)
    right = [(k, a) for k, a in enumerate(track.answers) if a.true is not None and a.place == a.true]
    assert res["right_steps"] == len(right) > 0 and res["tracked_steps"] == len(track.answers) == 15
    err = [math.hypot(a.pose[0] - track.poses[k][0], a.pose[1] - track.poses[k][1]) for k, a in right]
    assert res["ape_right"]["rmse_m"] == pytest.approx(math.sqrt(np.mean(np.square(err))), rel=1e-9)
    st = res["stream"]  # the query part (15 scans) as its own log, read whole and line by line
    assert st["offline_steps"] == st["stream_steps"] == st["same_place"] == st["same_record"] == 15


def test_the_held_out_log_is_the_query_part(tmp_path):
    from fingerloc.experiments.live import held_out_log
    from fingerloc.pipeline.readers import load_log_scans

    from ._doors import rooms_log_with_doors

    log = rooms_log_with_doors(tmp_path / "rooms-corrected.log")
    assert held_out_log(log, 10, tmp_path / "held.log") == 20
    text = (tmp_path / "held.log").read_text().splitlines()
    assert text[:2] == log.read_text().splitlines()[:2] and text[2].startswith("FLASER")
    full, _ = load_log_scans(log)
    held, _ = load_log_scans(tmp_path / "held.log")
    assert [s.timestamp for s in held] == [s.timestamp for s in full[10:]]


def test_a_position_in_any_copy_goes_back_to_the_first():
    from fingerloc.experiments.live import _in_copy

    corner, pitch, gap = (-2.0, 1.0), (30.0, 20.0), 10.0
    here = np.array([[3.0, 4.0], [-6.0, 1.0], [17.9, 10.9]])  # within copy 0 (up to half a gap outside its box)
    for k, r in ((0, 0), (1, 0), (2, 3), (4, 1)):
        np.testing.assert_allclose(_in_copy(here + np.array([k * pitch[0], r * pitch[1]]), corner, pitch, gap), here, atol=1e-9)
