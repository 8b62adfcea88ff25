import json
import sqlite3
from types import SimpleNamespace

import numpy as np
import pytest

from fingerloc.errors import DatabaseError
from fingerloc.io import write_observations
from fingerloc.map.database import load_model, read_graph_edges, save_model
from fingerloc.model import PlaceModel

from ._cli import run_cli
from ._places import dataset


def test_roundtrip_identical_predictions(tmp_path):
    obs, labels = dataset()
    from fingerloc.align import CostModel

    for kw in (
        {},
        {"fp_reference": "consensus", "fp_likelihood": "exp"},
        {"terms": ("VE", "Ex")},
        {"costs": CostModel.feature_aware(), "cyclic": True, "unknown_prior": 0.1, "outlier_weight": 0.01},
    ):
        model = PlaceModel(3, **kw).fit(obs, labels)
        path = tmp_path / "p.sqlite"
        size = save_model(model, path, graph_edges={("a", "b"): 3})
        assert size == path.stat().st_size > 0
        again = load_model(path)
        test, _ = dataset(seed=7, n=2)
        np.testing.assert_array_equal(again.predict_log_proba(test), model.predict_log_proba(test))
        assert list(again.classes_) == list(model.classes_)
        assert again.get_params()["terms"] == list(model.terms)
        assert read_graph_edges(path) == {("a", "b"): 3}


def test_save_is_atomic(tmp_path, monkeypatch):
    obs, labels = dataset(n=2)
    path = tmp_path / "p.sqlite"
    save_model(PlaceModel(2).fit(obs, labels), path)
    good = path.read_bytes()

    def boom(*a, **k):
        raise RuntimeError("crash mid-write")

    monkeypatch.setattr("fingerloc.map.database.encode_observation", boom)
    with pytest.raises(RuntimeError):
        save_model(PlaceModel(3).fit(obs, labels), path)
    assert path.read_bytes() == good
    assert sorted(p.name for p in tmp_path.iterdir()) == ["p.sqlite", "p.sqlite.lock"]  # the writers' lock stays
    load_model(path)


