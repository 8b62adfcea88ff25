"""The library layer: presets, places from a trajectory, schema v2, map / localize / track on raw runs."""

import json
import math
import shutil
import sqlite3
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fingerloc import Observation
from fingerloc.config import Config
from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.carmen import make_split, run_benchmark
from fingerloc.model import PlaceModel
from fingerloc.pipeline.mapping import make_map
from fingerloc.pipeline.placemap import load_map
from fingerloc.pipeline.places import mapping_count, places_from_trajectory
from fingerloc.pipeline.presets import PRESETS, choose_preset, model_options, resolve_preset
from fingerloc.pipeline.readers import read_run

from ._cli import run_cli
from ._runs import write_bag, write_carmen

LASER = Observation.from_degrees({"c": [10, 100], "Ex": [40]}, label="a")
IMAGE = Observation.from_degrees({"VE": [10, 200], "CP": [{"bearing": 40, "hue": 100}]}, label="a")
BOTH = Observation.from_degrees({"VE": [10], "c": [100]}, label="a")


# ---- presets ---------------------------------------------------------------------------------------


def test_auto_picks_by_sensor():
    assert choose_preset([LASER, LASER])[0] == "laser2d"
    assert choose_preset([IMAGE])[0] == "panorama"
    assert choose_preset([LASER, IMAGE])[0] == "multimodal"
    assert choose_preset([BOTH])[0] == "multimodal"
    assert choose_preset([Observation(label="x")])[0] == "paper"
    r = resolve_preset("auto", [LASER, LASER])
    assert r.name == "laser2d" and r.requested == "auto" and "2 of 2 observations have laser features" in r.reason


def test_paper_preset_is_the_default_model():
    opts = model_options("paper")
    default = PlaceModel().get_params()
    assert opts == {**default, "terms": tuple(default["terms"])}


def test_overrides_win_and_are_recorded():
    r = resolve_preset("laser2d", overrides={"terms": ["Fp"], "cyclic": True})
    assert r.options["terms"] == ["Fp"] and r.overrides == {"terms": ["Fp"]}  # cyclic is the preset's already
    assert r.options["laser_letters"] is True
    assert list(r.model().get_params()["terms"]) == ["Fp"]
    with pytest.raises(InvalidParameterError, match=r"preset must be one of .*got 'lidar'"):
        resolve_preset("lidar")
    with pytest.raises(InvalidParameterError, match="costs must be one of unit, feature, got 'zero'"):
        resolve_preset("paper", overrides={"costs": "zero"})


def test_presets_are_editable_plain_dicts():
    assert set(PRESETS) == {"paper", "laser2d", "panorama", "multimodal"}
    for p in PRESETS.values():
        json.dumps(p)  # plain data


# ---- places from a trajectory --------------------------------------------------------------------


def test_places_from_trajectory_is_the_benchmark_split():
    rng = np.random.default_rng(3)
    pos = np.cumsum(rng.normal(0, 0.7, size=(120, 2)), axis=0)
    a, b = places_from_trajectory(pos), make_split(pos)
    for f in ("centres", "centre_scans", "train_idx", "train_labels", "query_idx", "query_labels"):
        assert np.array_equal(getattr(a, f), getattr(b, f))
    assert a.n_mapping == 60


def test_mapping_part_and_until():
    assert mapping_count(10) == 5 and mapping_count(10, mapping_part=0.3) == 3
    assert mapping_count(5, until=2.0, timestamps=[10, 11, 12, 12.5, 20]) == 3  # inclusive
    pos = np.array([[0, 0], [3, 0], [6, 0], [0, 0.5], [3, 0.2], [6, 0.1]], dtype=float)
    sp = places_from_trajectory(pos, until=1.0, timestamps=[0, 1, 2, 3, 4, 5])
    assert sp.n_places == 2 and sp.query_idx.tolist() == [3, 4] and sp.query_labels.tolist() == [0, 1]
    with pytest.raises(InvalidParameterError, match="until needs a timestamp"):
        places_from_trajectory(pos, until=1.0)
    with pytest.raises(InvalidParameterError, match=r"mapping_part must be a fraction in \(0, 1\], got 1\.5"):
        mapping_count(4, mapping_part=1.5)


# ---- map, database v2 ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def rooms(tmp_path_factory):
    return write_carmen(tmp_path_factory.mktemp("runs") / "rooms-corrected.log")


