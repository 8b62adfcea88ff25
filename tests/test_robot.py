"""The simulated robot experiment (Tables II-IV): protocol, ranks, JSON, command."""

import json
import math

import numpy as np
import pytest

from fingerloc import sim
from fingerloc.cli import main
from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.robot import (
    PAPER_TABLE4,
    TABLE4_FITTED,
    TABLE4_TERMS,
    RobotProtocol,
    RobotResult,
    evaluate_trial,
    measurement_poses,
    rank_of_truth,
    run_robot,
    simulate_trial,
    small_protocol,
)


def run(capsys, *args):
    code = 0
    try:
        main(list(args))
    except SystemExit as e:
        code = int(e.code or 0)
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def trial():
    p = small_protocol()
    data = simulate_trial(p, (0, 0))
    return p, data, evaluate_trial(data, p)


def test_poses_follow_the_protocol():
    p = RobotProtocol()
    worlds = sim.make_offices(3, random_state=1)
    rng = np.random.default_rng(2)
    for w in worlds:
        train, test = measurement_poses(w, p, rng)
        assert len(train) == 8 and len(test) == 2
        ax, ay = w.anchor
        for x, y, th in train:
            assert 0.4 - 1e-9 <= math.hypot(x - ax, y - ay) <= 0.7 + 1e-9
            assert abs(th) < math.radians(10)
        for x, y, _ in test:
            assert math.hypot(x - ax, y - ay) <= 0.4 + 1e-9
        pts = np.array([(x, y) for x, y, _ in train + test])
        assert w.contains(pts).all()
        assert (w.clearance(pts) >= p.min_clearance_m - 1e-9).all()
        # eight evenly spaced directions around the measurement point
        ang = np.sort(np.mod([math.atan2(y - ay, x - ax) for x, y, _ in train], 2 * np.pi))
        gaps = np.diff(np.append(ang, ang[0] + 2 * np.pi))
        assert np.allclose(gaps, 2 * np.pi / 8, atol=1e-6)


def test_rank_ties_count_against():
    s = np.array([[0.0, 1.0, 1.0], [3.0, 1.0, 2.0], [-np.inf, -np.inf, 0.0]])
    r = rank_of_truth(s, np.array([1, 0, 0]))
    assert r.tolist() == [2, 1, 3]


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"n_offices": 1}, "n_offices"),
        ({"train_radius_m": (0.7, 0.4)}, "train_radius_m"),
        ({"test_radius_m": -1.0}, "test_radius_m"),
        ({"ks": (0,)}, "ks"),
        ({"heading_jitter_deg": -2.0}, "heading_jitter_deg"),
    ],
)
def test_protocol_validation(kwargs, match):
    with pytest.raises(InvalidParameterError, match=match):
        RobotProtocol(**kwargs)


def test_run_robot_validation():
    with pytest.raises(InvalidParameterError, match="trials"):
        run_robot(trials=0)
    with pytest.raises(InvalidParameterError, match="seed"):
        run_robot(trials=1, seed=-1)


def test_trial_uses_raw_sensor_features(trial):
    p, data, ev = trial
    roles = [m.role for m in data.measurements]
    assert roles.count("train") == p.n_offices * p.n_train
    assert roles.count("test") == p.n_offices * p.n_test
    assert roles.count("test-random-heading") == p.n_offices * p.n_test
    # features come from the extractors: some of every type, bearings differ from measurement to measurement
    assert all(ev.features[t] > 0 for t in ("VE", "Ex", "CP", "c"))
    ve = [tuple(np.round(m.observation.ve, 6)) for m in data.measurements]
    assert len(set(ve)) == len(ve)
    assert all(m.scan is None for m in data.measurements)  # raw data not kept unless asked


def test_trial_cells_and_json(trial):
    p, _, ev = trial
    for key, (top1, rank) in ev.cells.items():
        assert 0.0 <= top1 <= 1.0, key
        assert 1.0 <= rank <= p.n_offices, key
    assert np.allclose(ev.posterior.sum(axis=1), 1.0)
    res = RobotResult(protocol=p, seed=0, trials=[ev, ev])
    js = json.loads(json.dumps(res.to_json()))
    assert set(js["table2"]) >= {"VE", "Ex", "CP", "B"}
    assert set(js["table3"]) == {"minimum_energy", "global_alignment"}
    for m in js["table3"].values():
        assert set(m) == {"top1", "mean_rank"}
    assert set(js["table4"]) == {*TABLE4_TERMS, TABLE4_FITTED}
    for row in js["table4"].values():
        assert set(row) == {str(k) for k in p.ks}
        for cell in row.values():
            assert set(cell) == {"top1", "mean_rank"} and 0 <= cell["top1"] <= 1
    assert "global_alignment" in js["random_heading"]
    assert js["spread"]["table4"]["VE"]["3"]["top1"] == 0.0  # two identical trials
    assert js["paper"]["table4"]["VE+Ex+Fp"]["5"]["top1"] == PAPER_TABLE4["VE+Ex+Fp"][5][0]


def test_random_heading_is_estimated(trial):
    _, data, ev = trial
    turned = [m for m in data.measurements if m.role == "test-random-heading"]
    assert any(abs(m.pose[2]) > 0.5 for m in turned)
    # cyclic alignment recovers the heading to a few degrees in most cases
    assert np.median(ev.heading_error_deg) < 10.0


def test_same_seed_same_trial():
    p = small_protocol(n_offices=2, n_train=2, n_test=1, random_heading=False)
    a = simulate_trial(p, (5, 0))
    b = simulate_trial(p, (5, 0))
    for x, y in zip(a.measurements, b.measurements, strict=True):
        assert x.pose == y.pose and x.observation == y.observation


def test_reproduce_robot_command(tmp_path, capsys):
    out = tmp_path / "robot.json"
    code, stdout, _ = run(
        capsys, "reproduce", "robot", "--quick", "--trials", "1", "--workers", "1", "--json", str(out)
    )
    assert code == 0
    assert "Table II" in stdout and "Table III" in stdout and "Table IV" in stdout and "paper" in stdout
    js = json.loads(out.read_text())
    assert {"table2", "table3", "table4", "random_heading"} <= set(js)


def test_reproduce_robot_bad_input(capsys):
    code, _, err = run(capsys, "reproduce", "robot", "--trials", "0")
    assert code == 2 and "trials" in err
    code, _, err = run(capsys, "reproduce", "robot", "--similarity", "1.5")
    assert code == 2 and "similarity" in err


@pytest.mark.slow
def test_parallel_simulation_matches_serial():
    from fingerloc.experiments.robot import simulation_pool

    p = small_protocol(n_offices=2, n_train=2, n_test=1, random_heading=False)
    a = simulate_trial(p, (3, 1))
    with simulation_pool(2) as ex:
        b = simulate_trial(p, (3, 1), executor=ex)
    for x, y in zip(a.measurements, b.measurements, strict=True):
        assert x.observation == y.observation
