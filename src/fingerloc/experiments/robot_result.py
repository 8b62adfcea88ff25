"""Figures of many simulated trials of the robot experiment, and their JSON (see :mod:`fingerloc.experiments.robot`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .._types import FArray
from .robot_eval import CI_LEVEL, TrialEvaluation, t_interval, wilson_interval
from .robot_sim import PAPER_TABLE2, PAPER_TABLE3, PAPER_TABLE4, TABLE2_TYPES, WORLD_PROFILES, RobotProtocol

__all__ = ["RobotResult"]


@dataclass(slots=True)
class RobotResult:
    """Figures of every trial, and their means and spreads.

    Attributes
    ----------
    protocol : RobotProtocol
    seed : int
    trials : list of TrialEvaluation
    """

    protocol: RobotProtocol
    seed: int
    trials: list[TrialEvaluation]

    def feature_stats(self) -> dict[str, tuple[float, float]]:
        """Feature type -> (mean, standard deviation over trials) of the count per measurement."""
        out = {}
        for t in TABLE2_TYPES:
            v = np.array([tr.features[t] for tr in self.trials])
            out[t] = (float(v.mean()), _std(v))
        return out

    def feature_stats_by_visit(self) -> dict[str, dict[str, float]]:
        """``"train"`` / ``"test"`` -> feature type -> mean count per measurement over trials (Table II per visit)."""
        if not all(tr.features_by_visit for tr in self.trials):
            return {}
        return {
            role: {t: float(np.mean([tr.features_by_visit[role][t] for tr in self.trials])) for t in TABLE2_TYPES}
            for role in ("train", "test")
        }

    def cell_stats(self) -> dict[tuple[str, ...], tuple[float, float, float, float]]:
        """Path -> (top1 mean, top1 std, mean-rank mean, mean-rank std) over trials."""
        out = {}
        for key in self.trials[0].cells:
            v = np.array([tr.cells[key] for tr in self.trials])
            out[key] = (float(v[:, 0].mean()), _std(v[:, 0]), float(v[:, 1].mean()), _std(v[:, 1]))
        return out

    def ci_method(self) -> str:
        """How :meth:`feature_ci` and :meth:`cell_ci` are computed, in words."""
        if len(self.trials) >= 2:
            return f"{CI_LEVEL:.0%} Student-t interval of the mean over {len(self.trials)} trials"
        return (
            f"one trial: {CI_LEVEL:.0%} Wilson interval of the right-classification share over the test queries, "
            "Student-t interval of the mean rank over the queries and of the counts over the measurements"
        )

    def feature_ci(self) -> dict[str, tuple[float, float] | None]:
        """Feature type -> 95 % confidence interval of the mean count per measurement.

        Over trials (Student t on the per-trial means) with two or more trials; with one
        trial, over its measurements.
        """
        out: dict[str, tuple[float, float] | None] = {}
        for t in TABLE2_TYPES:
            if len(self.trials) >= 2:
                out[t] = t_interval([tr.features[t] for tr in self.trials])
            else:
                out[t] = t_interval(self.trials[0].counts.get(t, np.empty(0)))
        return out

    def cell_ci(self) -> dict[tuple[str, ...], tuple[tuple[float, float] | None, tuple[float, float] | None]]:
        """Path -> (95 % interval of the right-classification share, 95 % interval of the mean rank).

        Over trials (Student t on the per-trial figures) with two or more trials; with one
        trial, over its test queries (Wilson for the share, Student t for the rank).
        """
        out = {}
        for key in self.trials[0].cells:
            if len(self.trials) >= 2:
                v = np.array([tr.cells[key] for tr in self.trials])
                out[key] = (t_interval(v[:, 0]), t_interval(v[:, 1]))
            else:
                r = self.trials[0].ranks.get(key, np.empty(0, dtype=np.int64))
                out[key] = (wilson_interval(int((r == 1).sum()), int(r.size)), t_interval(r))
        # a share lies in [0, 1] and a rank in [1, places]: clip the t intervals to what can be
        n_places = max(len(self.trials[0].classes), 1)
        return {key: (_clip(a, 0.0, 1.0), _clip(r, 1.0, float(n_places))) for key, (a, r) in out.items()}

    def heading_error_deg(self) -> float | None:
        """Median absolute heading error of the random-heading measurements (true place), degrees."""
        errs = np.concatenate([tr.heading_error_deg for tr in self.trials]) if self.trials else np.empty(0)
        errs = errs[np.isfinite(errs)]
        return float(np.median(errs)) if errs.size else None

    def term_stats(self) -> dict[str, dict[str, Any]]:
        """k (str) -> the fusion's scale, mean over trials: ``spread_nats`` (term -> how far it moves the
        places, :func:`~fingerloc.experiments.robot_eval.term_scale`), ``fitted_weights`` (term -> weight of
        ``PlaceModel(weights="fit")``) and ``fp_lambda`` (of ``P(Fp) ∝ exp(-lambda cost)``)."""
        out: dict[str, dict[str, Any]] = {}
        trials = [tr for tr in self.trials if tr.term_scale]
        if not trials:
            return out
        for k in trials[0].term_scale:
            first = trials[0]
            out[k] = {
                "spread_nats": {t: float(np.mean([tr.term_scale[k][t] for tr in trials])) for t in first.term_scale[k]},
                "fitted_weights": {
                    t: float(np.mean([tr.term_weights[k][t] for tr in trials])) for t in first.term_weights.get(k, {})
                },
                "fp_lambda": float(np.mean([tr.fp_lambda[k] for tr in trials])) if k in first.fp_lambda else None,
            }
        return out

    def findings(self) -> list[Any]:
        """The paper's findings beside ours (:func:`~fingerloc.experiments.robot_findings.paper_findings`)."""
        from .robot_findings import paper_findings

        return paper_findings(self)

    def to_json(self) -> dict[str, Any]:
        """The JSON of ``fingerloc reproduce robot --json`` (top1 in [0, 1]).

        ``table2`` counts every training and test measurement; ``table2_by_visit`` the
        training (``"train"``) and test (``"test"``) measurements apart, whose offices
        differ in the ``"paper"`` world (``protocol.sensor_profile.session``). Each cell of
        ``table3``, ``table4`` and ``random_heading`` holds ``top1``, ``mean_rank`` and
        ``ci95`` (``{"top1": [low, high], "mean_rank": [low, high]}``, the same intervals as
        the ``ci95`` block); ``table4_terms`` the fusion's scale (:meth:`term_stats`);
        ``findings`` the paper's findings beside ours (:meth:`findings`).
        """
        cells = self.cell_stats()
        cis = self.cell_ci()
        main: dict[str, Any] = {}
        spread: dict[str, Any] = {}
        for key, (t1, t1s, mr, mrs) in cells.items():
            a, r = cis[key]
            _put(main, key, {"top1": t1, "mean_rank": mr, "ci95": {"top1": _pair(a), "mean_rank": _pair(r)}})
            _put(spread, key, {"top1": t1s, "mean_rank": mrs})
        fs = self.feature_stats()
        out: dict[str, Any] = {"table2": {t: m for t, (m, _) in fs.items()}}
        out["table3"] = main["table3"]
        out["table4"] = main["table4"]
        if "random_heading" in main:
            out["random_heading"] = main["random_heading"]
            out["random_heading"]["heading_error_deg"] = self.heading_error_deg()
        by_visit = self.feature_stats_by_visit()
        if by_visit:
            out["table2_by_visit"] = by_visit
        spread["table2"] = {t: s for t, (_, s) in fs.items()}
        out["spread"] = spread
        ci: dict[str, Any] = {"table2": {t: _pair(v) for t, v in self.feature_ci().items()}}
        for key, (a, r) in cis.items():
            _put(ci, key, {"top1": _pair(a), "mean_rank": _pair(r)})
        out["ci95"] = ci
        terms = self.term_stats()
        if terms:
            out["table4_terms"] = terms
        out["findings"] = [f.to_json() for f in self.findings()]
        out["paper"] = {
            "table2": dict(PAPER_TABLE2),
            "table3": {m: {"top1": a, "mean_rank": r} for m, (a, r) in PAPER_TABLE3.items()},
            "table4": {
                row: {str(k): {"top1": a, "mean_rank": r} for k, (a, r) in ks.items()}
                for row, ks in PAPER_TABLE4.items()
            },
        }
        p = self.protocol
        out["protocol"] = {
            "trials": len(self.trials),
            "seed": self.seed,
            "n_offices": p.n_offices,
            "n_train": p.n_train,
            "n_test": p.n_test,
            "train_radius_m": list(p.train_radius_m),
            "test_radius_m": p.test_radius_m,
            "heading_jitter_deg": p.heading_jitter_deg,
            "similarity": p.office_similarity,
            "n_beams": p.n_beams,
            "omni_size": list(p.omni_size),
            "panorama_width": p.panorama_width,
            "jpeg_quality": WORLD_PROFILES[p.world]["jpeg_quality"] if p.jpeg_quality is None else p.jpeg_quality,
            "world": p.world,
            "sensor_profile": WORLD_PROFILES[p.world],
            "ks": list(p.ks),
            "spread": "standard deviation over trials",
            "ci95": self.ci_method() + " (null where undefined)",
        }
        return out


def _std(v: FArray) -> float:
    return float(v.std(ddof=1)) if v.size > 1 else 0.0


def _clip(v: tuple[float, float] | None, lo: float, hi: float) -> tuple[float, float] | None:
    return None if v is None else (min(max(v[0], lo), hi), min(max(v[1], lo), hi))


def _pair(v: tuple[float, float] | None) -> list[float] | None:
    return None if v is None else [float(v[0]), float(v[1])]


def _put(d: dict[str, Any], key: tuple[str, ...], value: Any) -> None:
    for part in key[:-1]:
        d = d.setdefault(part, {})
    d[key[-1]] = value