def test_map_round_trip(rooms, tmp_path):
    run = read_run(rooms)
    pm = make_map(run, Config().with_(calibration={"enabled": False}))
    assert pm.preset.name == "laser2d" and pm.split.n_places == 4 and pm.split.n_train == 12
    pm.save(tmp_path / "m.sqlite")
    lm = load_map(tmp_path / "m.sqlite")
    assert lm.labels == pm.labels
    assert np.allclose(lm.positions, pm.split.centres)
    assert lm.calibration == pm.calibration
    assert lm.preset == pm.preset
    assert len(lm.content_hashes) == 12 and lm.mapped_run(run.key)["n_mapping"] == 12
    # graph from the visiting order: room 0 -> 1 -> 2 -> 3 along the mapping part
    assert ("0", "1") in lm.graph.edges() and ("0", "3") not in lm.graph.edges()


def test_version_1_database_still_loads(rooms, tmp_path):
    db = tmp_path / "v1.sqlite"
    shutil.copyfile(Path(__file__).parent / "data" / "v2_laser.sqlite", db)  # written by schema version 2
    with sqlite3.connect(db) as con:  # what fingerloc wrote before schema version 2
        con.execute("UPDATE meta SET value = '1' WHERE key = 'schema_version'")
        con.execute("DELETE FROM meta WHERE key IN ('preset', 'calibration', 'runs')")
        con.execute("DROP TABLE place_positions")
        con.execute("DROP TABLE content_hashes")
    lm = load_map(db)
    assert lm.positions is None and lm.preset is None and lm.calibration is None
    stored = [o for p in lm.model.places_.values() for o in p.observations]
    assert len(lm.content_hashes) == len(stored) == 9  # hashed from the stored observations


def test_map_then_localize_is_the_benchmark(rooms, tmp_path, capsys):
    db, out = tmp_path / "m.sqlite", tmp_path / "out.json"
    code, _, err = run_cli(capsys, "map", rooms, "--db", db)
    assert code == 0, err
    assert "auto picked laser2d" in err
    code, _, err = run_cli(capsys, "localize", rooms, "--db", db, "--json", out, "-q")
    assert code == 0, err
    js = json.loads(out.read_text())
    bench = run_benchmark([rooms], ["fingerprint"]).to_json()["logs"]["rooms"]["methods"]["fingerprint"]
    assert js["preset"] == "laser2d" and js["summary"]["n"] == 12
    assert js["summary"]["top1"] == pytest.approx(bench["top1"], abs=1e-9)
    assert js["summary"]["mean_rank"] == pytest.approx(bench["mean_rank"], abs=1e-9)
    code, out_text, _ = run_cli(capsys, "places", "--db", db)
    assert "preset: laser2d" in out_text and "terms=Fp,R" in out_text and "calibration: beta=" in out_text


def test_map_refuses_to_replace_and_checks_first(rooms, tmp_path, capsys):
    db = tmp_path / "m.sqlite"
    db.write_bytes(b"precious")
    code, _, err = run_cli(capsys, "map", rooms, "--db", db)
    assert code == 2 and "--overwrite" in err and db.read_bytes() == b"precious"
    code, _, err = run_cli(capsys, "map", rooms, "--db", tmp_path / "new.sqlite", "--json", tmp_path / "no" / "x.jsonl")
    assert code == 2 and "--json: " in err and "does not exist" in err and not (tmp_path / "new.sqlite").exists()
    code, _, err = run_cli(capsys, "map", rooms, "--db", db, "--mapping-part", "0", "--overwrite")
    assert code == 2 and "--mapping-part must be a fraction in (0, 1], got 0.0" in err
    assert db.read_bytes() == b"precious"


def test_learn_twice_does_not_duplicate(rooms, tmp_path, capsys):
    db, train = tmp_path / "m.sqlite", tmp_path / "train.jsonl"
    code, _, err = run_cli(capsys, "map", rooms, "--db", tmp_path / "x.sqlite", "--json", train, "--no-calibration")
    assert code == 0, err
    code, _, err = run_cli(capsys, "learn", train, "--db", db)
    assert code == 0 and "auto picked laser2d" in err
    n1 = sum(len(p.observations) for p in load_map(db).model.places_.values())
    code, _, err = run_cli(capsys, "learn", train, "--db", db)
    assert code == 0 and "skipped 12 observation(s) already stored" in err
    assert sum(len(p.observations) for p in load_map(db).model.places_.values()) == n1 == 12
    code, _, err = run_cli(capsys, "learn", train, "--db", db, "--preset", "paper")
    assert code == 2 and "preset 'laser2d'" in err


