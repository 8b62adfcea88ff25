"""Places from fingerprints alone: view distances, keyframes, the revisit filter, the node-creation rule, and a
map made from a bag without odometry that ``localize`` and the place filter use."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.special import logsumexp

from fingerloc.errors import InvalidParameterError
from fingerloc.observation import Observation
from fingerloc.pipeline.presets import resolve_preset
from fingerloc.pipeline.revisits import (
    STEP_KERNEL,
    background_log_likelihood,
    loop_closures,
    revisit_filter,
)
from fingerloc.pipeline.topology import fingerprint_places, place_purity
from fingerloc.pipeline.view_distances import (
    distance_term_weights,
    keyframes,
    term_distances,
    view_distance_matrix,
)

from ._bags import write_bag
from ._cli import run_cli
from ._logs import box_scan


def _room_views(rooms=((3.0, 3.0), (8.0, 2.0), (5.0, 12.0), (4.0, 6.0)), loops=2, steps=(-0.6, -0.3, 0.0, 0.3, 0.6)):
    """Laser views walking ``loops`` times through box rooms: (scan, room) per view."""
    out = []
    k = 0
    for _ in range(loops):
        for j, (w, h) in enumerate(rooms):
            for dx in steps:
                out.append((box_scan(w, h, w / 2 + dx, h / 2, 0.3 * dx, noise=0.005, rng=np.random.default_rng(k)), j))
                k += 1
    return out


def _observations(views):
    from fingerloc.features.laser import observation_from_scan

    return [observation_from_scan(s) for s, _ in views]


@pytest.fixture(scope="module")
def rooms():
    views = _room_views()
    obs = _observations(views)
    options = resolve_preset("laser2d", obs).options
    return obs, np.array([j for _, j in views]), options


def test_distance_terms_follow_the_model_options():
    assert distance_term_weights({"terms": ["Fp", "R"]}) == {"Fp": 1.0, "R": 1.0}
    # a term with weight 0 and the mixtures have no say
    assert distance_term_weights({"terms": ["VE", "Fp", "A", "K"], "weights": {"Fp": 0.0, "A": 2.0}}) == {
        "A": 2.0,
        "K": 1.0,
    }
    with pytest.raises(InvalidParameterError, match="distance term"):
        distance_term_weights({"terms": ["VE", "Ex"]})


def test_range_distances_are_the_l1_distance_of_cumulative_histograms(rooms):
    obs, _, options = rooms
    d = term_distances(obs[:5], options, obs[3:9])["R"]
    # oracle: the histogram of each view's ranges (0.25 m bins to 10 m, one more bin), cumulated, L1
    edges = np.arange(0.25, 10.0 + 1e-9, 0.25)

    def cum(o):
        r = np.where(np.isfinite(o.ranges), o.ranges, np.inf)
        h = np.bincount(np.minimum(np.searchsorted(edges, r, side="right"), edges.size), minlength=edges.size + 1)
        return np.cumsum(h / h.sum())

    want = np.array([[np.abs(cum(a) - cum(b)).sum() for b in obs[3:9]] for a in obs[:5]])
    np.testing.assert_allclose(d, want, atol=1e-12)


def test_view_distance_matrix_weighs_each_term_by_its_scale(rooms):
    obs, _, options = rooms
    d, scales = view_distance_matrix(obs, options, scales={"Fp": 2.0, "R": 0.5})
    per = term_distances(obs, options)
    np.testing.assert_allclose(d, 2.0 * per["Fp"] + 0.5 * per["R"])
    assert scales == {"Fp": 2.0, "R": 0.5}
    np.testing.assert_allclose(np.diag(d), 0.0, atol=1e-12)


def test_keyframes_skip_views_that_repeat_the_last_keyframe(rooms):
    obs, _, options = rooms
    doubled = [o for o in obs[:6] for _ in range(3)]  # every view three times in a row
    keys = keyframes(doubled, options, change=0.01)
    assert keys[0] == 0 and np.all(keys % 3 == 0)  # a repeat never differs from the keyframe it repeats
    assert keyframes(doubled, options, change=0.0).tolist() == list(range(len(doubled)))
    assert keyframes([], options).size == 0


def test_background_is_the_log_mean_likelihood_of_the_views_out_of_reach():
    rng = np.random.default_rng(3)
    d = rng.uniform(0, 5, (9, 9))
    bg = background_log_likelihood(d, 2)
    for i in range(9):
        far = [k for k in range(9) if abs(k - i) > 2]
        assert bg[i] == pytest.approx(logsumexp(-d[i, far]) - math.log(len(far)))


def test_step_kernel_is_a_normalised_gaussian_over_five_steps():
    ks = [k for k, _ in STEP_KERNEL]
    w = np.array([w for _, w in STEP_KERNEL])
    assert ks == [-2, -1, 0, 1, 2] and w.sum() == pytest.approx(1.0)
    assert w[0] / w[2] == pytest.approx(math.exp(-2.0))


def test_revisit_filter_names_the_earlier_view_a_view_repeats():
    # views 0..5 are distinct; views 8..10 repeat views 1..3 exactly, 6 and 7 are new
    n = 11
    d = np.full((n, n), 20.0)
    np.fill_diagonal(d, 0.0)
    for a, b in ((8, 1), (9, 2), (10, 3)):
        d[a, b] = d[b, a] = 0.0
    bg = np.full(n, -20.0 + math.log(5.0))  # a new place explains a view better than a wrong old one
    post = revisit_filter(d, bg, np.maximum(0, np.arange(n) - 4))
    assert post.best[:4].tolist() == [-1, -1, -1, -1]
    assert post.best[8:].tolist() == [1, 2, 3]
    assert np.all(np.exp(post.log_probability[8:]) > 0.99)
    assert np.all(post.unknown[5:8] > 0.9)  # nothing repeats: a new place
    # the sequence helps: the third repeat is surer than the first
    assert post.log_probability[10] >= post.log_probability[8]


def test_revisit_filter_checks_its_inputs():
    d = np.zeros((3, 3))
    with pytest.raises(InvalidParameterError):
        revisit_filter(d, np.zeros(3), np.array([0, 2, 1]))  # eligible beyond the view itself
    with pytest.raises(InvalidParameterError):
        revisit_filter(np.zeros((3, 2)), np.zeros(3), np.zeros(3, int))
    with pytest.raises(InvalidParameterError):
        revisit_filter(d, np.zeros(3), np.zeros(3, int), leave=1.0)


def test_a_place_ends_after_the_change_budget_and_a_revisit_joins_the_old_place():
    # a corridor of 40 views, each 10 nats from the next (as real views one metre apart); then 8 views unlike
    # anything; then 7 views that show corridor views 10..16 again
    src = list(range(40)) + [None] * 8 + list(range(10, 17))
    n = len(src)
    d = np.full((n, n), 30.0)
    for a in range(n):
        for b in range(n):
            if src[a] is not None and src[b] is not None:
                d[a, b] = min(10.0 * abs(src[a] - src[b]), 30.0)
    np.fill_diagonal(d, 0.0)
    place, closures = fingerprint_places(d, change=2.5, join=0.9, recent=4)
    # the corridor: the typical change is 10 nats, so a new place after every 3 views (25 nats exceeded)
    assert place[:39].tolist() == [k // 3 for k in range(39)]
    assert len(set(place[40:48].tolist())) == 8  # each unlike view is a place of its own
    assert closures.shape[0] >= 1
    for k, j in closures.tolist():
        assert k >= 48 and src[k] == src[j] and place[k] == place[j]  # a revisit joins the place it shows
    # joining never: a chain of places only
    chain, none = fingerprint_places(d, change=2.5, join=2.0, recent=4)
    assert none.size == 0 and np.all(np.diff(chain) >= 0)


def test_place_purity_counts_views_near_their_place_median():
    pos = np.array([[0, 0], [1, 0], [2, 0], [50, 0], [10, 10], [10.5, 10]], float)
    lab = np.array([0, 0, 0, 0, 1, -1])
    # place 0's median is (1.5, 0): views at 0, 1, 2 are within 3 m, the one at 50 is not; place 1 is pure
    assert place_purity(lab, pos, 3.0) == pytest.approx(4 / 5)
    with pytest.raises(InvalidParameterError):
        place_purity(lab, pos[:3])


def test_loop_closures_find_the_second_loop_through_the_rooms(rooms):
    obs, room, options = rooms
    lc = loop_closures(obs, options, recent=4)
    second = np.arange(len(obs) // 2, len(obs))
    sure = second[np.exp(lc.log_probability[second]) > 0.5]
    assert sure.size >= 3
    assert np.all(room[lc.best[sure]] == room[sure])  # every sure revisit names a view of the same room


def _bag_without_odometry(path):
    """A ROS 1 bag of 180 deg scans (no odometry, no /tf): twice through four box rooms."""
    scans = []
    for k, (s, _) in enumerate(_room_views()):
        r = np.minimum(s.ranges, 29.0).astype(np.float32)
        scans.append((10.0 + 0.5 * k, "/scan", {"n": r.size, "fov_deg": 180.0, "ranges": r, "intensities": False}))
    return write_bag(path, True, scans=scans)


def test_a_bag_without_odometry_maps_from_fingerprints_and_the_place_filter_tracks_it(tmp_path, capsys):
    import fingerloc as fl
    from fingerloc.pipeline.topology import places_from_fingerprints

    bag = _bag_without_odometry(tmp_path / "noodom.bag")
    room = np.array([j for _, j in _room_views()])
    run = fl.read_run(bag, bag_options={"pose_source": "none"})
    assert run.poses is None
    fm = places_from_fingerprints(run)  # the first loop through the rooms maps
    assert fm.n_mapping == len(run) // 2 and 2 <= fm.n_places <= fm.n_mapping
    for j in range(4):  # no place mixes two rooms
        assert (
            len(
                set(fm.assignment[room[: fm.n_mapping] == j].tolist())
                & set(fm.assignment[room[: fm.n_mapping] != j].tolist())
            )
            == 0
        )
    db = tmp_path / "fp.sqlite"
    fm.save(db)
    back = fl.load_map(db)
    assert back.labels == fm.labels and back.positions is None and back.graph.graph.number_of_edges() > 0
    res = back.track(run, filter="places")  # the run the map was made from: its second loop is tracked
    assert len(res.answers) == len(run) - fm.n_mapping and all(a.observed for a in res.answers)
    right = [int(a.place) in set(fm.assignment[room[: fm.n_mapping] == room[fm.n_mapping + t]].tolist())
             for t, a in enumerate(res.answers)]  # fmt: skip
    assert sum(right) >= len(right) - 2
    # the command line: map, the place filter and localize on the same bag
    cli_db = tmp_path / "cli.sqlite"
    code, _, err = run_cli(capsys, "map", bag, "--places", "fingerprints", "--pose-source", "none", "--db", cli_db)
    assert code == 0, err
    assert f"{fm.n_places} place(s) from fingerprints" in err
    code, out, err = run_cli(capsys, "track", bag, "--db", cli_db, "--pose-source", "none", "-q")  # no --filter
    assert code == 0, err
    assert "filter: places" in err and f"{len(run) - fm.n_mapping} steps" in out
    code, out, err = run_cli(capsys, "localize", bag, "--db", cli_db, "--pose-source", "none", "-q")
    assert code == 0, err


def test_map_from_fingerprints_refuses_queries_before_writing(tmp_path, rooms_log, capsys):
    db = tmp_path / "x.sqlite"
    code, _, err = run_cli(
        capsys, "map", rooms_log, "--places", "fingerprints", "--db", db, "--queries", tmp_path / "q.jsonl"
    )
    assert code == 2 and "--queries" in err and not db.exists()
    code, _, err = run_cli(capsys, "map", rooms_log, "--places", "nowhere", "--db", db)
    assert code == 2 and not db.exists()


def test_map_from_fingerprints_writes_all_its_outputs_or_none(tmp_path, rooms_log, capsys, monkeypatch):
    import errno
    import os

    import fingerloc.reporting.loops as pages

    db, js, rep, tum = tmp_path / "m.sqlite", tmp_path / "m.jsonl", tmp_path / "rep", tmp_path / "m.tum"
    rep.mkdir()
    old = {db: b"old database", js: b"old views\n", rep / "index.html": b"<p>old</p>", rep / "places.png": b"old"}
    for path, content in old.items():
        path.write_bytes(content)
    draw = pages.draw_fingerprint_places

    def full_disk(path, **kwargs):  # the figure is written, then the device is full
        draw(path, **kwargs)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))

    monkeypatch.setattr(pages, "draw_fingerprint_places", full_disk)
    args = ("map", rooms_log, "--places", "fingerprints", "--db", db, "--overwrite", "--json", js, "--report", rep,
            "--tum", tum)  # fmt: skip
    code, _, err = run_cli(capsys, *args)
    last = err.strip().splitlines()[-1]
    assert code == 2 and last == f"error: cannot write {rep / 'places.png'}: no space left on the device"
    assert "Traceback" not in err
    assert {p: p.read_bytes() for p in old} == old  # every existing file byte-identical
    assert sorted(os.listdir(tmp_path)) == ["m.jsonl", "m.sqlite", "m.sqlite.lock", "rep"]  # no temporary left
    assert sorted(os.listdir(rep)) == ["index.html", "places.png"]
    monkeypatch.setattr(pages, "draw_fingerprint_places", draw)
    code, _, err = run_cli(capsys, *args)
    assert code == 0, err
    assert db.read_bytes().startswith(b"SQLite format 3") and js.read_bytes() != old[js] and tum.exists()
    assert b"Places from fingerprints" in (rep / "index.html").read_bytes() and (rep / "report.json").exists()
    assert sorted(os.listdir(tmp_path)) == ["m.jsonl", "m.sqlite", "m.sqlite.lock", "m.tum", "rep"]
    assert f"poses to {tum}" in err


def test_map_from_fingerprints_of_a_short_run_warns_of_its_single_place(tmp_path, capsys):
    from ._logs import write_log

    log = write_log(tmp_path / "short.log", [(3.0, 3.0, 1.5, 1.5, 0.0)] * 4)  # four views of one room
    code, _, err = run_cli(capsys, "map", log, "--places", "fingerprints", "--db", tmp_path / "s.sqlite")
    assert code == 0, err
    assert "1 place(s) from fingerprints" in err and "warning: the map has 1 place" in err


def test_map_from_fingerprints_refuses_tum_without_poses_before_any_work(tmp_path, capsys):
    bag = _bag_without_odometry(tmp_path / "noodom.bag")
    db = tmp_path / "n.sqlite"
    code, _, err = run_cli(capsys, "map", bag, "--places", "fingerprints", "--pose-source", "none", "--db", db,
                           "--tum", tmp_path / "n.tum")  # fmt: skip
    assert code == 2 and "--tum" in err and "no pose" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["noodom.bag"]


def test_map_from_fingerprints_of_a_log_with_poses_reports_its_purity(tmp_path, rooms_log, capsys):
    rep = tmp_path / "rep"
    code, _, err = run_cli(capsys, "map", rooms_log, "--places", "fingerprints", "--db", tmp_path / "y.sqlite",
                           "--report", rep)  # fmt: skip
    assert code == 0, err
    assert "purity" in err and (rep / "places.png").exists() and (rep / "index.html").exists()


def test_observations_without_any_distance_term_are_refused():
    obs = [Observation(ve=np.array([0.1, 1.0])), Observation(ve=np.array([0.2, 2.0]))]
    with pytest.raises(InvalidParameterError, match="distance term"):
        view_distance_matrix(obs, {"terms": ["VE"]})


def test_panoramas_in_order_give_one_place_per_room_and_the_place_filter_follows_them(tmp_path, capsys):
    import fingerloc as fl
    from fingerloc.features.vision import observation_from_views
    from fingerloc.io.jsonl import write_observations
    from fingerloc.pipeline.topology import places_from_fingerprints
    from fingerloc.sim import make_offices
    from fingerloc.sim.camera import render_panorama

    offices = make_offices(4, similarity=0.3, random_state=1)
    obs, room = [], []
    for loop in range(2):  # twice through four offices, five panoramas a visit along a short path
        for j, w in enumerate(offices):
            cx, cy = np.asarray(w.room).mean(axis=0)
            for k in range(5):
                pose = (cx + 0.4 * (k - 2), cy + 0.2 * (k - 2) * (-1) ** loop, 0.5 * k + loop)
                pano = render_panorama(
                    w, pose, width=240, height=40, supersample=1, random_state=100 * loop + 10 * j + k
                )
                obs.append(observation_from_views(panorama=pano, appearance=True, profile=True))
                room.append(j)
    path = write_observations(tmp_path / "panoramas.jsonl", obs) and tmp_path / "panoramas.jsonl"
    run = fl.read_run(path)
    fm = places_from_fingerprints(run, preset="panorama")
    half = np.array(room[: fm.n_mapping])
    for j in range(4):  # a place never mixes two offices
        assert not set(fm.assignment[half == j].tolist()) & set(fm.assignment[half != j].tolist())
    code, _, err = run_cli(
        capsys, "map", path, "--places", "fingerprints", "--no-calibration", "--db", tmp_path / "p.sqlite"
    )
    assert code == 0, err
    pm = fl.load_map(tmp_path / "p.sqlite")
    res = pm.track(run, filter="places")  # the run the map was made from: the views after its mapping part
    assert len(res.answers) == len(run) - fm.n_mapping
    right = [
        int(a.place) in set(fm.assignment[half == room[fm.n_mapping + t]].tolist()) for t, a in enumerate(res.answers)
    ]
    assert sum(right) >= len(right) - 1  # the second pass through the offices: the first pass's places
