"""Exact retrieval (fingerloc.retrieval.PlaceIndex) against the linear scan over every place."""

import itertools
import math
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from fingerloc.errors import InvalidParameterError
from fingerloc.features.laser import observation_from_scan
from fingerloc.io.carmen import iter_scans
from fingerloc.model import normalise_log
from fingerloc.observation import Observation
from fingerloc.pipeline.presets import resolve_preset
from fingerloc.retrieval import PlaceIndex, place_layout
from fingerloc.sim.campus import campus_observations

from .features_world import CARMEN_DIR

SHARED_LOGS = Path(os.environ.get("FINGERLOC_CARMEN_DIR", str(CARMEN_DIR)))


def linear_top(joint, k):
    """The k best columns of one row of joint log-likelihoods, ties by column (as argmax)."""
    return np.lexsort((np.arange(joint.size), -joint))[:k]


def check_same_as_linear(model, index, queries, *, k, tol=None):
    """Same k best places, bit-identical joints, and (with tol) posteriors within tol of the linear scan's."""
    res = index.search(queries, k=k, tol=tol)
    joint = model.joint_log_likelihood(queries)
    logp = normalise_log(joint)
    kk = min(k, joint.shape[1])
    for i in range(len(queries)):
        top = linear_top(joint[i], kk)
        np.testing.assert_array_equal(res.places[i], top)
        np.testing.assert_array_equal(res.joint[i], joint[i, top])
        if tol is not None:
            assert res.mass_bound[i] <= tol
            # every probability within tol of the linear scan's (absolute)
            np.testing.assert_allclose(np.exp(res.log_posterior[i]), np.exp(logp[i, top]), rtol=0, atol=tol)
    return res


@pytest.fixture(scope="module")
def campus():
    train, queries = campus_observations(60, n_queries=1, seed=7)
    model = resolve_preset("laser2d").model().fit(train)
    return model, queries


@pytest.fixture(scope="module")
def indexes(campus):
    model, _ = campus
    return {g: PlaceIndex(model, group_views=g) for g in (3, 8, 64)}


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    which=st.lists(st.integers(0, 59), min_size=1, max_size=4),
    k=st.integers(1, 12),
    group=st.sampled_from([3, 8, 64]),
    tol=st.sampled_from([None, 1e-9, 1e-3, 0.1]),
)
def test_index_gives_the_linear_scans_best_places_on_a_campus(campus, indexes, which, k, group, tol):
    model, queries = campus
    check_same_as_linear(model, indexes[group], [queries[i] for i in which], k=k, tol=tol)


def _random_view(rng, label=None):
    """A laser view of random features: corners, extremities, walls and a range profile, full circle."""
    n = lambda hi: int(rng.integers(0, hi))  # noqa: E731
    nw = n(6)
    beams = 360
    return Observation(
        c=rng.uniform(0, 2 * math.pi, n(6)),
        ex=rng.uniform(0, 2 * math.pi, n(6)),
        b=rng.uniform(0, 2 * math.pi, n(2)),
        w=rng.uniform(0, 2 * math.pi, nw),
        w_length=rng.uniform(0.3, 6.0, nw),
        w_range=rng.uniform(0.5, 8.0, nw),
        ranges=rng.uniform(0.3, 12.0, beams),
        range_bearings=np.linspace(0, 2 * math.pi, beams, endpoint=False),
        label=label,
    )


@settings(max_examples=8, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n_places=st.integers(2, 40), k=st.integers(1, 6), group=st.sampled_from([2, 5, 64]))
def test_index_gives_the_linear_scans_best_places_on_random_views(seed, n_places, k, group):
    rng = np.random.default_rng(seed)
    train = [_random_view(rng, f"p{j}") for j in range(n_places) for _ in range(int(rng.integers(1, 4)))]
    model = resolve_preset("laser2d").model().fit(train)
    queries = [_random_view(rng) for _ in range(3)] + [train[int(rng.integers(len(train)))]]
    check_same_as_linear(model, PlaceIndex(model, group_views=group), queries, k=k, tol=1e-9)


def test_index_scores_few_places_when_the_answer_is_clear(campus, indexes):
    """The point of the index: on most queries whole groups are skipped (here at least a third of the places)."""
    model, queries = campus
    res = indexes[8].search(queries[:40], k=5)
    assert np.median(res.scored) < 2 * len(model.classes_) / 3