def test_track_raw_log_with_the_map(rooms, tmp_path, capsys):
    db, out = tmp_path / "m.sqlite", tmp_path / "t.json"
    code, _, err = run_cli(capsys, "track", rooms, "--db", db, "--map", "--filter", "pose", "--json", out, "-q")
    assert code == 0, err
    s = json.loads(out.read_text())["summary"]
    assert s["filter"] == "pose" and s["steps"] == 12 and s["filtered"]["labelled"] == 12
    assert s["likelihood_scale"] == pytest.approx(load_map(db).calibration.beta)
    code, _, err = run_cli(capsys, "track", rooms, "--db", db, "--map")
    assert code == 2 and "--overwrite" in err


def test_map_localize_track_a_bag(tmp_path, capsys):
    bag = write_bag(tmp_path / "rooms-bag")
    db, out, t = tmp_path / "m.sqlite", tmp_path / "out.json", tmp_path / "t.json"
    code, _, err = run_cli(capsys, "map", bag, "--db", db, "--pose-source", "odom", "--no-calibration")
    assert code == 0, err
    assert "4 place(s) from 12 training scan(s)" in err
    code, _, err = run_cli(capsys, "localize", bag, "--db", db, "--json", out, "-q")
    assert code == 0, err
    assert json.loads(out.read_text())["summary"]["n"] == 12  # the query pass, every scan within 1 m
    code, _, err = run_cli(capsys, "track", bag, "--db", db, "--filter", "pose", "--json", t, "-q")
    assert code == 0, err
    s = json.loads(t.read_text())["summary"]
    assert s["steps"] == 12 and s["filtered"]["labelled"] == 12
    code, _, err = run_cli(capsys, "map", bag, "--db", tmp_path / "n.sqlite", "--pose-source", "gps")
    assert code == 2 and "--pose-source must be auto, none, tf, tf:FRAME, odom or odom:TOPIC, got 'gps'" in err


def test_empty_terms_are_named():
    from fingerloc.pipeline.presets import empty_terms

    assert empty_terms(model_options("paper"), [LASER]) == ["VE", "CP", "B"]
    assert empty_terms(model_options("laser2d"), [LASER]) == []


def test_learn_into_a_map_keeps_its_preset(rooms, tmp_path, capsys):
    db, extra = tmp_path / "m.sqlite", tmp_path / "extra.jsonl"
    pm = make_map(read_run(rooms), Config().with_(calibration={"enabled": False}))
    pm.save(db)
    from fingerloc.io.jsonl import write_observations

    write_observations(extra, [pm.training[0].rotated(0.5).with_label("new-place")])
    code, _, err = run_cli(capsys, "learn", extra, "--db", db)
    assert code == 0, err
    lm = load_map(db)
    assert "new-place" in lm.labels and lm.positions is not None  # the new place has its view's position
    assert lm.positions[lm.labels.index("new-place")].tolist() == list(pm.training[0].pose[:2])
    assert lm.preset is not None and lm.preset.name == "laser2d" and len(lm.content_hashes) == 13


@settings(max_examples=60, deadline=None)
@given(
    steps=st.lists(st.tuples(st.floats(-1.5, 1.5), st.floats(-1.5, 1.5)), min_size=1, max_size=60),
    part=st.floats(0.05, 1.0),
)
def test_places_properties(steps, part):
    """Centres are more than the spacing apart; every training scan / query is within the radius of its nearest centre."""
    pos = np.cumsum(np.array(steps, dtype=float), axis=0)
    sp = places_from_trajectory(pos, mapping_part=part)
    c = sp.centres
    if len(c) == 0:  # an empty mapping part makes no place, so nothing trains or is queried
        assert sp.n_mapping == 0 and sp.n_train == 0 and sp.n_queries == 0
        return
    d = np.hypot(c[:, None, 0] - c[None, :, 0], c[:, None, 1] - c[None, :, 1])
    assert np.all(d[~np.eye(len(c), dtype=bool)] > 2.0)
    assert np.all(sp.train_idx < sp.n_mapping) and np.all(sp.query_idx >= sp.n_mapping)
    for idx, lab in ((sp.train_idx, sp.train_labels), (sp.query_idx, sp.query_labels)):
        if idx.size:
            dd = np.hypot(pos[idx, None, 0] - c[None, :, 0], pos[idx, None, 1] - c[None, :, 1])
            assert np.all(dd[np.arange(idx.size), lab] <= 1.0)
            assert np.all(dd[np.arange(idx.size), lab] <= dd.min(axis=1))
    # every mapping scan within the radius of a centre trains (none is lost)
    near = np.hypot(pos[: sp.n_mapping, None, 0] - c[None, :, 0], pos[: sp.n_mapping, None, 1] - c[None, :, 1])
    assert set(sp.train_idx.tolist()) == set(np.flatnonzero(near.min(axis=1) <= 1.0).tolist())
    assert sp.centre_scans.tolist() == sorted(sp.centre_scans.tolist())


