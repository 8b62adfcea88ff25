"""Property and fuzz tests of every reader of user input.

Each reader either succeeds or raises the library's error for bad input
(``DataFormatError``, ``DatabaseError``); the command line either succeeds
or prints one line ``error: ...`` and exits with 2. Nothing else.
"""

from __future__ import annotations

import json
import shutil
import sqlite3
import uuid

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fingerloc.errors import DatabaseError, DataFormatError
from fingerloc.io.carmen import iter_laser, parse_line
from fingerloc.io.jsonl import observation_from_record, parse_record, read_observations

from ._cli import run_cli
from .conftest import fuzz_examples

_json_scalars = st.none() | st.booleans() | st.integers() | st.floats() | st.text(max_size=8)
_json = st.recursive(
    _json_scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=12,
)
_keys = st.sampled_from(["VE", "CP", "Ex", "c", "B", "W", "Q", "bearing", "hue", "length", "range"])
_feature_values = st.lists(
    st.floats(allow_nan=True) | st.integers() | st.dictionaries(_keys, _json_scalars, max_size=3) | st.text(max_size=3),
    max_size=4,
)
_records = st.fixed_dictionaries(
    {},
    optional={
        "features": st.dictionaries(_keys, _feature_values, max_size=4) | _json,
        "place": st.none() | st.text(max_size=6) | st.integers(),
        "pose": st.lists(st.floats() | st.integers(), max_size=4) | _json,
        "fov": st.lists(st.lists(st.floats() | st.integers(), max_size=3), max_size=3) | _json,
        "timestamp": st.floats() | st.integers() | st.text(max_size=3),
        "scan": st.fixed_dictionaries(
            {"bearings": st.lists(st.floats(), max_size=4), "ranges": st.lists(st.none() | st.floats(), max_size=4)}
        )
        | _json,
    },
)


@settings(max_examples=fuzz_examples(300))
@given(record=_records | _json)
def test_observation_records_fuzz(record):
    try:
        obs = observation_from_record(record)
    except DataFormatError:
        return
    assert obs.ve.size == len(record["features"].get("VE", []))  # every bearing kept, none invented


@settings(max_examples=fuzz_examples(300))
@given(text=st.text(alphabet=st.sampled_from(list('{}[]",:0123456789.-eE tnrufalsNI\\u')), max_size=60))
def test_json_lines_text_fuzz(text):
    try:
        parse_record(text)
    except DataFormatError:
        pass


@settings(max_examples=fuzz_examples(60), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(lines=st.lists(st.text(max_size=40) | st.binary(max_size=40).map(lambda b: b.decode("latin-1")), max_size=5))
def test_json_lines_file_fuzz(tmp_path, lines):
    p = tmp_path / f"{uuid.uuid4().hex}.jsonl"
    p.write_text("\n".join(lines), encoding="utf-8", errors="surrogatepass")
    try:
        read_observations(p)
    except DataFormatError:
        pass


_tokens = st.sampled_from(
    ["FLASER", "RLASER", "ROBOTLASER1", "ROBOTLASER2", "ODOM", "PARAM", "#", "3", "2", "0", "-1", "1e308", "nan",
     "inf", "x", "0.5", "181", "100000000000000000000", "host"]
)  # fmt: skip


@settings(max_examples=fuzz_examples(400))
@given(parts=st.lists(_tokens | st.text(max_size=5), max_size=30))
def test_carmen_line_fuzz(parts):
    try:
        parse_line(" ".join(parts), line=1)
    except DataFormatError:
        pass


@settings(max_examples=fuzz_examples(40), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    lines=st.lists(st.lists(_tokens, min_size=1, max_size=12).map(" ".join), max_size=6),
    skip_bad=st.booleans(),
)
def test_carmen_file_fuzz(tmp_path, lines, skip_bad):
    p = tmp_path / f"{uuid.uuid4().hex}.log"
    good = "FLASER 3 1.0 2.0 3.0 0 0 0 0 0 0 1.0 host 1.0"
    p.write_text("\n".join([good, *lines]) + "\n", encoding="utf-8")
    try:
        for _ in iter_laser(p, skip_bad=skip_bad):
            pass
    except DataFormatError:
        pass


@pytest.fixture(scope="module")
def learned_db(tmp_path_factory):
    from fingerloc.map.database import save_model
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation

    obs, labels = [], []
    for k, lab in enumerate("abc"):
        for j in range(3):
            obs.append(Observation.from_degrees({"VE": [10 + 90 * k + 3 * j, 150 + 40 * k, 300.0], "c": [45.0 + k]}))
            labels.append(lab)
    db = tmp_path_factory.mktemp("fuzzdb") / "p.sqlite"
    save_model(PlaceModel(2).fit(obs, labels), db, graph_edges={("a", "b"): 2})
    return db, obs


_COLUMNS = {
    "places": ["id", "label", "medoid", "consensus_letters", "consensus_bearings"],
    "observations": ["place_id", "idx", "data", "source"],
    "fingerprints": ["obs_id", "letters", "bearings"],
    "mixtures": ["place_id", "term", "weights", "means", "sigmas"],
    "graph_edges": ["src", "dst", "count"],
    "meta": ["value"],
}
_values = (
    st.none()
    | st.integers(-(2**63), 2**63 - 1)
    | st.floats()
    | st.text(max_size=8)
    | st.binary(max_size=24)
    | st.sampled_from(["[]", "{}", '{"a": 1}', "[1, 2]", "nan", "VE", "a", "vnnc"])
)


@settings(max_examples=fuzz_examples(60), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    table=st.sampled_from(sorted(_COLUMNS)),
    data=st.data(),
    value=_values,
    rowid=st.integers(1, 12),
    delete=st.booleans(),
)
def test_database_loader_fuzz(tmp_path, learned_db, table, data, value, rowid, delete):
    from fingerloc.map.database import load_model, read_graph_edges

    src, obs = learned_db
    db = tmp_path / f"{uuid.uuid4().hex}.sqlite"
    shutil.copyfile(src, db)
    column = data.draw(st.sampled_from(_COLUMNS[table]))
    with sqlite3.connect(db) as con:
        try:
            if delete:
                con.execute(f"DELETE FROM {table} WHERE rowid = ?", (rowid,))
            else:
                con.execute(f"UPDATE {table} SET {column} = ? WHERE rowid = ?", (value, rowid))
        except sqlite3.IntegrityError:
            return
    con.close()
    try:
        model = load_model(db)
        read_graph_edges(db)
    except DatabaseError:
        return
    post = model.predict_proba(obs[:2])  # what loads, works
    assert post.shape == (2, len(model.classes_))


@settings(max_examples=fuzz_examples(40), suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    option=st.sampled_from(["--empty-step-deg", "--merge-tol-deg", "--json", "--bogus"]),
    value=st.sampled_from(["0", "-1", "1e-9", "1e309", "nan", "inf", "-inf", "20", "x", "", "[red]x", "5"])
    | st.floats().map(repr),
)
def test_cli_options_fuzz(tmp_path, capsys, option, value):
    p = tmp_path / "d.jsonl"
    if not p.exists():
        p.write_text(json.dumps({"features": {"VE": [10, 100, 200], "c": [50]}}) + "\n")
    args = ["fingerprint", p, option] + ([] if option == "--json" else [value])
    code, out, err = run_cli(capsys, *args)
    assert code in (0, 2)
    if code == 2:
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error: ")
    else:
        assert out.strip()
