import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from rapidfuzz.distance import Levenshtein
from scipy.special import erf, logsumexp

from fingerloc import Observation, make_fingerprint
from fingerloc.errors import InvalidParameterError, NotFittedError
from fingerloc.model import PlaceModel, consensus_fingerprint, rank_scores
from fingerloc.model import normalise_log as _normalise

from ._places import BASES, dataset, office


def spec_log_mog(x, w, m, s):
    """log p_MOG(x) written directly from SPEC.md §3 (scipy erf)."""
    terms = []
    for wk, mk, sk in zip(w, m, s, strict=True):
        if wk == 0:
            continue
        d = (x - mk + math.pi) % (2 * math.pi) - math.pi
        eta = 1.0 / (math.sqrt(2 * math.pi) * sk * erf(math.pi / (math.sqrt(2) * sk)))
        # w * eta * exp(-d^2 / (2 sigma^2)), summed in log space (far bearings underflow)
        terms.append(math.log(wk * eta) - d**2 / (2 * sk**2))
    return float(logsumexp(terms))


def test_two_place_example_reproduces_spec():
    rng = np.random.default_rng(1)
    obs = [office(rng, BASES["a"]) for _ in range(4)] + [office(rng, BASES["b"]) for _ in range(4)]
    labels = ["a"] * 4 + ["b"] * 4
    model = PlaceModel(3, terms=("VE", "Ex", "Fp")).fit(obs, labels)
    q = office(rng, BASES["a"], noise=6.0)
    # by hand: uniform prior, product of mixture densities, 1 / (Levenshtein + 1)
    fq = make_fingerprint(q).letters
    joint = []
    for lab in ("a", "b"):
        j = model.column_of(lab)
        lp = 0.0
        for term in ("VE", "Ex"):
            w, m, s = model.terms_[term].mixtures_[j]
            lp += sum(spec_log_mog(x, w, m, s) for x in q.bearings(term))
        cost = min(Levenshtein.distance(fq, fp.letters) for fp in model.terms_["Fp"].fingerprints_[j])
        lp += math.log(1.0 / (cost + 1.0))
        joint.append(lp + math.log(0.5))
    expected = np.exp(np.array(joint) - logsumexp(joint))
    got = model.predict_proba([q])[0]
    assert list(model.classes_) == ["a", "b"]
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-12)


def test_injected_parameters_exact():
    # one component per place, known parameters: the posterior of SPEC §4 in closed form
    obs, labels = dataset(n=2)
    model = PlaceModel(1, terms=("VE",)).fit(obs, labels)
    params = {"a": (0.0, 0.3), "b": (1.0, 0.5), "c": (-2.0, 1.0)}
    mixtures = [[np.array([1.0]), np.array([mu]), np.array([sig])] for mu, sig in params.values()]
    model.terms_["VE"].set_state({"mixtures": mixtures}, [p.observations for p in model.places_.values()])
    q = Observation(ve=np.array([0.2, 0.5]))
    ll = np.array([sum(spec_log_mog(x, [1.0], [mu], [sig]) for x in q.ve) for mu, sig in params.values()])
    np.testing.assert_allclose(model.predict_log_proba([q])[0], ll - logsumexp(ll), rtol=1e-10)


def test_rows_sum_to_one_and_shift_invariance():
    obs, labels = dataset()
    model = PlaceModel(3).fit(obs, labels)
    p = model.predict_proba(obs)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, rtol=1e-12)
    joint = sum(model.term_log_likelihoods(obs).values())
    np.testing.assert_allclose(_normalise(joint + 123.4), _normalise(joint), atol=1e-9)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1e6, 1e6), min_size=1, max_size=8), st.floats(-1e3, 1e3))
def test_normalise_property(row, shift):
    a = np.array([row])
    out = np.exp(_normalise(a))
    assert np.isclose(out.sum(), 1.0)
    np.testing.assert_allclose(np.exp(_normalise(a + shift)), out, atol=1e-9)


