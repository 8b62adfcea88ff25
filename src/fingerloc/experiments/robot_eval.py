"""Figures of one simulated trial of the robot experiment: Tables II-IV (see :mod:`fingerloc.experiments.robot`)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._types import FArray
from ..metrics import min_per_place, true_place_ranks
from ..observation import Observation
from .robot_sim import TABLE2_TYPES, TABLE4_EXP, TABLE4_FITTED, TABLE4_TERMS, RobotProtocol, TrialData

__all__ = ["CI_LEVEL", "TrialEvaluation", "evaluate_trial", "t_interval", "term_scale", "wilson_interval"]


def _cell(ranks: NDArray[np.int64]) -> tuple[float, float]:
    return float(np.mean(ranks == 1)), float(np.mean(ranks))


#: Two-sided coverage of the confidence intervals.
CI_LEVEL = 0.95


def t_interval(values: ArrayLike, level: float = CI_LEVEL) -> tuple[float, float] | None:
    """Student-t confidence interval of the mean of ``values`` (None for fewer than two values).

    Parameters
    ----------
    values : array_like, shape (n,)
        Independent measurements (one per trial, or one per query).
    level : float
        Coverage, e.g. 0.95.

    Returns
    -------
    (low, high) or None
        ``mean -+ t_{(1 + level) / 2, n - 1} s / sqrt(n)``, ``s`` the sample standard deviation.
    """
    from scipy.stats import t as student_t

    v = np.asarray(values, dtype=np.float64).reshape(-1)
    if v.size < 2:
        return None
    m = float(v.mean())
    h = float(student_t.ppf(0.5 + level / 2, v.size - 1)) * float(v.std(ddof=1)) / math.sqrt(v.size)
    return (m - h, m + h)


def wilson_interval(successes: int, n: int, level: float = CI_LEVEL) -> tuple[float, float] | None:
    """Wilson score interval of a proportion ``successes / n`` (None for ``n == 0``).

    ``(p + z^2/2n -+ z sqrt(p (1 - p) / n + z^2 / 4n^2)) / (1 + z^2 / n)`` with ``z`` the
    normal quantile of ``(1 + level) / 2``; unlike the normal approximation it stays inside
    [0, 1] and is not empty at 0 % or 100 %.
    """
    from scipy.stats import norm

    if n <= 0:
        return None
    z = float(norm.ppf(0.5 + level / 2))
    p = successes / n
    den = 1.0 + z * z / n
    centre = (p + z * z / (2 * n)) / den
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return (max(0.0, centre - half), min(1.0, centre + half))


@dataclass(slots=True)
class TrialEvaluation:
    """Figures of one trial, plus what the demo shows.

    Attributes
    ----------
    features : dict
        Feature type -> mean count per measurement (Table II).
    cells : dict
        Path tuple (e.g. ``("table4", "VE+Ex+Fp", "5")``) -> (top1 in [0, 1], mean rank).
    classes : list of str
        Place names, columns of ``posterior``.
    truth : ndarray of int, shape (n_test,)
        True place of each test measurement.
    posterior : ndarray, shape (n_test, P)
        Full program's posterior (largest k) on the test measurements.
    heading_error_deg : ndarray
        Absolute heading error of the random-heading test measurements (true place), degrees.
    model, models : PlaceModel, dict
        The full program (terms VE, Ex, Fp) fit with the largest k, and with each k
        (k -> model); dropped by :func:`run_robot` to keep results small.
    ranks : dict
        Path -> rank of the true place for each test query, shape (n_test,) (what ``cells`` averages).
    counts : dict
        Feature type -> count per measurement, shape (n_measurements,) (what ``features`` averages).
    features_by_visit : dict
        ``"train"`` / ``"test"`` -> feature type -> mean count per measurement of that visit.
    term_scale : dict
        k (str) -> term -> how far the term moves the places' log-likelihoods, nats: the
        median over the test queries of (largest - smallest log-likelihood over the places).
        Terms ``"VE"``, ``"Ex"``, ``"Fp"`` (the paper's ``1 / (cost + 1)``) and ``"Fp-exp"``
        (``exp(-lambda cost)``, :data:`~fingerloc.experiments.robot_sim.TABLE4_EXP`).
    term_weights : dict
        k (str) -> term -> weight fit on the training views (``PlaceModel(weights="fit")``).
    fp_lambda : dict
        k (str) -> ``lambda`` of the ``exp(-lambda cost)`` fingerprint likelihood, per unit of cost.
    """

    features: dict[str, float]
    cells: dict[tuple[str, ...], tuple[float, float]]
    ranks: dict[tuple[str, ...], NDArray[np.int64]] = field(default_factory=dict)
    counts: dict[str, NDArray[np.int64]] = field(default_factory=dict)
    classes: list[str] = field(default_factory=list)
    truth: NDArray[np.int64] = field(default_factory=lambda: np.empty(0, dtype=np.int64))
    posterior: FArray = field(default_factory=lambda: np.empty((0, 0)))
    heading_error_deg: FArray = field(default_factory=lambda: np.empty(0))
    model: Any = None
    models: dict[int, Any] = field(default_factory=dict)
    features_by_visit: dict[str, dict[str, float]] = field(default_factory=dict)
    term_scale: dict[str, dict[str, float]] = field(default_factory=dict)
    term_weights: dict[str, dict[str, float]] = field(default_factory=dict)
    fp_lambda: dict[str, float] = field(default_factory=dict)


def term_scale(ll: FArray) -> float:
    """How far one term moves the places: median over queries of (max - min) of its log-likelihood, nats.

    Parameters
    ----------
    ll : ndarray, shape (n_queries, P)
        The term's log-likelihood of each query at each place.
    """
    v = np.asarray(ll, dtype=np.float64)
    if v.size == 0:
        return 0.0
    finite = np.where(np.isfinite(v), v, np.nan)
    spread = np.nanmax(finite, axis=1) - np.nanmin(finite, axis=1)
    spread = spread[np.isfinite(spread)]
    return float(np.median(spread)) if spread.size else 0.0


def evaluate_trial(data: TrialData, protocol: RobotProtocol, *, random_state: int = 0) -> TrialEvaluation:
    """Tables II-IV (and the random-heading row) of one simulated trial.

    Parameters
    ----------
    data : TrialData
    protocol : RobotProtocol
    random_state : int
        Seed of the mixtures' initialisation.
    """
    from ..align import alignment_costs, minimum_energy_costs
    from ..fingerprint import make_fingerprint
    from ..model import PlaceModel

    all_obs = [m.observation for m in data.measurements if m.role in ("train", "test")]
    counts = {t: np.array([o.bearings(t).size for o in all_obs], dtype=np.int64) for t in TABLE2_TYPES}
    features = {t: float(np.mean(c)) for t, c in counts.items()}
    by_visit = {
        role: {t: float(np.mean([o.bearings(t).size for o in data.observations(role)])) for t in TABLE2_TYPES}
        for role in ("train", "test")
    }
    train = data.observations("train")
    test = data.observations("test")
    classes = [w.name for w in data.worlds]
    col = {c: j for j, c in enumerate(classes)}
    owner = np.array([col[str(o.label)] for o in train], dtype=np.int64)
    truth = np.array([col[str(o.label)] for o in test], dtype=np.int64)
    cells: dict[tuple[str, ...], tuple[float, float]] = {}
    ranks: dict[tuple[str, ...], NDArray[np.int64]] = {}

    def record(key: tuple[str, ...], scores: Any, true_cols: NDArray[np.int64]) -> None:
        r = true_place_ranks(scores, true_cols)
        ranks[key] = r
        cells[key] = _cell(r)

    # Table III: string matching alone, nearest place by least cost
    train_fp = [make_fingerprint(o) for o in train]
    test_fp = [make_fingerprint(o) for o in test]
    me = min_per_place(minimum_energy_costs(test_fp, train_fp), owner, len(classes))
    ga = min_per_place(alignment_costs(test_fp, train_fp), owner, len(classes))
    record(("table3", "minimum_energy"), -me, truth)
    record(("table3", "global_alignment"), -ga, truth)

    # Table IV: the Bayesian program, one model per k, term sets by summing terms
    posterior = np.empty((0, 0))
    model: Any = None
    models: dict[int, Any] = {}
    scale: dict[str, dict[str, float]] = {}
    weights: dict[str, dict[str, float]] = {}
    lambdas: dict[str, float] = {}
    for k in protocol.ks:
        model = PlaceModel(k, terms=("VE", "Ex", "Fp"), random_state=random_state).fit(train)
        models[k] = model
        if list(model.classes_) != classes:
            raise RuntimeError("PlaceModel changed the order of the places")  # pragma: no cover
        ll = model.term_log_likelihoods(test)
        for row, terms in TABLE4_TERMS.items():
            joint = sum(ll[t] for t in terms)
            record(("table4", row, str(k)), joint, truth)
        posterior = model.predict_proba(test)
        fitted = PlaceModel(k, terms=("VE", "Ex", "Fp"), weights="fit", random_state=random_state).fit(train)
        record(("table4", TABLE4_FITTED, str(k)), fitted.predict_log_proba(test), truth)
        weights[str(k)] = {t: float(w) for t, w in fitted.weights_.items()}
        # the string on the mixtures' scale: P(Fp | loc) proportional to exp(-lambda cost), lambda fit
        # leave-one-out on the training views (the mixtures are those of the paper's program)
        fp_exp = PlaceModel(k, terms=("Fp",), fp_likelihood="exp", random_state=random_state).fit(train)
        ll_exp = fp_exp.term_log_likelihoods(test)["Fp"]
        record(("table4", TABLE4_EXP, str(k)), ll["VE"] + ll["Ex"] + ll_exp, truth)
        lambdas[str(k)] = fp_exp.fp_lambda_
        scale[str(k)] = {t: term_scale(ll[t]) for t in ("VE", "Ex", "Fp")}
        scale[str(k)]["Fp-exp"] = term_scale(ll_exp)

    # Random heading: cyclic matching, per-place heading estimate for the mixture terms
    heading_err = np.empty(0)
    if protocol.random_heading:
        rtest = data.observations("test-random-heading")
        rtruth = np.array([col[str(o.label)] for o in rtest], dtype=np.int64)
        rfp = [make_fingerprint(o) for o in rtest]
        gc = min_per_place(alignment_costs(rfp, train_fp, cyclic=True), owner, len(classes))
        record(("random_heading", "global_alignment"), -gc, rtruth)
        poses = [m.pose for m in data.measurements if m.role == "test-random-heading"]
        for k in protocol.ks:
            cm = PlaceModel(k, terms=("VE", "Ex", "Fp"), cyclic=True, random_state=random_state).fit(train)
            fp_ll = cm.term_log_likelihoods(rtest)["Fp"]
            # The mixtures alone (the same fit as cm's: one batch over the same places and terms), for the
            # observations turned back by each place's heading: one call for all places, no Fp recomputed.
            mixtures = PlaceModel(k, terms=("VE", "Ex"), random_state=random_state).fit(train)
            mog = np.zeros_like(fp_ll)
            head = np.full((len(rtest), len(classes)), np.nan)
            turned: list[Observation] = []
            for j, name in enumerate(classes):
                h = cm.headings(rtest, [name] * len(rtest))
                head[:, j] = h
                turned += [o.rotated(-math.radians(v)) if np.isfinite(v) else o for o, v in zip(rtest, h, strict=True)]
            ll = mixtures.term_log_likelihoods(turned)
            n_r = len(rtest)
            for j in range(len(classes)):
                rows = slice(j * n_r, (j + 1) * n_r)
                mog[:, j] = ll["VE"][rows, j] + ll["Ex"][rows, j]
            record(("random_heading", "VE+Ex+Fp", str(k)), mog + fp_ll, rtruth)
            if k == protocol.ks[-1]:
                # the robot's heading relative to the training heading (about 0): heading_deg = -theta... see below
                est = head[np.arange(len(rtest)), rtruth]
                true_turn = np.array([p[2] for p in poses])
                # query bearings = stored bearings - theta, so the estimate should be -theta (mod 360)
                err = np.rad2deg(np.abs(np.angle(np.exp(1j * (np.deg2rad(est) + true_turn)))))
                heading_err = err
    return TrialEvaluation(
        features=features,
        features_by_visit=by_visit,
        cells=cells,
        ranks=ranks,
        counts=counts,
        classes=classes,
        truth=truth,
        posterior=posterior,
        heading_error_deg=heading_err,
        model=model,
        models=models,
        term_scale=scale,
        term_weights=weights,
        fp_lambda=lambdas,
    )
