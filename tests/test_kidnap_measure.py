"""What ``bench kidnap`` measures: recovery against a never-kidnapped run, its floor, and the ground truth.

Scripted filters whose answers are known step by step, so that every figure
of a trial can be written down by hand.
"""

from __future__ import annotations

import numpy as np
import pytest

from fingerloc.experiments.kidnap import KidnapResult, TrackingData, _settles, kidnap_experiment
from fingerloc.map.filter import FilterResult

P = 3
N = 100
STRETCH = 20
TRUTH_CELL = (np.arange(N) // 10) % P  # the true place (Voronoi cell) of every step
OBSERVED = np.arange(N) % 5 == 0  # a query every fifth step


def _result(best):
    lp = np.full((len(best), P), np.log(0.05))
    lp[np.arange(len(best)), best] = np.log(0.9)
    return FilterResult.from_log_posterior(lp)


class _Scripted(TrackingData):
    """A filter whose never-kidnapped runs and kidnapped runs answer as scripted.

    Reference (first never-kidnapped run): the true cell everywhere. Later
    never-kidnapped runs: the same but another place at every step ``= 2
    (mod 5)`` (between queries). A kidnapped run: on its second stretch,
    another place for the first ``wrong`` steps, then the reference's answers.
    """

    __slots__ = ("calls", "wrong")

    def run(self, idx=None):  # type: ignore[override]
        if idx is None:
            self.calls += 1
            best = TRUTH_CELL.copy()
            if self.calls > 1:
                noisy = np.arange(N) % 5 == 2
                best[noisy] = (best[noisy] + 1) % P
            return _result(best)
        idx = np.asarray(idx)
        best = TRUTH_CELL[idx].copy()
        best[STRETCH : STRETCH + self.wrong] = (best[STRETCH : STRETCH + self.wrong] + 1) % P
        return _result(best)


def _scripted(wrong: int) -> _Scripted:
    truth = np.where(OBSERVED, TRUTH_CELL, -1)
    pos = np.column_stack([np.arange(N) * 1.0, np.zeros(N)])
    d = _Scripted(None, np.zeros((N, P)), np.ones(N), truth, pos, None, cells=TRUTH_CELL.copy())  # type: ignore[arg-type]
    d.calls, d.wrong = 0, wrong
    return d


def test_settles_is_the_first_step_after_the_last_disagreement():
    assert _settles([True, True]) == 0
    assert _settles([False, True, False, True, True]) == 3
    assert _settles([True, False]) is None  # the last step disagrees: never
    # only the masked steps count
    assert _settles([False, False, True, False, True], [True, False, True, False, True]) == 1
    # unconfirmed, a stretch whose only observation is wrong settles after it; confirmed, it never does
    assert _settles([True, False, True, True], [False, True, False, False]) == 2
    assert _settles([True, False, True, True], [False, True, False, False], confirmed=True) is None
    assert _settles([True, True, True], [False, True, False], confirmed=True) == 0


def test_kidnap_figures_of_a_scripted_filter():
    """Wrong for 7 steps after the jump; a second unkidnapped run that differs between queries at steps 2 (mod 5)."""
    res = kidnap_experiment(_scripted(7), n_trials=5, stretch=STRETCH, min_jump_m=10.0, min_queries=4)
    assert len(res.trials) == 5
    for t in res.trials:
        assert t["b_start"] % 5 == 0  # B starts at a query
        assert t["recover_steps"] == 7
        assert t["recover_observed_steps"] == 6  # queries at 0 and 5 wrong, 10 and 15 right
        assert t["recover_truth_steps"] == 6 and t["reference_recover_truth_steps"] == 0
        assert t["recover_cell_steps"] == 7 and t["reference_recover_cell_steps"] == 0
        assert (t["observed"], t["right"], t["reference_right"]) == (4, 2, 4)
        # the floor: the second run last disagrees at step 17 of the stretch, never at a query
        assert t["floor_recover_steps"] == 18 and t["floor_recover_observed_steps"] == 0
        assert t["floor_disagreement"] == pytest.approx(4 / 20)
    s = res.summary()
    assert s["within_10"] == 1.0 and s["observed_within_10"] == 1.0
    assert s["floor_within_10"] == 0.0 and s["floor_observed_within_10"] == 1.0
    assert s["floor_median_steps"] == 18.0 and s["floor_disagreement"] == pytest.approx(0.2)
    assert s["truth_within_10"] == 1.0 and s["reference_truth_within_10"] == 1.0
    assert s["cell_within_10"] == 1.0 and s["cell_median_steps"] == 7.0
    assert s["kidnapped_top1"] == pytest.approx(0.5) and s["reference_top1"] == 1.0


def test_a_filter_that_never_recovers_is_not_counted():
    """Wrong through the whole second stretch: no recovery on any column, top-1 0 after the kidnapping."""
    res = kidnap_experiment(_scripted(STRETCH), n_trials=3, stretch=STRETCH, min_jump_m=10.0, min_queries=4)
    s = res.summary()
    assert s["within_10"] == 0.0 and s["observed_within_10"] == 0.0
    assert s["truth_within_10"] == 0.0 and s["cell_within_10"] == 0.0
    assert s["kidnapped_top1"] == 0.0
    assert s["reference_truth_within_10"] == 1.0  # the reference is right throughout


def test_old_trials_without_the_new_fields_summarise():
    """A trial recorded before the floor and truth fields existed: the new summary fields are None."""
    t = {"recover_steps": 3, "recover_observed_steps": 2, "merge_steps": None, "recover_observations": 1,
         "merge_observations": None, "first_right_steps": 0, "reference_first_right_steps": 0}  # fmt: skip
    s = KidnapResult("old", [t]).summary()
    assert s["within_10"] == 1.0 and s["floor_within_10"] is None and s["kidnapped_top1"] is None


def test_a_deterministic_filter_has_no_floor():
    """The discrete filter over places answers the same twice: the floor is 0 steps on every trial."""
    from ._chain import chain_data

    res = kidnap_experiment(chain_data(), name="chain", n_trials=6, stretch=20, min_jump_m=20.0)
    for t in res.trials:
        assert t["floor_recover_steps"] == 0 and t["floor_disagreement"] == 0.0
    assert res.summary()["floor_within_10"] == 1.0