def test_classifies_and_ranks():
    obs, labels = dataset(seed=2)
    model = PlaceModel(3).fit(obs, labels)
    test, tlabels = dataset(seed=3, n=3)
    assert model.score(test, tlabels) >= 0.9
    ranks = model.rank(test)
    assert ranks.shape == (len(test), 3)
    assert sorted(ranks[0]) == [1, 2, 3]
    assert np.all(model.rank_of(test, tlabels) >= 1)
    assert list(model.predict(test)).count("a") >= 2


def test_rank_ties_count_against():
    r = rank_scores(np.array([[0.0, 0.0, -1.0], [3.0, 1.0, 2.0]]))
    assert r.tolist() == [[2, 2, 3], [1, 3, 2]]


def test_no_nan_edge_cases():
    obs, labels = dataset(n=3)
    # place "c" has no beacons at all; a place with no training bearings of a type
    model = PlaceModel(5, n_init=1).fit(obs, labels)
    assert model.terms_["B"].mixtures_[model.column_of("c")] is None
    cases = [
        Observation(),  # no features at all
        Observation.from_degrees({"B": [10, 20, 30]}),  # only a type "c" never saw
        Observation.from_degrees({"VE": [10], "Ex": [200]}, fov=[[-30, 30]]),  # narrow fov
        Observation.from_degrees({"VE": [0, 0, 0, 0, 0, 0]}),
    ]
    p = model.predict_proba(cases)
    assert np.all(np.isfinite(p))
    np.testing.assert_allclose(p.sum(axis=1), 1.0)
    # empty observation: every term uninformative except Fp
    mog_only = PlaceModel(3, terms=("VE", "Ex")).fit(obs, labels)
    np.testing.assert_allclose(mog_only.predict_proba([Observation()])[0], 1 / 3)


def test_more_components_than_bearings():
    obs = [Observation.from_degrees({"VE": [10]}, label="x"), Observation.from_degrees({"VE": [200, 210]}, label="y")]
    model = PlaceModel(5, terms=("VE",)).fit(obs)
    assert model.predict([Observation.from_degrees({"VE": [12]})])[0] == "x"
    assert np.all(np.isfinite(model.predict_log_proba(obs)))


def test_terms_and_weights():
    obs, labels = dataset()
    full = PlaceModel(3).fit(obs, labels)
    tl = full.term_log_likelihoods(obs[:2])
    assert set(tl) == {"VE", "CP", "Ex", "B", "Fp"}
    ve = PlaceModel(3, terms=("VE",)).fit(obs, labels)
    np.testing.assert_allclose(ve.predict_log_proba(obs[:2]), _normalise(ve.term_log_likelihoods(obs[:2])["VE"]))
    w = PlaceModel(3, terms=("VE", "Ex"), weights={"VE": 0.0}).fit(obs, labels)
    np.testing.assert_allclose(w.predict_log_proba(obs[:2]), _normalise(w.term_log_likelihoods(obs[:2])["Ex"]))


def test_a_term_of_weight_zero_is_not_computed_for_the_posterior(monkeypatch):
    """Its log-likelihoods add nothing: the posterior does not ask for them (an infinite one would give 0 * inf), the same bits."""
    obs, labels = dataset()
    w = PlaceModel(3, terms=("VE", "Ex"), weights={"VE": 0.0}).fit(obs, labels)
    want = w.predict_log_proba(obs[:3])
    assert np.array_equal(want, _normalise(w.term_log_likelihoods(obs[:3])["Ex"]))

    def refuse(*args, **kwargs):
        raise AssertionError("a term of weight 0 was computed")

    monkeypatch.setattr(w.terms_["VE"], "log_likelihood", refuse)
    assert np.array_equal(w.predict_log_proba(obs[:3]), want)
    everything = PlaceModel(3, terms=("VE", "Ex"), weights={"VE": 0.0, "Ex": 0.0}).fit(obs, labels)
    assert np.array_equal(everything.predict_log_proba(obs[:3]), np.full((3, len(everything.classes_)), -np.log(len(everything.classes_))))


