"""PlaceModel(temper=True): one factor on the summed log-likelihoods, fit on held-out folds of the training views."""

from __future__ import annotations

import numpy as np

from fingerloc.experiments.panorama import calibration
from fingerloc.map.database import load_model, save_model
from fingerloc.model import PlaceModel
from fingerloc.observation import Observation


def _views(seed: int, places: int = 8, per: int = 6) -> list[Observation]:
    """Appearance descriptors and column profiles of noisy places."""
    rng = np.random.default_rng(seed)
    centres = rng.random((places, 12))
    out = []
    for j in range(places):
        for _ in range(per):
            a = np.abs(centres[j] + rng.normal(0, 0.35, 12))
            prof = np.tile(a[None, :4], (8, 1))  # the same numbers again, as a profile that does not turn
            out.append(Observation(appearance=a, profile=prof, label=f"p{j}"))
    return out


def test_tempering_undoes_a_threefold_count_of_one_term_and_keeps_the_answers(tmp_path):
    """A weight of 3 on a calibrated term makes the posterior overconfident: the factor comes out near 1/3."""
    train, test = _views(0), _views(1)
    loud = {"A": 3.0, "AP": 0.0}
    plain = PlaceModel(terms=("A", "AP"), weights=loud).fit(train)
    temp = PlaceModel(terms=("A", "AP"), weights=loud, temper=True).fit(train)
    assert 0.5 < 3.0 * temp.temper_ < 1.5 and plain.__dict__.get("temper_", 1.0) == 1.0
    assert np.array_equal(plain.predict(test), temp.predict(test))
    truth = np.array([plain.column_of(o.label) for o in test])
    before = calibration(plain.predict_log_proba(test), truth)
    after = calibration(temp.predict_log_proba(test), truth)
    assert after["mean_confidence"] < before["mean_confidence"]
    assert after["ece"] < before["ece"]
    # kept by the place database
    db = tmp_path / "places.sqlite"
    save_model(temp, db)
    back = load_model(db)
    assert back.temper_ == temp.temper_ and np.allclose(back.predict_log_proba(test), temp.predict_log_proba(test))
