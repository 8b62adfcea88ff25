"""The simulated robot experiment (Tables II-IV): protocol, ranks, JSON, command."""

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from fingerloc import sim
from fingerloc.cli import main
from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.robot import (
    PAPER_TABLE3,
    PAPER_TABLE4,
    TABLE4_EXP,
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
    # (a view of the calibrated world may show no long vertical edge at all: those are left out)
    ve = [tuple(np.round(m.observation.ve, 6)) for m in data.measurements if m.observation.ve.size]
    assert len(ve) > len(data.measurements) // 2 and len(set(ve)) == len(ve)
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
        assert set(m) == {"top1", "mean_rank", "ci95"}
    assert set(js["table4"]) == {*TABLE4_TERMS, TABLE4_FITTED, TABLE4_EXP}
    for name, row in js["table4"].items():
        assert set(row) == {str(k) for k in p.ks}
        for k, cell in row.items():
            assert set(cell) == {"top1", "mean_rank", "ci95"} and 0 <= cell["top1"] <= 1
            # the interval inside the cell is the one of the ci95 block
            assert cell["ci95"] == js["ci95"]["table4"][name][k]
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


def test_parallel_simulation_matches_serial():
    from fingerloc.experiments.robot import simulation_pool

    p = small_protocol(n_offices=2, n_train=2, n_test=1, random_heading=False)
    a = simulate_trial(p, (3, 1))
    with simulation_pool(2) as ex:
        b = simulate_trial(p, (3, 1), executor=ex)
    for x, y in zip(a.measurements, b.measurements, strict=True):
        assert x.observation == y.observation


def test_t_interval_matches_hand_computation():
    from fingerloc.experiments.robot import t_interval

    v = [0.8, 0.9, 0.7, 1.0]
    # mean 0.85, s = sqrt(0.05 / 3), t_{0.975, 3} = 3.182446305
    h = 3.182446305284263 * math.sqrt(0.05 / 3) / 2
    lo, hi = t_interval(v)
    assert lo == pytest.approx(0.85 - h) and hi == pytest.approx(0.85 + h)
    assert t_interval([0.5]) is None


def test_wilson_interval_known_values():
    from fingerloc.experiments.robot import wilson_interval

    z2 = 1.959963984540054**2
    lo, hi = wilson_interval(0, 20)
    assert lo == 0.0 and hi == pytest.approx(z2 / (20 + z2))  # all wrong: upper bound z^2 / (n + z^2)
    lo, hi = wilson_interval(20, 20)
    assert hi == 1.0 and lo == pytest.approx(20 / (20 + z2))
    lo, hi = wilson_interval(10, 20)  # symmetric about one half
    assert lo + hi == pytest.approx(1.0) and lo < 0.5 < hi
    assert wilson_interval(0, 0) is None


def test_json_has_confidence_intervals(trial):
    p, _, ev = trial
    one = json.loads(json.dumps(RobotResult(protocol=p, seed=0, trials=[ev]).to_json()))
    cell = one["ci95"]["table4"]["VE+Ex+Fp"]["3"]
    top1 = one["table4"]["VE+Ex+Fp"]["3"]["top1"]
    assert cell["top1"][0] <= top1 <= cell["top1"][1]
    assert cell["top1"][1] - cell["top1"][0] > 0.05  # eight queries: a wide interval
    assert set(one["ci95"]["table2"]) >= {"VE", "Ex", "CP", "B"}
    assert "Wilson" in one["protocol"]["ci95"]
    two = RobotResult(protocol=p, seed=0, trials=[ev, ev]).to_json()
    # two identical trials: a zero-width interval at the mean
    assert two["ci95"]["table3"]["global_alignment"]["top1"] == [two["table3"]["global_alignment"]["top1"]] * 2
    assert "Student" in two["protocol"]["ci95"]


def test_worlds_and_profiles():
    from fingerloc.experiments.robot import WORLD_PROFILES

    assert set(WORLD_PROFILES) == {"paper", "paper-static", "paper-ideal", "alike"}
    assert {prof["offices"] for prof in WORLD_PROFILES.values()} == set(sim.WORLDS) == {"paper", "alike"}
    assert RobotProtocol().world == "paper" and RobotProtocol().office_similarity == 0.8
    # the default world measures its test poses at a later visit; the old settings stay reachable
    assert RobotProtocol().session_change == sim.PAPER_VISIT
    assert RobotProtocol(world="paper-ideal").session_change == sim.OFFICE_DAY
    assert RobotProtocol(world="paper-static").session_change is None
    assert RobotProtocol(world="alike").session_change is None
    assert RobotProtocol().perception == RobotProtocol(world="paper-static").perception == sim.PAPER_ROBOT
    assert RobotProtocol(world="paper-ideal").perception is None and RobotProtocol(world="alike").perception is None
    # the later visit of the paper world is the office day plus the robot's heading offset
    assert sim.PAPER_VISIT == replace(sim.OFFICE_DAY, heading_offset_deg=sim.PAPER_VISIT.heading_offset_deg)
    same = ("session", "perception", "calibrated_on")
    for other in ("paper-static", "paper-ideal"):
        mine = {k: v for k, v in WORLD_PROFILES[other].items() if k not in same}
        assert mine == {k: v for k, v in WORLD_PROFILES["paper"].items() if k not in same}
    assert WORLD_PROFILES["paper"]["calibrated_on"] == ["table2", "table3"]
    assert RobotProtocol(world="alike").office_similarity == 0.5
    assert RobotProtocol(world="alike", similarity=0.95).office_similarity == 0.95
    with pytest.raises(InvalidParameterError, match="world"):
        RobotProtocol(world="zillow")


def test_later_visit_changes_only_the_test_measurements():
    p = small_protocol(n_offices=2, n_train=2, n_test=2, omni_size=(160, 120), panorama_width=180, random_heading=False)
    later = simulate_trial(p, (5, 0), keep_raw=True)
    static = simulate_trial(replace(p, world="paper-static"), (5, 0), keep_raw=True)
    assert [w.name for w in later.test_worlds] == [w.name for w in later.worlds]
    assert all(a is b for a, b in zip(static.worlds, static.test_worlds, strict=True))
    assert not any(a is b for a, b in zip(later.worlds, later.test_worlds, strict=True))
    turns: dict[int, list[float]] = {}
    for a, b in zip(later.measurements, static.measurements, strict=True):
        assert a.pose[:2] == b.pose[:2] and a.role == b.role and a.office == b.office
        same_image = np.array_equal(a.omni.image, b.omni.image)
        # the same offices, poses and sensor noise at the training visit; another office at the test visit
        assert same_image if a.role == "train" else not same_image
        if a.role == "train":
            assert a.observation == b.observation and a.pose == b.pose
        else:
            turns.setdefault(a.office, []).append(a.pose[2] - b.pose[2])
    # the robot's heading at the later visit: one offset per office, the same for its test poses
    assert all(len(v) == 2 and v[0] == pytest.approx(v[1]) for v in turns.values())
    assert len({round(v[0], 9) for v in turns.values()}) == len(turns)


def test_perception_errors_change_the_extracted_features():
    p = small_protocol(n_offices=2, n_train=3, n_test=1, omni_size=(160, 120), panorama_width=180, random_heading=False)
    ideal = simulate_trial(replace(p, world="paper-ideal"), (3, 0), keep_raw=True)
    paper = simulate_trial(p, (3, 0), keep_raw=True)
    assert RobotProtocol(world="paper-ideal").perception is None and p.perception == sim.PAPER_ROBOT
    for a, b in zip(ideal.measurements, paper.measurements, strict=True):
        # the perfect robot reports what the extractors found; the calibrated one changes it from there
        assert a.extracted == a.observation
        assert b.extracted is not None and b.observation.label == b.extracted.label
        if a.role == "train":  # same offices, poses and raw data at the training visit
            assert a.extracted == b.extracted
    changed = sum(m.observation != m.extracted for m in paper.measurements)
    assert changed >= 1


def test_table2_per_visit(trial):
    p, data, ev = trial
    assert set(ev.features_by_visit) == {"train", "test"}
    out = RobotResult(protocol=p, seed=0, trials=[ev, ev]).to_json()
    assert set(out["table2_by_visit"]["test"]) >= {"VE", "Ex", "CP", "B"}
    assert out["protocol"]["sensor_profile"]["session"]["chair_moved"] == sim.OFFICE_DAY.chair_moved
    n = {r: len(data.observations(r)) for r in ("train", "test")}
    for t in ("VE", "Ex", "CP", "B"):  # Table II is the mean over both visits' measurements
        both = sum(n[r] * ev.features_by_visit[r][t] for r in n) / sum(n.values())
        assert both == pytest.approx(ev.features[t])
        assert out["table2_by_visit"]["train"][t] == pytest.approx(ev.features_by_visit["train"][t])


def test_reproduce_robot_bad_world(capsys):
    code, _, err = run(capsys, "reproduce", "robot", "--world", "mall")
    assert code == 2 and "--world" in err and "mall" in err


def test_explain_query_names_the_terms_that_pulled_wrong(trial):
    from fingerloc.experiments.report import explain_query

    _, data, ev = trial
    why = explain_query(data, ev)
    assert why is not None
    assert f"Between the training and the test visit of {why.truth}: " in why.reason  # the default world's later visit
    answers = np.argmax(ev.posterior, axis=1)
    wrong = np.flatnonzero(answers != ev.truth)
    if wrong.size:  # the full program's first wrong answer is the one explained
        assert why.program == ("VE", "Ex", "Fp") and why.k == max(ev.models)
        assert why.index == int(wrong[0]) and why.truth != why.answer
        pulling = [t for t, (lt, la) in why.terms.items() if la > lt]
        assert pulling and all(
            t in why.reason or {"VE": "vertical-edge", "Ex": "extremity", "Fp": "fingerprint"}[t] in why.reason
            for t in pulling
        )
    elif why.truth != why.answer:  # else one that a program with fewer terms gets wrong
        assert why.program in (("VE", "Ex"), ("Ex",), ("VE",)) and set(why.terms) == set(why.program)
    else:
        assert "right" in why.reason
    # the joint log-likelihood (terms weighted 1) favours the answer over the other place compared
    truth_sum, rival_sum = (sum(v[i] for v in why.terms.values()) for i in (0, 1))
    assert why.rival != why.truth
    assert (rival_sum >= truth_sum - 1e-9) if why.answer == why.rival else (truth_sum >= rival_sum - 1e-9)
    assert why.posterior.sum() == pytest.approx(1.0)
    # the nearest training fingerprints and their costs are the global-alignment minima
    from fingerloc.align import alignment_costs
    from fingerloc.fingerprint import make_fingerprint

    q = make_fingerprint(data.observations("test")[why.index])
    own = [make_fingerprint(o) for o in data.observations("train") if o.label == why.truth]
    assert why.nearest["truth"][1] == pytest.approx(float(np.min(alignment_costs([q], own))))
    # an explicit index: a right answer explains itself as right
    right = np.flatnonzero(answers == ev.truth)
    if right.size:
        r = explain_query(data, ev, int(right[0]), k=max(ev.models), terms=("VE", "Ex", "Fp"))
        assert r is not None and r.truth == r.answer != r.rival and "right" in r.reason


def test_random_heading_rows_leave_tables_2_to_4_unchanged():
    p = small_protocol(n_offices=2, n_train=2, n_test=1, omni_size=(160, 120), panorama_width=180)
    a = simulate_trial(p, (7, 0))
    b = simulate_trial(replace(p, random_heading=False), (7, 0))
    keep = [m for m in a.measurements if m.role != "test-random-heading"]
    assert len(keep) == len(b.measurements) < len(a.measurements)
    for x, y in zip(keep, b.measurements, strict=True):
        assert x.pose == y.pose and x.observation == y.observation


@pytest.mark.slow
def test_paper_world_counts_near_table_2():
    """Two templates (20 offices, 40 measurements): the robot's extractors find about Table II's counts."""
    from fingerloc.experiments.robot import PAPER_TABLE2, WORLD_PROFILES
    from fingerloc.experiments.sim_stats import calibration_counts

    prof = WORLD_PROFILES["paper"]
    got = calibration_counts(
        world=prof["offices"],
        similarity=prof["similarity"],
        templates=2,
        blur=prof["blur"],
        noise=prof["noise"],
        jpeg_quality=prof["jpeg_quality"],
        edge_params=prof["extractor"],
        session=prof["session"],
    )
    for t, paper in PAPER_TABLE2.items():
        for visit in ("train_", "test_", ""):  # the training visit, the later test visit, both
            assert abs(got[visit + t] / paper - 1.0) <= 0.35, (visit, t, got[visit + t], paper)  # a loose band
    # the alike world's extractor finds several times the paper's vertical edges
    alike = calibration_counts(world="alike", similarity=0.5, templates=1, blur=0.7, noise=0.015, jpeg_quality=85)
    assert alike["VE"] > 2.5 * PAPER_TABLE2["VE"]


def test_findings_compare_the_paper_differences(trial):
    p, _, ev = trial
    res = RobotResult(protocol=p, seed=0, trials=[ev])
    found = {f.key: f for f in res.findings()}
    assert set(found) == {"ga_beats_me", "fusion_beats_single", "fp_helps"}  # one k: no "more components"
    ga = found["ga_beats_me"]
    assert ga.paper == pytest.approx(PAPER_TABLE3["global_alignment"][0] - PAPER_TABLE3["minimum_energy"][0])
    # one trial: paired over its queries, the mean difference of the two cells
    cells = ev.cells
    assert ga.ours == pytest.approx(cells[("table3", "global_alignment")][0] - cells[("table3", "minimum_energy")][0])
    d = (ev.ranks[("table3", "global_alignment")] == 1).astype(float) - (ev.ranks[("table3", "minimum_energy")] == 1)
    if np.std(d) > 0:
        lo, hi = ga.ci95
        assert lo < ga.ours < hi
    verdict = {True: "holds", False: "reversed"}
    for f in found.values():
        if f.ci95 is not None and (f.ci95[0] > 0 or f.ci95[1] < 0):
            assert f.verdict == verdict[f.ci95[0] > 0]
        else:
            assert f.verdict == "not shown"
    js = res.to_json()["findings"]
    assert [f["key"] for f in js] == list(found) and js[0]["verdict"] == ga.verdict
    # two trials: paired over trials; two identical trials give a zero-width interval at the mean
    two = {f.key: f for f in RobotResult(protocol=p, seed=0, trials=[ev, ev]).findings()}
    assert two["ga_beats_me"].ours == pytest.approx(ga.ours) and two["ga_beats_me"].ci95 == pytest.approx(
        (ga.ours, ga.ours)
    )


def test_term_scale_shows_the_flat_paper_fingerprint(trial):
    p, _, ev = trial
    st = RobotResult(protocol=p, seed=0, trials=[ev]).term_stats()
    k = str(p.ks[0])
    sp = st[k]["spread_nats"]
    # 1 / (cost + 1) over costs of a few letters spans a nat or two; the mixtures span far more
    assert 0 < sp["Fp"] < math.log(40) and sp["VE"] > 5 * sp["Fp"]
    assert set(st[k]["fitted_weights"]) == {"VE", "Ex", "Fp"} and st[k]["fp_lambda"] > 0


@pytest.mark.slow
def test_calibrated_errors_put_global_alignment_above_minimum_energy():
    """Table III's ordering in a seeded small run: the calibrated errors hurt minimum energy most."""
    from fingerloc.experiments.sim_stats import table3_sweep

    p = small_protocol(n_offices=8, n_train=6, n_test=2, world="paper-ideal", random_heading=False)
    calibrated = {
        "camera_detection": sim.PAPER_ROBOT.camera_detection,
        "laser_detection": sim.PAPER_ROBOT.laser_detection,
        "spurious": sim.PAPER_ROBOT.spurious,
        "heading_offset_deg": sim.PAPER_VISIT.heading_offset_deg,
    }
    none, cal = table3_sweep([{}, calibrated], trials=2, seed=0, noise_seeds=range(8), protocol=p)
    me, ga = cal["minimum_energy"]["top1"], cal["global_alignment"]["top1"]
    assert none["minimum_energy"]["top1"] >= 0.9 and none["global_alignment"]["top1"] >= 0.85
    assert ga - me >= 0.1 and me <= 0.8


def test_reference_story_tells_the_given_figures_and_verdicts():
    from copy import deepcopy

    from fingerloc.experiments.robot_findings import REFERENCE_RUN, reference_story

    ref = deepcopy(REFERENCE_RUN)
    ref["cells"]["table3/minimum_energy"] = (0.5, 0.41, 0.59)
    ref["findings"]["ga_beats_me"] = (-0.1, -0.15, -0.05)
    ref["findings"]["fp_helps"] = (0.02, -0.01, 0.05)
    lines = reference_story(ref)
    text = "\n".join(lines)
    assert "minimum energy    50.0% [41.0, 59.0]  paper 62.4%" in text
    ga = next(line for line in lines if "global alignment beats minimum energy" in line)
    assert "reversed (-10.0 points [-15.0, -5.0]" in ga
    fp = next(line for line in lines if "the full program beats VE & Ex" in line)
    assert "not shown (+2.0 points" in fp
    assert "VE 5.7 Ex 6.2 CP 2.6 B 4.2 (paper 5.6 5.6 2.7 3.9)" in text
    # the heading-kept comparison is told only when its figures are given
    assert "paper-ideal" in text
    del ref["ideal"]
    assert "paper-ideal" not in "\n".join(reference_story(ref))
    assert reference_story({**ref, "cells": {}}) == []


def test_reference_run_figures_are_the_documented_ones():
    """The demo's reference figures are those of the reproduction section of docs/METHOD.md."""
    from pathlib import Path

    from fingerloc.experiments.robot_findings import REFERENCE_RUN

    doc = (Path(__file__).resolve().parents[1] / "docs" / "METHOD.md").read_text(encoding="utf-8")
    for key, (m, lo, hi) in REFERENCE_RUN["cells"].items():
        cell = f"{100 * m:.1f} [{100 * lo:.1f}, {100 * hi:.1f}]"
        assert cell in doc, (key, cell)
    for key, (m, lo, hi) in REFERENCE_RUN["findings"].items():
        diff = f"{100 * m:+.1f} [{100 * lo:+.1f}, {100 * hi:+.1f}]"
        assert diff in doc, (key, diff)