def test_fp_exp_and_references():
    obs, labels = dataset(seed=4, noise=6.0)
    exp = PlaceModel(3, terms=("Fp",), fp_likelihood="exp").fit(obs, labels)
    assert 1e-3 <= exp.fp_lambda_ <= 1e4
    np.testing.assert_allclose(
        exp.term_log_likelihoods(obs[:3])["Fp"], -exp.fp_lambda_ * exp.terms_["Fp"].distances(obs[:3])
    )
    for ref in ("medoid", "consensus"):
        m = PlaceModel(3, terms=("Fp",), fp_reference=ref).fit(obs, labels)
        assert m.score(obs, labels) >= 0.6
        assert m.terms_["Fp"].distances(obs[:1]).shape == (1, 3)


def test_consensus_not_worse_than_medoid():
    obs, _ = dataset(seed=5, noise=8.0)
    fps = [make_fingerprint(o) for o in obs[:6]]
    cons = consensus_fingerprint(fps)

    def total(s):
        return sum(Levenshtein.distance(s, f.letters) for f in fps)

    assert total(cons.letters) <= min(total(f.letters) for f in fps)


def test_add_places_does_not_refit_others():
    obs, labels = dataset()
    first = [(o, lab) for o, lab in zip(obs, labels, strict=True) if lab != "c"]
    model = PlaceModel(3).fit([o for o, _ in first], [lab for _, lab in first])
    before = {
        lab: {t: tuple(a.copy() for a in model.terms_[t].mixtures_[j]) for t in ("VE", "Ex") if model.terms_[t].mixtures_[j]}
        for j, lab in enumerate(model.classes_)
    }
    model.add_places([o for o, lab in zip(obs, labels, strict=True) if lab == "c"], ["c"] * 6)
    assert list(model.classes_) == ["a", "b", "c"]
    for lab, mix in before.items():
        for t, arrays in mix.items():
            for x, y in zip(arrays, model.terms_[t].mixtures_[model.column_of(lab)], strict=True):
                np.testing.assert_array_equal(x, y)


def test_unknown_place():
    obs, labels = dataset()
    model = PlaceModel(3, unknown_prior=0.1).fit(obs, labels)
    rng = np.random.default_rng(9)
    known = model.predict_unknown_proba(obs)
    strange = [Observation.from_degrees({"VE": list(rng.uniform(0, 360, 7)), "c": list(rng.uniform(0, 360, 9))})
               for _ in range(5)]
    unknown = model.predict_unknown_proba(strange)
    assert np.all((known >= 0) & (known <= 1))
    assert np.median(known) < 0.5 < np.median(unknown)
    assert np.all(PlaceModel(3).fit(obs, labels).predict_unknown_proba(obs) == 0)


def test_errors():
    obs, labels = dataset(n=2)
    with pytest.raises(NotFittedError):
        PlaceModel().predict(obs)
    with pytest.raises(InvalidParameterError, match="unknown term 'XX'"):
        PlaceModel(terms=("XX",)).fit(obs, labels)
    with pytest.raises(InvalidParameterError, match="n_components"):
        PlaceModel(0).fit(obs, labels)
    with pytest.raises(InvalidParameterError, match="fp_likelihood"):
        PlaceModel(fp_likelihood="nope").fit(obs, labels)  # type: ignore[arg-type]
    with pytest.raises(InvalidParameterError, match="no place label"):
        PlaceModel().fit([Observation()])
    with pytest.raises(InvalidParameterError, match="one label per observation"):
        PlaceModel().fit(obs, labels[:-1])


