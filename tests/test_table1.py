"""Tests of the Table I experiment and of ``fingerloc reproduce table1``."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fingerloc.errors import InvalidParameterError
from fingerloc.experiments.table1 import (
    DEFAULT_N_EDGES,
    PAPER_K,
    PAPER_N,
    PAPER_TABLE1,
    make_observations,
    make_places,
    run_table1,
)
from fingerloc.mog import fit_mixtures

from ._cli import run_cli as run


def test_paper_table_is_the_papers():
    assert PAPER_K == (3, 4, 5) and PAPER_N == (5, 10, 15, 20, 25, 30, 35)
    tab = np.asarray(PAPER_TABLE1)
    assert tab.shape == (3, 7)
    assert tab[0, 0] == 55.5 and tab[2, 6] == 100.0 and tab[1, 3] == 95.0


def test_generator_shapes_and_alikeness():
    rng = np.random.default_rng(0)
    places = make_places(rng, 10, DEFAULT_N_EDGES, 10.0)
    assert places.shape == (10, DEFAULT_N_EDGES)
    # one shared layout: each edge's spread across places is about the place spread, not uniform
    spread = np.rad2deg(places.std(axis=0))
    assert np.all(spread < 25.0)
    obs = make_observations(rng, places, 4, 35, 5.0)
    assert obs.shape == (10, 4, 35)
    # every feature lies near one of its own place's edges
    d = np.abs(np.angle(np.exp(1j * (obs[..., None] - places[:, None, None, :])))).min(axis=-1)
    assert np.rad2deg(d).max() < 5.0 * 6
    identical = make_places(np.random.default_rng(1), 3, 4, 0.0)
    assert np.all(identical == identical[0])


def test_run_table1_format_and_determinism():
    a = run_table1(trials=2, seed=3, ks=(3, 5), ns=(5, 20))
    b = run_table1(trials=2, seed=3, ks=(3, 5), ns=(5, 20))
    np.testing.assert_array_equal(a.per_trial, b.per_trial)
    assert a.per_trial.shape == (2, 2, 2)
    assert np.all((a.accuracy >= 0) & (a.accuracy <= 1))
    assert a.stderr.shape == (2, 2)
    paper = a.paper()
    assert paper is not None
    np.testing.assert_allclose(paper, [[0.555, 0.935], [0.80, 0.995]])
    js = a.to_json()
    assert js["k"] == [3, 5] and js["N"] == [5, 20] and js["trials"] == 2
    assert np.asarray(js["accuracy"]).shape == (2, 2) and np.asarray(js["stderr"]).shape == (2, 2)
    json.dumps(js)  # JSON-ready
    assert run_table1(trials=1, ks=(3,), ns=(6,)).paper() is None


def test_alikeness_controls_accuracy():
    far = run_table1(trials=2, seed=0, ks=(4,), ns=(10,), place_spread_deg=180.0).accuracy[0, 0]
    near = run_table1(trials=2, seed=0, ks=(4,), ns=(10,), place_spread_deg=2.0).accuracy[0, 0]
    assert far > 0.95
    assert near < far - 0.2


def test_bad_parameters():
    with pytest.raises(InvalidParameterError, match="trials"):
        run_table1(trials=0)
    with pytest.raises(InvalidParameterError, match="ks"):
        run_table1(trials=1, ks=())
    with pytest.raises(InvalidParameterError, match="place_spread_deg"):
        run_table1(trials=1, place_spread_deg=-1.0)
    with pytest.raises(InvalidParameterError, match="observation_model"):
        run_table1(trials=1, observation_model="bogus")
    with pytest.raises(InvalidParameterError, match="evaluation"):
        run_table1(trials=1, evaluation="bogus")


def test_held_out_is_harder_than_resubstitution():
    # identical places: with itself in its place's training data an observation is found far above chance;
    # held out, only chance (10 %) is left
    kw = {"trials": 3, "seed": 1, "ks": (5,), "ns": (5,), "place_spread_deg": 0.0}
    resub = run_table1(**kw).accuracy[0, 0]
    held = run_table1(evaluation="held-out", **kw).accuracy[0, 0]
    assert resub > 0.5
    assert held < 0.3
    assert run_table1(evaluation="held-out", **kw).to_json()["evaluation"] == "held-out"


def test_held_out_scoring_matches_plain_loops():
    # replay run_table1's random draws, then score every observation with plain loops
    seed, n_places, n_obs, n, k = 5, 10, 4, 10, 3
    r = run_table1(trials=1, seed=seed, ks=(k,), ns=(n,), evaluation="held-out", place_spread_deg=20.0)
    rng = np.random.default_rng(seed)
    places = make_places(rng, n_places, DEFAULT_N_EDGES, 20.0)
    obs = make_observations(rng, places, n_obs, n, 5.0)
    samples = [obs[p].ravel() for p in range(n_places)]
    samples += [np.delete(obs[p], o, axis=0).ravel() for p in range(n_places) for o in range(n_obs)]
    fit = fit_mixtures(samples, k, random_state=rng)
    right = 0
    for p in range(n_places):
        for o in range(n_obs):
            scores = []
            for q in range(n_places):
                m = n_places + p * n_obs + o if q == p else q
                scores.append(fit.log_density(obs[p, o])[m].sum())
            right += int(np.argmax(scores) == p)
    assert r.accuracy[0, 0] == pytest.approx(right / (n_places * n_obs))


def test_fixed_observation_model():
    r = run_table1(trials=1, seed=0, ks=(3,), ns=(5, 35), observation_model="fixed")
    assert r.per_trial.shape == (1, 1, 2)
    assert r.to_json()["observation_model"] == "fixed"


def test_cli_reproduce_table1(tmp_path, capsys):
    out_json = tmp_path / "t1.json"
    code, out, err = run(capsys, "reproduce", "table1", "--trials", "2", "--seed", "1", "--json", str(out_json))
    assert code == 0, err
    assert "Table I" in out and "paper" in out and "55.5" in out
    data = json.loads(out_json.read_text())
    assert data["k"] == [3, 4, 5] and data["N"] == [5, 10, 15, 20, 25, 30, 35]
    acc = np.asarray(data["accuracy"])
    assert acc.shape == (3, 7) and np.all((acc >= 0) & (acc <= 1))
    assert np.asarray(data["stderr"]).shape == (3, 7)
    assert data["paper"][0][0] == pytest.approx(0.555)


def test_cli_reproduce_table1_bad_input(capsys):
    code, _, _ = run(capsys, "reproduce", "table1", "--trials", "0")
    assert code == 2


def test_cli_defaults_match_the_experiment():
    from fingerloc.cli import mog as cli_mog
    from fingerloc.experiments import table1

    assert cli_mog.PLACE_SPREAD_DEG == table1.DEFAULT_PLACE_SPREAD_DEG
    assert cli_mog.N_EDGES == table1.DEFAULT_N_EDGES
