import json

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.carmen import make_method, make_split, run_benchmark
from fingerloc.experiments.filtered import FilteredMethod
from fingerloc.experiments.kidnap import kidnap_experiment, with_synthetic_likelihood
from fingerloc.pipeline.calibration import mapping_graph, step_distances
from fingerloc.pipeline.places import visit_folds

from ._chain import chain_data as _chain_data
from ._cli import run_cli as _run_cli


def test_step_distances():
    assert step_distances([[0, 0], [3, 4], [3, 4]]).tolist() == [0.0, 5.0, 0.0]


def test_visit_folds_alternate_per_place():
    idx = np.array([0, 1, 2, 5, 6, 9, 10, 11])
    lab = np.array([0, 0, 1, 0, 0, 1, 0, 0])
    # visits: place 0 at 0-1 (0), place 1 at 2 (0), place 0 at 5-6 (1), place 1 at 9 (1), place 0 at 10-11 (0)
    assert visit_folds(idx, lab).tolist() == [0, 0, 0, 1, 1, 1, 0, 0]


def test_mapping_graph_counts_consecutive_cells():
    pos = np.array([[0, 0], [0.5, 0], [3, 0], [3.2, 0], [6, 0], [0, 0], [3, 0], [6, 0]], dtype=float)
    sp = make_split(pos)
    g, metres = mapping_graph(pos[: sp.n_mapping], sp.centres)
    assert sp.n_mapping == 4 and sp.n_places == 2
    assert g.edges() == {("0", "0"): 1, ("0", "1"): 1, ("1", "1"): 1}
    assert metres == pytest.approx(3.2)  # 3.2 m travelled, one change of place


def test_filtered_method_needs_the_trajectory():
    m = FilteredMethod("baseline-histogram")
    with pytest.raises(InvalidParameterError, match="fit_log"):
        m.fit([], np.zeros(0))
    with pytest.raises(InvalidParameterError, match="unknown base method"):
        FilteredMethod("nope")._factory()


def test_filtered_benchmark_end_to_end(rooms_log):
    run = run_benchmark([rooms_log], ["baseline-histogram", "baseline-histogram-filtered"])
    js = json.loads(json.dumps(run.to_json()))
    lg = js["logs"]["rooms"]
    assert lg["queries"] == 9 and lg["scans"] == 22
    assert lg["methods"]["baseline-histogram-filtered"]["top1"] == 1.0


def test_filtered_method_steps_every_query_pass_scan(rooms_log):
    from fingerloc.experiments.carmen import load_log_scans

    scans, _ = load_log_scans(rooms_log)
    sp = make_split(np.array([s.pose[:2] for s in scans]))
    m = make_method("baseline-histogram-filtered")
    assert isinstance(m, FilteredMethod)
    m.fit_log(scans, sp)
    out = m.score([scans[i] for i in sp.query_idx])
    assert out.shape == (sp.n_queries, sp.n_places)
    assert m.result_.log_posterior.shape == (sp.n_scans - sp.n_mapping, sp.n_places)
    assert m.scale_ > 0 and m.calibration_rows_ > 0
    with pytest.raises(InvalidParameterError, match="queries"):
        m.score(scans[:2])


def test_synthetic_likelihood_marks_the_true_place():
    d = _chain_data()
    assert np.mean(np.argmax(d.log_likelihood, axis=1) == d.truth) > 0.5
    with pytest.raises(InvalidParameterError, match="separation"):
        with_synthetic_likelihood(d, -1.0)


def test_kidnap_recovers_on_a_synthetic_corridor():
    res = kidnap_experiment(_chain_data(), name="chain", n_trials=10, stretch=20, min_jump_m=20.0)
    s = res.summary()
    assert s["trials"] == 10 and s["recovered"] == 10
    assert s["max_recover_steps"] <= 10 and s["within_10"] == 1.0
    for t in res.trials:
        assert t["jump_m"] >= 20.0


def test_cli_track_carmen_and_jsonl(rooms_log, tmp_path, capsys):
    db = tmp_path / "rooms.sqlite"
    out = tmp_path / "t.json"
    code, text, err = _run_cli(capsys, "track", str(rooms_log), "--db", str(db), "--map", "--json", str(out), "-q")
    assert code == 0, err
    js = json.loads(out.read_text())
    assert js["summary"]["steps"] == 11 and js["summary"]["observed_steps"] == 9
    assert js["summary"]["filtered"]["labelled"] == 9
    assert {"best", "probability", "entropy_bits", "true", "observed"} <= set(js["steps"][0])
    from fingerloc.map.graph import load_graph

    assert load_graph(db).graph.number_of_edges() > 0
    # the same database again, without --map, every scan observing
    code, text, err = _run_cli(capsys, "track", str(rooms_log), "--db", str(db), "--observe", "all", "-q")
    assert code == 0, err
    assert "11 steps (11 observed)" in text
    # JSON Lines through the same database
    from fingerloc.io.jsonl import write_observations
    from fingerloc.map.database import load_model

    model = load_model(db)
    obs = [o for p in model.places_.values() for o in p.observations]
    jl = tmp_path / "o.jsonl"
    write_observations(jl, obs)
    code, text, err = _run_cli(capsys, "track", str(jl), "--db", str(db), "--json", str(out))
    assert code == 0, err
    js = json.loads(out.read_text())
    assert js["summary"]["steps"] == len(obs)
    assert js["summary"]["filtered"]["top1"] >= 0.5
    code, _, err = _run_cli(capsys, "track", str(jl), "--db", str(db), "--map")
    assert code == 2 and err.startswith("error:") and "--map" in err