def test_another_run_is_queried_whole(rooms, tmp_path, capsys):
    """A run other than the mapped one: every scan within the radius is a query, from its first scan."""
    from ._runs import walk

    db, out = tmp_path / "m.sqlite", tmp_path / "o.json"
    make_map(read_run(rooms), Config().with_(calibration={"enabled": False})).save(db)
    other = write_carmen(tmp_path / "other.log", walk(passes=1)[::-1])
    code, _, err = run_cli(capsys, "localize", other, "--db", db, "--json", out, "-q")
    assert code == 0, err
    assert "run the map was made from" not in err
    recs = json.loads(out.read_text())["observations"]
    assert len(recs) == 12 and recs[0]["place"] == "3" and recs[-1]["place"] == "0"


def test_track_json_lines_uses_learns_calibration(rooms, tmp_path, capsys):
    train, db, out = tmp_path / "train.jsonl", tmp_path / "l.sqlite", tmp_path / "t.json"
    code, _, err = run_cli(capsys, "map", rooms, "--db", tmp_path / "m.sqlite", "--json", train, "--no-calibration")
    assert code == 0, err
    code, _, err = run_cli(capsys, "learn", train, "--db", db)
    assert code == 0 and "likelihood scale beta" in err
    from fingerloc.map.database import read_map_info

    beta = read_map_info(db).calibration["beta"]
    code, _, err = run_cli(capsys, "track", train, "--db", db, "--json", out, "-q")
    assert code == 0, err
    assert json.loads(out.read_text())["summary"]["likelihood_scale"] == pytest.approx(beta)


def test_bag_flags():
    from fingerloc.cli.options import bag_options

    assert bag_options(["/front"], "odom:/wheel", None) == {"topic": "/front", "pose_source": "odom:/wheel", "base_frame": None}
    assert bag_options(None, "tf:map", None)["pose_source"] == "tf:map"
    with pytest.raises(InvalidParameterError, match="--pose-source"):
        bag_options(None, "gps", None)
    assert bag_options(["/front", "/back"], "tf", "base_footprint")["topic"] == ("/front", "/back")
    assert bag_options(None, "auto", None)["topic"] is None


def test_map_and_pose_track_on_a_bag_with_two_lidars_back_to_back(tmp_path, capsys):
    """Front lidar + upside-down back lidar merged into one 360 deg observation per step."""
    from fingerloc.map.database import load_model

    from ._bags import bag_path, write_robot_bag

    def loop(t):  # two laps of a 1.6 m circle around the room's centre, 20 s a lap, facing along the path
        a = 2 * math.pi * (t - 10.0) / 20.0
        return (4.0 + 1.6 * math.cos(a), 3.0 + 1.6 * math.sin(a), a + math.pi / 2)

    front = tuple(10.0 + 0.5 * k for k in range(81))
    back = tuple(t + 0.02 for t in front)
    bag = write_robot_bag(bag_path(tmp_path, False, "loop"), False, front_stamps=front, back_stamps=back, pose=loop)
    db, t = tmp_path / "m.sqlite", tmp_path / "t.json"
    topics = ["--topic", "/scan_front", "--topic", "/scan_back"]
    code, _, err = run_cli(capsys, "map", bag, "--db", db, *topics, "--no-calibration")
    assert code == 0, err
    model = load_model(db)
    # the first lap (40 scans, 10 m) makes a place every 2 m: brute force on the true positions
    centres: list[tuple[float, float]] = []
    for tt in front[:40]:
        x, y, _ = loop(tt)
        if all(math.hypot(x - cx, y - cy) > 2.0 for cx, cy in centres):
            centres.append((x, y))
    assert len(model.classes_) == len(centres)
    views = [o for p in model.places_.values() for o in p.observations]
    assert views and all(o.full_fov for o in views)  # both lidars in every stored view
    code, _, err = run_cli(capsys, "track", bag, "--db", db, *topics, "--filter", "pose", "--json", t, "-q")
    assert code == 0, err
    s = json.loads(t.read_text())["summary"]
    assert s["steps"] == 41 and s["filtered"]["labelled"] > 20
