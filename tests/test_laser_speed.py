"""The 2D-laser preset at speed: the answers of the plain code, and the ``laser`` bench section.

``tests/data/laser2d_golden.json`` holds the answers of the code before the
compiled kernels on a small simulated case: the extracted features of every
scan, the query fingerprints, every term's log-likelihoods, the posterior and
the headings of ``localize`` (the function that wrote it:
``laser2d_golden_values`` below). Every value must come back, within the last
bits a numpy / numba build may change (``tests/_golden.py``).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fingerloc.align import cyclic_alignment
from fingerloc.experiments.speed_laser import laser_figures, laser_places, localize_answers
from fingerloc.pipeline.presets import resolve_preset

from ._golden import assert_close

GOLDEN = Path(__file__).parent / "data" / "laser2d_golden.json"


def _features(o: Any) -> dict[str, list[float]]:
    return {k: [float(x) for x in getattr(o, k)] for k in ("c", "ex", "b", "w", "w_length", "w_range")}


def laser2d_golden_values() -> dict[str, Any]:
    """The golden file's content, computed by the code at hand."""
    d = laser_places(6, n_train=2, seed=7)
    tr = d.observations(d.train, d.train_labels)
    q = d.observations(d.queries, d.query_labels)
    m = resolve_preset("laser2d").model().fit(tr, d.train_labels)
    qq = q + tr[::3]
    a = localize_answers(m, qq)
    fp = m.terms_["Fp"]
    return {
        "features_train": [_features(o) for o in tr],
        "features_queries": [_features(o) for o in q],
        "fingerprints": [[f.letters, [float(x) for x in f.bearings]] for f in (fp.fingerprint(o) for o in qq)],
        "terms": {k: v.tolist() for k, v in a["terms"].items()},
        "log_posterior": a["log_posterior"].tolist(),
        "headings": [None if np.isnan(h) else float(h) for h in a["headings"]],
        "refs": a["refs"].tolist(),
        "lambdas": {k: float(t.lambda_) for k, t in m.terms_.items()},
    }


@pytest.fixture(scope="module")
def golden_now() -> dict[str, Any]:
    return laser2d_golden_values()


def test_golden_file_is_the_reference():
    g = json.loads(GOLDEN.read_text())
    assert len(g["features_train"]) == 12 and len(g["log_posterior"]) == 10
    assert any(f["c"] for f in g["features_train"]) and any(f["ex"] for f in g["features_train"])


@pytest.mark.parametrize("key", ["features_train", "features_queries", "fingerprints", "lambdas"])
def test_laser2d_features_and_fingerprints_unchanged(golden_now, key):
    assert_close(golden_now[key], json.loads(GOLDEN.read_text())[key], where=key)


def test_laser2d_localize_answers_unchanged(golden_now):
    g = json.loads(GOLDEN.read_text())
    for key in ("terms", "log_posterior", "headings", "refs"):
        assert_close(golden_now[key], g[key], where=key)


def test_laser_section_small():
    figs = laser_figures(n_places=3, n_train=2, n_queries=2, chunk=3, repeat=1)
    assert figs["places"] == 3 and figs["references"] == 6 and figs["beams"] == 1081
    for key in ("extract_cpu_ms", "term_Fp_cpu_ms", "term_R_cpu_ms", "localize_cpu_ms", "localize_with_extraction_ms"):
        assert math.isfinite(figs[key]) and figs[key] > 0, key
    assert figs["localize_with_extraction_cpu_ms"] >= figs["extract_cpu_ms"] * 0.5
    assert 0.0 <= figs["top1"] <= 1.0 and 1.0 <= figs["mean_rank"] <= 3.0


@pytest.mark.parametrize("align_each", [0, 8])  # the few views of a place: in one batch first, or each aligned once
def test_localize_answers_match_the_model(align_each, monkeypatch):
    import fingerloc.terms.fingerprint as fpmod

    monkeypatch.setattr(fpmod, "_ALIGN_EACH", align_each)
    d = laser_places(3, n_train=2, seed=3)
    tr = d.observations(d.train, d.train_labels)
    m = resolve_preset("laser2d").model().fit(tr, d.train_labels)
    q = d.observations(d.queries)
    a = localize_answers(m, q)
    np.testing.assert_array_equal(a["log_posterior"], m.predict_log_proba(q))
    h, refs = m.headings_with_reference(q, [m.classes_[j] for j in a["best"]])
    np.testing.assert_array_equal(a["headings"], h)
    np.testing.assert_array_equal(a["refs"], refs)
    # without the latest batch's costs at hand (other objects): the same headings, views and costs
    fresh = [o.with_label(o.label) for o in q]
    assert m.terms_["Fp"]._query(fresh[0])[1] is None
    h2, refs2 = m.headings_with_reference(fresh, [m.classes_[j] for j in a["best"]])
    np.testing.assert_array_equal(h2, h)
    np.testing.assert_array_equal(refs2, refs)
    for o in fresh:  # every view of every place, aligned one by one as before
        for j in range(len(m.classes_)):
            fp = m.terms_["Fp"]
            costs = [cyclic_alignment(fp.fingerprint(o), f, costs=fp.costs) for f in fp.fingerprints_[j]]
            v = min(range(len(costs)), key=lambda k: (costs[k].cost, k))
            assert fp.heading_at(o, j) == (costs[v].heading_deg, v)
