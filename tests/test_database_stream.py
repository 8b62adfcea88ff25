"""A place database's observation rows are read and decoded a chunk at a time: the same model, the same refusals."""

from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from fingerloc import PlaceModel
from fingerloc.errors import DatabaseError
from fingerloc.map import database
from fingerloc.map.database import load_model, save_model

from ._places import dataset


def _saved(tmp_path):
    obs, labels = dataset(seed=4, n=7)
    model = PlaceModel(terms=("Fp", "VE", "Ex")).fit(obs, labels)
    save_model(model, tmp_path / "m.sqlite")
    return tmp_path / "m.sqlite", obs


@pytest.mark.parametrize("chunk", [1, 4, 7, 1000])
def test_chunked_loading_gives_the_whole_loads_model(tmp_path, monkeypatch, chunk):
    path, obs = _saved(tmp_path)
    whole = load_model(path)
    monkeypatch.setattr(database, "LOAD_CHUNK_ROWS", chunk)
    database._VERIFIED.clear()
    part = load_model(path)
    assert list(part.places_) == list(whole.places_)
    for lab in whole.places_:
        assert part.places_[lab].observations == whole.places_[lab].observations
    np.testing.assert_array_equal(part.predict_log_proba(obs), whole.predict_log_proba(obs))


def test_a_damaged_row_in_a_later_chunk_is_refused_with_its_place(tmp_path, monkeypatch):
    path, _ = _saved(tmp_path)
    with sqlite3.connect(path) as con:
        last = con.execute("SELECT max(id) FROM observations").fetchone()[0]
        con.execute("UPDATE observations SET data = ? WHERE id = ?", (b"\x01\x00" + bytes(8), last))
        con.execute("UPDATE meta SET value = '4' WHERE key = 'schema_version'")  # no digests: the record check speaks
    monkeypatch.setattr(database, "LOAD_CHUNK_ROWS", 2)
    with pytest.raises(DatabaseError, match=r"m\.sqlite: place '.*': corrupt observation record"):
        load_model(path)