def _noisy_ex_dataset(seed, n=8):
    """Three places whose VE bearings are their own (5 deg noise) and whose Ex bearings are pure noise."""
    rng = np.random.default_rng(seed)
    obs, labels = [], []
    for lab, base in BASES.items():
        for _ in range(n):
            ve = (np.asarray(base["VE"]) + rng.normal(0, 5.0, len(base["VE"]))).tolist()
            ex = rng.uniform(0, 360, 6).tolist()
            obs.append(Observation.from_degrees({"VE": ve, "Ex": ex}))
            labels.append(lab)
    return obs, labels


def test_fitted_weights_trust_the_informative_term():
    obs, labels = _noisy_ex_dataset(0)
    m = PlaceModel(2, terms=("VE", "Ex"), weights="fit").fit(obs, labels)
    assert set(m.weights_) == {"VE", "Ex"}
    assert m.weights_["Ex"] < 0.25 * m.weights_["VE"]
    # held-out views: the fitted weights give the right place more probability than weights of 1
    test, tl = _noisy_ex_dataset(1, n=10)
    ones = PlaceModel(2, terms=("VE", "Ex")).fit(obs, labels)
    col = {c: j for j, c in enumerate(m.classes_)}
    y = np.array([col[t] for t in tl])
    lp_fit = m.predict_log_proba(test)[np.arange(y.size), y].mean()
    lp_one = ones.predict_log_proba(test)[np.arange(y.size), y].mean()
    assert lp_fit > lp_one
    assert m.get_params()["weights"] == "fit"


def test_fitted_weights_edge_cases_and_errors():
    obs, labels = dataset(n=1)  # one view a place: no held-out rows, every weight 1
    m = PlaceModel(2, terms=("VE", "Ex"), weights="fit").fit(obs, labels)
    assert m.weights_ == {"VE": 1.0, "Ex": 1.0}
    with pytest.raises(InvalidParameterError, match="fit"):
        PlaceModel(2, weights="learn").fit(obs, labels)  # type: ignore[arg-type]


def test_fitted_weights_survive_the_database(tmp_path):
    from fingerloc.map.database import load_model, save_model

    obs, labels = _noisy_ex_dataset(2)
    m = PlaceModel(2, terms=("VE", "Ex"), weights="fit").fit(obs, labels)
    save_model(m, tmp_path / "p.sqlite")
    back = load_model(tmp_path / "p.sqlite")
    assert back.weights == "fit" and back.weights_ == pytest.approx(m.weights_)
    np.testing.assert_allclose(back.predict_log_proba(obs[:5]), m.predict_log_proba(obs[:5]))


@settings(max_examples=200, deadline=None)
@given(
    rows=st.lists(
        st.lists(
            st.one_of(
                st.floats(-800, 50, allow_nan=False),
                st.sampled_from([-np.inf, 0.0, -1.5, 3.25, -745.5, 709.0]),
            ),
            min_size=1,
            max_size=12,
        ).filter(lambda r: any(math.isfinite(x) for x in r)),
        min_size=1,
        max_size=4,
    ).filter(lambda rows: len({len(r) for r in rows}) == 1),
)
def test_row_logsumexp_equals_scipy_bit_for_bit(rows):
    from fingerloc._lse import logsumexp_rows

    a = np.array(rows, dtype=np.float64)
    np.testing.assert_array_equal(logsumexp_rows(a), logsumexp(a, axis=1, keepdims=True))


def test_row_logsumexp_ties_and_wide_rows():
    from fingerloc._lse import logsumexp_rows

    rng = np.random.default_rng(4)
    a = np.round(rng.normal(-50, 30, (5, 1000)), 1)  # many tied maxima after rounding
    a[1, ::7] = -np.inf
    a[2, :] = -3.0
    for x in (a, np.ascontiguousarray(a[:, :999])):
        np.testing.assert_array_equal(logsumexp_rows(x), logsumexp(x, axis=1, keepdims=True))
    assert not np.array_equal(logsumexp_rows(a)[0], np.log(np.exp(a[0]).sum()))  # the test can tell them apart