def test_rank_of_truth_is_the_linear_rank(campus, indexes):
    model, queries = campus
    q = queries[:15]
    res = indexes[8].search(q, k=3, truth=[o.label for o in q])
    np.testing.assert_array_equal(res.rank_of_truth, model.rank_of(q))


@pytest.mark.slow
def test_the_paper_program_is_exact_too():
    """Mixture terms have no bound of their own: scored in full, the fingerprint term still bounded."""
    train, queries = campus_observations(40, camera=True, random_heading=False, seed=3)
    model = resolve_preset("paper").model().fit(train)
    check_same_as_linear(model, PlaceIndex(model, group_views=8), queries[:10], k=4, tol=1e-9)


def test_layout_groups_every_place_once_within_the_view_budget():
    rng = np.random.default_rng(0)
    views = rng.integers(1, 5, 500)
    lay = place_layout(rng.normal(size=(500, 3)), views, group_views=16)
    np.testing.assert_array_equal(np.sort(lay.order), np.arange(500))
    per_group = np.add.reduceat(views[lay.order], lay.starts[:-1])
    assert per_group.max() <= 16
    assert lay.starts[-1] == 500


def test_search_rejects_bad_arguments(campus, indexes):
    _, queries = campus
    with pytest.raises(InvalidParameterError):
        indexes[8].search(queries[:1], k=0)
    with pytest.raises(InvalidParameterError):
        indexes[8].search(queries[:1], tol=-1.0)
    with pytest.raises(InvalidParameterError):
        indexes[8].search(queries[:2], truth=["place-0"])


@pytest.mark.slow
@pytest.mark.skipif(not SHARED_LOGS.is_dir(), reason="shared CARMEN logs not available")
@pytest.mark.parametrize("name", ["intel-corrected.log.gz", "aces-corrected.log.gz"])
def test_index_gives_the_linear_scans_best_places_on_a_real_log(name):
    """Scans of a real log, labelled by the 2 m cell of their pose: half the views learn, the other half query."""
    scans = list(itertools.islice(iter_scans(SHARED_LOGS / name, messages=("FLASER",)), 0, 1500, 3))
    obs = [observation_from_scan(s, label="cell-{}-{}".format(*np.floor(np.asarray(s.pose[:2]) / 2.0).astype(int))) for s in scans]
    model = resolve_preset("laser2d").model().fit(obs[0::2])
    assert len(model.classes_) > 40
    queries = [o for o in obs[1::2] if o.label in set(model.classes_)][:40]
    index = PlaceIndex(model, group_views=16)
    res = check_same_as_linear(model, index, queries, k=5)
    check_same_as_linear(model, index, queries[:10], k=5, tol=1e-9)
    assert res.scored.mean() < len(model.classes_)


def test_localize_answers_through_the_index_are_those_of_the_full_scan(campus, monkeypatch):
    """answer_chunk (the localize command's table and summary) gives the same rows, ranks and headings either way."""
    from fingerloc import retrieval
    from fingerloc.pipeline.localize import answer_chunk

    model, queries = campus
    q = [*queries[:12], queries[12].with_label(None)]
    names = [f"q{i}" for i in range(len(q))]
    monkeypatch.setattr(retrieval, "INDEX_MIN_PLACES", 10**9)
    assert retrieval.index_for(model) is None
    full = answer_chunk(model, q, names, 5, 4, table=True, records=False)
    monkeypatch.setattr(retrieval, "INDEX_MIN_PLACES", 2)
    assert retrieval.index_for(model) is not None
    fast = answer_chunk(model, q, names, 5, 4, table=True, records=False)
    assert fast.rows == full.rows
    assert fast.rank_of_true == full.rank_of_true
    assert fast.pairs == full.pairs


def test_index_for_leaves_small_and_unbounded_models_to_the_full_scan(campus):
    from fingerloc.retrieval import index_for

    model, _ = campus
    assert index_for(model) is None  # 60 places: below the threshold
    assert index_for(model, min_places=2) is index_for(model, min_places=2)  # built once
    train, _ = campus_observations(12, camera=True, random_heading=False, seed=3)
    paper = resolve_preset("paper").model().fit(train)
    assert index_for(paper, min_places=2) is None  # mixture terms have no bounds