def test_bad_files(tmp_path):
    obs, labels = dataset(n=2)
    path = tmp_path / "p.sqlite"
    save_model(PlaceModel(2).fit(obs, labels), path)
    data = path.read_bytes()
    trunc = tmp_path / "trunc.sqlite"
    trunc.write_bytes(data[: len(data) // 2])
    text = tmp_path / "text.sqlite"
    text.write_text("hello, not a database\n" * 100)
    foreign = tmp_path / "foreign.sqlite"
    con = sqlite3.connect(foreign)
    con.execute("CREATE TABLE t(x)")
    con.commit()
    con.close()
    newer = tmp_path / "newer.sqlite"
    newer.write_bytes(data)
    con = sqlite3.connect(newer)
    con.execute("UPDATE meta SET value='99' WHERE key='schema_version'")
    con.commit()
    con.close()
    for p, match in ((trunc, "trunc.sqlite"), (text, "text.sqlite"), (foreign, "not a fingerloc"),
                     (newer, "version '99'"), (tmp_path / "none.sqlite", "no such")):
        with pytest.raises(DatabaseError, match=match):
            load_model(p)


@pytest.fixture
def cli(capsys):
    """``fingerloc ARGS...`` in-process: ``.returncode``, ``.stdout``, ``.stderr``."""

    def run(*args):
        code, out, err = run_cli(capsys, *args)
        return SimpleNamespace(returncode=code, stdout=out, stderr=err)

    return run


def test_cli_learn_localize_places(tmp_path, cli):
    obs, labels = dataset()
    train = tmp_path / "train.jsonl"
    write_observations(train, [o.with_label(lab) for o, lab in zip(obs, labels, strict=True)])
    db = tmp_path / "places.sqlite"
    r = cli("learn", str(train), "--db", str(db), "-k", "3", "--preset", "paper")
    assert r.returncode == 0, r.stderr
    test, tl = dataset(seed=11, n=2)
    qfile = tmp_path / "q.jsonl"
    write_observations(qfile, [o.with_label(lab) for o, lab in zip(test, tl, strict=True)])
    out = tmp_path / "out.json"
    r = cli("localize", str(qfile), "--db", str(db), "--json", str(out))
    assert r.returncode == 0, r.stderr
    assert "right classification" in r.stdout
    res = json.loads(out.read_text())
    ranks = [r["rank_of_true"] for r in res["observations"]]
    assert res["summary"]["n"] == 6 and res["summary"]["top1"] == pytest.approx(sum(r == 1 for r in ranks) / 6)
    rec = res["observations"][0]
    assert set(rec) >= {"index", "place", "best", "posterior", "rank_of_true", "terms", "heading_deg"}
    assert abs(sum(rec["posterior"].values()) - 1) < 1e-9
    assert set(rec["terms"]) == {"VE", "CP", "Ex", "B", "Fp"}
    r = cli("places", "--db", str(db))
    assert r.returncode == 0 and "a" in r.stdout
    # the file order gave the place graph: 5 stays in each place, a->b and b->c once
    edges = read_graph_edges(db)
    assert edges[("a", "a")] == 5 and edges[("a", "b")] == 1 and edges[("b", "c")] == 1
    # extending with a different option is an error
    r = cli("learn", str(train), "--db", str(db), "-k", "4")
    assert r.returncode == 2 and "--components 3" in r.stderr  # the flag, not the parameter


def test_cli_bad_database_exit_2(tmp_path, cli):
    q = tmp_path / "q.jsonl"
    q.write_text('{"features": {"VE": [1]}}\n')
    bad = tmp_path / "bad.sqlite"
    bad.write_text("not sqlite at all " * 200)
    obs, labels = dataset(n=2)
    good = tmp_path / "good.sqlite"
    save_model(PlaceModel(2).fit(obs, labels), good)
    trunc = tmp_path / "trunc.sqlite"
    trunc.write_bytes(good.read_bytes()[:3000])
    for db in (bad, trunc):
        r = cli("localize", str(q), "--db", str(db))
        assert r.returncode == 2
        lines = r.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ") and db.name in lines[0]


def test_cli_learn_weights(tmp_path, cli):
    obs, labels = dataset()
    train = tmp_path / "train.jsonl"
    write_observations(train, [o.with_label(lab) for o, lab in zip(obs, labels, strict=True)])
    db = tmp_path / "fit.sqlite"
    r = cli("learn", str(train), "--db", str(db), "-k", "2", "--terms", "VE,Ex,Fp", "--weights", "fit")
    assert r.returncode == 0, r.stderr
    m = load_model(db)
    assert m.weights == "fit" and set(m.weights_) == {"VE", "Ex", "Fp"}
    db2 = tmp_path / "fixed.sqlite"
    r = cli("learn", str(train), "--db", str(db2), "-k", "2", "--weights", "VE=0.5, Fp=2")
    assert r.returncode == 0, r.stderr
    assert load_model(db2).weights == {"VE": 0.5, "Fp": 2.0}
    for bad in ("VE", "VE=-1", "VE=x", "fitted"):
        r = cli("learn", str(train), "--db", str(tmp_path / "x.sqlite"), "--weights", bad)
        assert r.returncode == 2 and r.stderr.startswith("error:"), (bad, r.stderr)


def test_localize_streams_in_chunks_with_the_same_answers(tmp_path, cli, monkeypatch):
    import fingerloc.cli._localize as localize_chunks  # localize imports LOCALIZE_CHUNK from here when it runs

    obs, labels = dataset()
    train = tmp_path / "train.jsonl"
    write_observations(train, [o.with_label(lab) for o, lab in zip(obs, labels, strict=True)])
    db = tmp_path / "p.sqlite"
    assert cli("learn", str(train), "--db", str(db), "-k", "2", "--preset", "paper").returncode == 0
    test, tl = dataset(seed=12, n=3)
    q = tmp_path / "q.jsonl"
    write_observations(q, [o.with_label(lab) for o, lab in zip(test, tl, strict=True)])
    whole, parts = tmp_path / "whole.json", tmp_path / "parts.json"
    assert cli("localize", str(q), "--db", str(db), "--json", str(whole), "-q").returncode == 0
    monkeypatch.setattr(localize_chunks, "LOCALIZE_CHUNK", 2)  # 9 observations in 5 chunks
    assert cli("localize", str(q), "--db", str(db), "--json", str(parts), "-q").returncode == 0
    a, b = json.loads(whole.read_text()), json.loads(parts.read_text())
    assert a == b and [r["index"] for r in b["observations"]] == list(range(9))
