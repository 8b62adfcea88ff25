"""PlaceModel as a combination of terms: scikit-learn conformance, labels, state, headings, parameter errors."""

import math
import re

import numpy as np
import pytest

from fingerloc import Observation
from fingerloc.errors import FingerlocError, InvalidParameterError
from fingerloc.map import load_model, save_model
from fingerloc.model import PlaceModel
from fingerloc.mog import AngularMixture
from fingerloc.terms import FingerprintTerm, MixtureTerm, RangeTerm

from ._places import dataset

sklearn_base = pytest.importorskip("sklearn.base", reason="scikit-learn is in the test extra")


@pytest.mark.parametrize(
    "est",
    [
        PlaceModel(3, terms=["VE", "Fp"], weights={"VE": 0.5}, cyclic=True),
        PlaceModel(),
        AngularMixture(4, tol=1e-4, random_state=np.random.default_rng(1)),
    ],
)
def test_sklearn_clone_gives_an_equal_unfitted_estimator(est):
    c = sklearn_base.clone(est)
    assert type(c) is type(est) and c is not est
    for name, value in est.get_params().items():
        other = c.get_params()[name]
        if isinstance(value, np.random.Generator):
            assert isinstance(other, np.random.Generator)
        else:
            assert other == value, name
    assert not hasattr(c, "terms_") and not hasattr(c, "weights_")


def test_constructor_stores_arguments_untouched():
    terms, weights = ["VE", "Fp"], {"VE": 0.5}
    m = PlaceModel(terms=terms, weights=weights)
    assert m.terms is terms and m.weights is weights
    assert m.get_params(deep=True)["terms"] is terms


def test_set_params_and_repr():
    m = PlaceModel().set_params(n_components=2, cyclic=True)
    assert (m.n_components, m.cyclic) == (2, True)
    assert repr(m) == "PlaceModel(n_components=2, cyclic=True)"
    with pytest.raises(InvalidParameterError, match="no parameter 'k'"):
        m.set_params(k=3)


def test_integer_labels_round_trip_through_fit_predict_and_the_database(tmp_path):
    obs, labels = dataset(seed=2)
    ints = [{"a": 1, "b": 2, "c": 30}[x] for x in labels]
    m = PlaceModel(3).fit(obs, ints)
    assert list(m.classes_) == [1, 2, 30] and all(type(c) is int for c in m.classes_)
    pred = m.predict(obs)
    assert all(type(p) is int for p in pred)
    assert m.score(obs, ints) == pytest.approx(np.mean(pred == np.array(ints, dtype=object)))
    save_model(m, tmp_path / "p.sqlite")
    back = load_model(tmp_path / "p.sqlite")
    assert list(back.classes_) == [1, 2, 30] and all(type(c) is int for c in back.classes_)
    np.testing.assert_allclose(back.predict_log_proba(obs), m.predict_log_proba(obs), atol=1e-9)


def test_state_round_trip_gives_the_same_posterior():
    obs, labels = dataset(seed=3)
    for params in ({}, {"fp_likelihood": "exp", "fp_reference": "consensus", "unknown_prior": 0.1}):
        m = PlaceModel(3, **params).fit(obs, labels)
        back = PlaceModel.from_state(m.to_state())
        np.testing.assert_array_equal(back.predict_log_proba(obs), m.predict_log_proba(obs))
        np.testing.assert_array_equal(back.predict_unknown_proba(obs), m.predict_unknown_proba(obs))


@pytest.mark.parametrize(
    ("params", "name"),
    [
        ({"unknown_prior": "x"}, "unknown_prior"),
        ({"weights": {"VE": "a"}}, "weights"),
        ({"n_components": 2.5}, "n_components"),
        ({"terms": "VE"}, "terms"),
        ({"cyclic": "yes"}, "cyclic"),
        ({"rotate_mixtures": True, "terms": ("VE",)}, "rotate_mixtures"),
        ({"fov_grid": 10}, "fov_grid"),
    ],
)
def test_bad_parameters_are_fingerloc_errors_naming_the_parameter(params, name):
    obs, labels = dataset(n=2)
    with pytest.raises(InvalidParameterError, match=name) as info:
        PlaceModel(**params).fit(obs, labels)
    assert "\n" not in str(info.value)


def test_predict_on_something_that_is_not_an_observation():
    obs, labels = dataset(n=2)
    m = PlaceModel(2).fit(obs, labels)
    with pytest.raises(FingerlocError, match=r"observations\[0\] must be an Observation"):
        m.predict(["abc"])


def test_each_term_alone_matches_the_model_column_for_column():
    obs, labels = dataset(seed=4)
    m = PlaceModel(3, terms=("VE", "Ex", "Fp")).fit(obs, labels)
    groups = [p.observations for p in m.places_.values()]
    fp = FingerprintTerm().fit(groups)
    np.testing.assert_array_equal(fp.log_likelihood(obs), m.term_log_likelihoods(obs)["Fp"])
    # a mixture term fit alone draws its own initialisation: same shape, same ranking of the truth
    ve = MixtureTerm("VE", n_components=3).fit(groups)
    assert ve.log_likelihood(obs).shape == (len(obs), 3)


def _ring(rng, base_deg, turn_deg=0.0, noise=2.0, label=None):
    ve = np.asarray(base_deg, dtype=float) + turn_deg + rng.normal(0, noise, len(base_deg))
    return Observation.from_degrees({"VE": ve.tolist(), "c": ve.tolist()}, label=label)