def test_cli_bench_kidnap(rooms_log, tmp_path, capsys):
    out = tmp_path / "k.json"
    code, text, err = _run_cli(
        capsys, "bench", "kidnap", str(rooms_log), "--base", "baseline-histogram", "--stretch", "3",
        "--min-jump", "5", "--trials", "2", "--json", str(out),
    )  # fmt: skip
    assert code == 0, err
    js = json.loads(out.read_text())
    assert "rooms" in js["logs"] and "pooled" in js and js["params"]["stretch"] == 3
    assert "pooled" in text
    # the floor and ground-truth fields beside the old ones; the discrete filter has no floor
    assert {"floor_within_10", "floor_observed_within_10", "truth_within_10", "reference_truth_within_10",
            "cell_within_10", "kidnapped_top1"} <= set(js["pooled"])  # fmt: skip
    assert all(t["floor_recover_steps"] == 0 for t in js["logs"]["rooms"]["trials"])
    assert "floor" in text and "truth" in text


def test_cli_track_jsonl_graph_from(tmp_path, capsys):
    from fingerloc.io.jsonl import write_observations
    from fingerloc.map.database import save_model
    from fingerloc.map.graph import load_graph
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation

    rng = np.random.default_rng(0)
    centres = {"a": [10, 100, 200], "b": [40, 150, 300], "c": [70, 220, 330]}

    def obs(lab, x):
        return Observation.from_degrees(
            {"VE": (np.array(centres[lab]) + rng.normal(0, 3, 3)).tolist()}, label=lab, pose=[x, 0.0, 0.0]
        )

    walk = ["a", "a", "b", "b", "c", "c", "b", "a"]
    train = [obs(lab, float(i)) for i, lab in enumerate(walk)]
    db = tmp_path / "p.sqlite"
    save_model(PlaceModel(n_components=2, terms=("VE",)).fit(train), db)
    tr = tmp_path / "train.jsonl"
    write_observations(tr, train)
    q = tmp_path / "q.jsonl"
    write_observations(q, [obs(lab, float(i)) for i, lab in enumerate(["a", "b", "c"])])
    out = tmp_path / "t.json"
    code, text, err = _run_cli(capsys, "track", str(q), "--db", str(db), "--graph-from", str(tr), "--json", str(out),
                               "--filter", "places")  # fmt: skip
    assert code == 0, err
    assert load_graph(db).edges()[("a", "b")] == 1
    js = json.loads(out.read_text())
    assert js["summary"]["steps"] == 3 and js["summary"]["metres_per_move"] == pytest.approx(7 / 4)
    assert "metric transitions over the place positions" in text and js["summary"]["transitions"] == "metric"
    write_observations(tr, [*train, Observation.from_degrees({"VE": [1.0]}, label="zz")])
    code, _, err = _run_cli(capsys, "track", str(q), "--db", str(db), "--graph-from", str(tr))
    assert code == 2 and "'zz'" in err


def test_cli_track_picks_the_filter_the_data_allow(rooms_log, tmp_path, capsys):
    """Without --filter: the pose filter for a log with poses against a map with place positions, and why; the
    place filter when the map has no positions (JSON Lines learned from labels)."""
    db = tmp_path / "rooms.sqlite"
    out = tmp_path / "t.json"
    code, _, err = _run_cli(capsys, "track", str(rooms_log), "--db", str(db), "--map", "--json", str(out), "-q")
    assert code == 0, err
    assert "filter: pose" in err and "odometry" in err
    auto = json.loads(out.read_text())["summary"]
    assert auto["filter"] == "pose"
    # the default gives the pose filter's figure: the same answers as --filter pose
    out_pose = tmp_path / "pose.json"
    code, _, err = _run_cli(capsys, "track", str(rooms_log), "--db", str(db), "--filter", "pose", "--json",
                            str(out_pose), "-q")  # fmt: skip
    assert code == 0 and "filter: " not in err, err
    assert json.loads(out_pose.read_text())["summary"] == auto
    from types import SimpleNamespace

    from fingerloc.pipeline.placemap import load_map

    pm = load_map(db, scan=False)
    assert pm.default_filter(SimpleNamespace(poses=None))[0] == "places"
    assert "no poses" in pm.default_filter(SimpleNamespace(poses=None))[1]
    from fingerloc.io.jsonl import write_observations
    from fingerloc.map.database import load_model

    obs = [o for p in load_model(db).places_.values() for o in p.observations]
    jl = tmp_path / "o.jsonl"
    write_observations(jl, obs)
    db2 = tmp_path / "labels.sqlite"
    assert _run_cli(capsys, "learn", str(jl), "--db", str(db2))[0] == 0
    code, _, err = _run_cli(capsys, "track", str(jl), "--db", str(db2), "--json", str(out), "-q")
    assert code == 0, err
    assert "filter: places" in err and "positions" in err
    assert json.loads(out.read_text())["summary"]["filter"] == "places"
