import numpy as np
import pytest

from fingerloc.errors import DatabaseError, InvalidParameterError
from fingerloc.map.graph import PlaceGraph, load_graph, nearest_place_sequence


def test_from_sequence_counts_stays_and_moves():
    g = PlaceGraph.from_sequence(["a", "b", "c"], ["a", "a", "b", "b", "b", "c", "b"])
    assert g.edges() == {("a", "a"): 1, ("a", "b"): 1, ("b", "b"): 2, ("b", "c"): 1, ("c", "b"): 1}
    c = g.count_matrix()
    assert c.tolist() == [[1, 1, 0], [0, 2, 1], [0, 1, 0]]
    assert g.stay_fraction() == pytest.approx(3 / 6)


def test_from_sequence_none_breaks_the_chain():
    g = PlaceGraph.from_sequence(["a", "b"], ["a", None, "b", "b"])
    assert g.edges() == {("b", "b"): 1}


def test_count_matrix_in_another_order():
    g = PlaceGraph.from_sequence(["a", "b"], ["a", "b"])
    assert g.count_matrix(["b", "a"]).tolist() == [[0, 0], [1, 0]]
    with pytest.raises(InvalidParameterError, match="each of the graph"):
        g.count_matrix(["a"])


def test_adjacency_symmetric_and_directed():
    g = PlaceGraph.from_edges({("a", "b"): 3, ("b", "b"): 2}, places=["a", "b", "c"])
    assert g.adjacency().tolist() == [[False, True, False], [True, False, False], [False, False, False]]
    assert g.adjacency(symmetric=False).tolist() == [[False, True, False], [False, False, False], [False, False, False]]


def test_from_plain_adjacency_has_zero_counts():
    g = PlaceGraph.from_edges([("x", "y"), ("y", "z")])
    assert g.places == ["x", "y", "z"]
    assert g.edges() == {("x", "y"): 0, ("y", "z"): 0}
    assert np.isnan(g.stay_fraction())


def test_bad_edges_rejected():
    with pytest.raises(InvalidParameterError, match="unknown place 'q'"):
        PlaceGraph(["a"], {("a", "q"): 1})
    with pytest.raises(InvalidParameterError, match="integer >= 0"):
        PlaceGraph(["a"], {("a", "a"): -1})
    with pytest.raises(InvalidParameterError, match="repeat"):
        PlaceGraph(["a", "a"])


def test_nearest_place_sequence():
    pos = [[0, 0], [0.9, 0], [1.6, 0], [10, 10]]
    c = [[0, 0], [2, 0]]
    assert nearest_place_sequence(pos, c).tolist() == [0, 0, 1, 1]
    assert nearest_place_sequence(pos, c, radius=1.0).tolist() == [0, 0, 1, -1]
    # ties go to the lower index
    assert nearest_place_sequence([[1, 0]], c).tolist() == [0]


def test_database_round_trip(tmp_path):
    from fingerloc.map.database import save_model
    from fingerloc.model import PlaceModel
    from fingerloc.observation import Observation

    obs = [Observation.from_degrees({"VE": [10.0 * k, 100.0 + 7 * k]}, label=lab) for k, lab in enumerate("aabbcc")]
    model = PlaceModel(n_components=1, terms=("VE",)).fit(obs)
    g = PlaceGraph.from_sequence(list(model.classes_), ["a", "a", "b", "c", "b"])
    path = tmp_path / "p.sqlite"
    save_model(model, path, graph_edges=g.edges())
    back = load_graph(path)
    assert back.places == ["a", "b", "c"]
    assert back.edges() == g.edges()
    save_model(model, path, graph_edges={("a", "zz"): 1})
    with pytest.raises(DatabaseError, match="zz"):
        load_graph(path)