def test_rotate_mixtures_scores_a_turned_view_as_if_it_were_not_turned():
    rng = np.random.default_rng(5)
    bases = {"a": [0, 40, 150, 250], "b": [10, 100, 190, 280, 330], "c": [60, 70, 200]}
    train = [_ring(rng, b, label=k) for k, b in bases.items() for _ in range(5)]
    plain = PlaceModel(3, terms=("VE", "Fp"), cyclic=True).fit(train)
    turned = PlaceModel(3, terms=("VE", "Fp"), cyclic=True, rotate_mixtures=True).fit(train)
    q = _ring(np.random.default_rng(6), bases["a"], turn_deg=0.0)
    q_turned = q.rotated(math.radians(95.0))
    h = turned.headings([q_turned], ["a"])[0]  # degrees, from the string alignment
    assert abs(h - 95.0) < 3.0
    # oracle: the turned view is scored exactly as the straight view turned by the heading's error
    ll_turned = turned.term_log_likelihoods([q_turned])["VE"][0, 0]
    ll_oracle = plain.term_log_likelihoods([q.rotated(math.radians(95.0 - h))])["VE"][0, 0]
    assert ll_turned == pytest.approx(ll_oracle, rel=1e-9)
    # without rotation the turned view is far less likely at its own place
    assert plain.term_log_likelihoods([q_turned])["VE"][0, 0] < ll_turned - 10


def test_range_term_state_keeps_descriptors_not_scans():
    rng = np.random.default_rng(7)
    bearings = np.linspace(-np.pi / 2, np.pi / 2, 181)
    groups = [
        [Observation(ranges=rng.uniform(lo, lo + 1.0, 181), range_bearings=bearings) for _ in range(3)]
        for lo in (1.0, 4.0)
    ]
    t = RangeTerm().fit(groups)
    st = t.to_state()
    assert [d.shape for d in st["descriptors"]] == [(3, t.bins().size + 1)] * 2
    back = RangeTerm().set_state(st, [[Observation()] * 3] * 2)  # scans not needed once descriptors are stored
    q = [o for g in groups for o in g]
    np.testing.assert_array_equal(back.log_likelihood(q), t.log_likelihood(q))
    assert np.argmax(t.log_likelihood(q), axis=1).tolist() == [0, 0, 0, 1, 1, 1]


def test_range_term_grows_a_place_without_its_old_scans():
    rng = np.random.default_rng(8)
    bearings = np.linspace(-np.pi / 2, np.pi / 2, 91)

    def scan(lo):
        return Observation(ranges=rng.uniform(lo, lo + 1.0, 91), range_bearings=bearings)

    groups = [[scan(1.0), scan(1.0)], [scan(5.0)]]
    full = RangeTerm().fit(groups)
    # a term restored from descriptors only (the old views carry no ranges any more) ...
    stripped = [[Observation() for _ in g] for g in groups]
    restored = RangeTerm().set_state(full.to_state(), stripped)
    extra = scan(5.0)
    full.update([groups[0], [*groups[1], extra]], [1])
    restored.update([stripped[0], [*stripped[1], extra]], [1])
    # ... grows exactly as the term that still has every scan
    for a, b in zip(full.descriptors_, restored.descriptors_, strict=True):
        np.testing.assert_array_equal(a, b)
    assert restored.descriptors_[1].shape[0] == 2


def test_filters_refuse_bad_parameters_with_fingerloc_errors():
    from fingerloc.map.filter import TransitionModel
    from fingerloc.map.pose_filter import PoseFilter

    with pytest.raises(InvalidParameterError, match="random_state"):
        PoseFilter(np.zeros((2, 2)), 1.0, random_state="x")
    with pytest.raises(InvalidParameterError, match="n_places must be an integer"):
        TransitionModel.uniform(2.5)


def test_database_keeps_range_descriptors_not_scans(tmp_path):
    import sqlite3

    rng = np.random.default_rng(9)
    bearings = np.linspace(-np.pi / 2, np.pi / 2, 361)
    obs = [
        Observation(c=np.array([0.3 * k]), ranges=rng.uniform(lo, lo + 2.0, 361), range_bearings=bearings, label=lab)
        for k, (lab, lo) in enumerate([("a", 1.0)] * 3 + [("b", 4.0)] * 3)
    ]
    m = PlaceModel(terms=("Fp", "R"), fp_likelihood="exp").fit(obs)
    db = tmp_path / "r.sqlite"
    save_model(m, db)
    from fingerloc.map._records import decode_observation

    with sqlite3.connect(db) as con:
        records = [decode_observation(r) for (r,) in con.execute("SELECT data FROM observations")]
        encodings = {e for (e,) in con.execute("SELECT encoding FROM range_descriptors")}
    assert records and not any(r.ranges is not None for r in records)
    assert encodings <= {"|u1", "<u2"}  # beam counts, not float64 descriptors
    back = load_model(db)
    np.testing.assert_array_equal(back.term_log_likelihoods(obs)["R"], m.term_log_likelihoods(obs)["R"])
    # the stored model still grows: a new view of "b" adds its descriptor to the stored ones
    back.add_places([obs[-1]])
    assert back.terms_["R"].descriptors_[1].shape[0] == 4


@pytest.mark.parametrize(
    ("features", "needle"),
    [
        ({"CP": [{"bearing": 1}]}, "lacks 'hue'"),
        ({"CP": [[1]]}, "list of 2 numbers"),
        ({"W": [[1, 2]]}, "list of 3 numbers"),
        ({"W": [{"bearing": 1, "length": 2}]}, "lacks 'range'"),
        ({"VE": ["a"]}, "features['VE'] must be a list of numbers"),
    ],
)
def test_from_degrees_refuses_malformed_entries(features, needle):
    with pytest.raises(InvalidParameterError, match=re.escape(needle)) as info:
        Observation.from_degrees(features)
    assert "\n" not in str(info.value)
