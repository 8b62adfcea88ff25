"""What a map learns on its mapping part for the filters, and the held-out machinery that learns it.

Everything here is taken from the **mapping part** of a run only (nothing
from the queries):

* the place graph: the nearest place centre (its Voronoi cell) of every
  mapping scan, in order; consecutive scans count a stay or a passage
  (:func:`mapping_graph`, :meth:`fingerloc.map.graph.PlaceGraph.from_sequence`),
  and ``metres_per_move``, the metres travelled per change of place;
* the likelihood scale ``beta`` (:func:`fingerloc.map.filter.fit_likelihood_scale`):
  the single-shot recogniser is fit on half of the training scans and scores
  the other half, two ways round (halves = alternate *visits* of each place,
  :func:`~fingerloc.pipeline.places.visit_folds`; too few usable rows ->
  alternate scans); ``beta`` maximises the held-out log-probability of the
  right place (:func:`held_out_calibration`);
* the heading model of the pose filter: each held-out view's heading implied
  at its own place, against its recorded heading (:func:`with_heading_model`).

:class:`Calibration` holds the learned values; the settings a map was made
with are a :class:`fingerloc.config.Config`. The whole sequence is
:func:`fingerloc.pipeline.calibrate.calibrate_map`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, replace
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray

from .._types import FArray, IArray
from ..config import Config
from ..errors import InvalidParameterError
from ..map.filter import fit_likelihood_scale
from ..map.filter import metres_per_move as _metres_per_move
from ..map.graph import PlaceGraph, nearest_place_sequence
from ..map.heading import HeadingModel, fit_heading_model
from .places import visit_folds

if TYPE_CHECKING:
    from ..observation import Observation

__all__ = [
    "Calibration",
    "FitHeadings",
    "FitScore",
    "HeldOut",
    "PlaceColumns",
    "calibrate_labelled",
    "fit_scale",
    "held_out_calibration",
    "held_out_headings",
    "held_out_rows",
    "held_out_scores",
    "implied_headings",
    "mapping_graph",
    "model_fit_headings",
    "model_fit_score",
    "model_fit_score_of",
    "posterior_columns",
    "read_calibration",
    "step_distances",
    "stored_calibration",
    "with_heading_model",
]

#: ``fit_score(train_rows, train_labels, test_rows) -> scores (n_test, k)``: fit a place
#: recogniser on rows with labels ``0 .. k - 1`` (every one used) and score the test rows.
FitScore = Callable[[IArray, IArray, IArray], FArray]
#: ``fit_headings(train_rows, train_labels, test_rows, own=None) -> headings (n_test, k)``: the same fit,
#: and the heading (radians, NaN = none) each test row implies at each place (:func:`implied_headings`);
#: with ``own`` (shape (n_test,), a column per test row) only ``[i, own[i]]`` is computed, the rest NaN.
FitHeadings = Callable[..., FArray]

_HEADING_KEYS = ("heading_kappa", "heading_intercept", "heading_slope", "heading_reverse", "heading_cap")


@dataclass(frozen=True, slots=True)
class Calibration:
    """What a map learned on its mapping part for the filters (module docstring).

    Attributes
    ----------
    beta : float
        Likelihood scale: the filters use ``beta * log P(place | observation)``.
    metres_per_move : float or None
        Mean metres travelled per change of place (the place filter's odometry;
        None: no odometry, a map learned from labels).
    kidnap : float
        Kidnapping probability per observation (pose filter): ``1 / (n_train + 2)``.
    n_train : int
        Training observations of the mapping part.
    calibration_rows : int
        Held-out rows ``beta`` was fit on (0: ``beta = 1``).
    radius, spacing : float
        Metres: a pose within ``radius`` of a centre is at that place; places ``spacing`` apart.
    temper_metres, temper_radians : float
        An observation counts fully after this much travel or turn (pose filter;
        the distance chosen on the mapping part, the turn the sensor's field of view).
    outlier : float
        Pose filter: ``rho``, how often the single shot's answer is noise (chosen on the mapping part).
    off_place : float
        Pose filter: likelihood weight of a pose at no place, at an observation.
    heading : HeadingModel or None
        Pose filter: the density of the heading each view implies (fitted on the
        mapping part); ``None``: headings are not used.
    heading_temper_metres : float
        The heading evidence counts fully after this much travel; 0: as the observations.
    scan_gamma : float
        Pose filter: the power of the laser end points' likelihood field (0: not used).
    lost_fit : float or None
        Pose filter: the scan fit below which the belief is taken for lost (None: off).
    lost_kidnap : float
        ... and the probability that such an observation re-draws from the sensor.
    place_filter_top1, place_single_top1 : float or None
        The place filter's and the single shot's top-1 over the mapping part's
        held-out views (:func:`~fingerloc.map.filter.check_place_filter`; None:
        not measured). When the filter is below the single shot, the place
        filter answers the single shot at its observations (:meth:`place_filter_steps_aside`).
    """

    beta: float = 1.0
    metres_per_move: float | None = 1.0
    kidnap: float = 0.005
    n_train: int = 0
    calibration_rows: int = 0
    radius: float = 1.0
    spacing: float = 2.0
    temper_metres: float = 2.0
    temper_radians: float = math.pi
    outlier: float = 0.1
    off_place: float = 0.1
    heading: HeadingModel | None = None
    heading_temper_metres: float = 0.0
    scan_gamma: float = 0.0
    lost_fit: float | None = None
    lost_kidnap: float = 0.0
    place_filter_top1: float | None = None
    place_single_top1: float | None = None

    def __post_init__(self) -> None:
        for name in ("beta", "metres_per_move", "radius", "spacing", "temper_metres", "temper_radians"):
            v = getattr(self, name)
            if v is None and name == "metres_per_move":
                continue
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InvalidParameterError(f"calibration {name} must be a finite number > 0, got {v!r}")
        for name in ("kidnap", "outlier", "off_place", "lost_kidnap"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise InvalidParameterError(f"calibration {name} must be a probability in [0, 1], got {v!r}")
        for name in ("heading_temper_metres", "scan_gamma"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                raise InvalidParameterError(f"calibration {name} must be a finite number >= 0, got {v!r}")
        if self.heading is not None and not isinstance(self.heading, HeadingModel):
            raise InvalidParameterError(f"calibration heading must be a HeadingModel or None, got {self.heading!r}")
        if self.lost_fit is not None and not (isinstance(self.lost_fit, (int, float)) and not math.isnan(self.lost_fit)):
            raise InvalidParameterError(f"calibration lost_fit must be a number or None, got {self.lost_fit!r}")
        for name in ("place_filter_top1", "place_single_top1"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and 0 <= v <= 1):
                raise InvalidParameterError(f"calibration {name} must be a fraction in [0, 1] or None, got {v!r}")

    def place_filter_steps_aside(self) -> bool:
        """True when the place filter was below the single shot on the mapping part's held-out views."""
        f, s = self.place_filter_top1, self.place_single_top1
        return f is not None and s is not None and f < s

    def place_filter_reason(self) -> str:
        """One line: whether the place filter beat the single shot on the mapping part (empty when not measured)."""
        f, s = self.place_filter_top1, self.place_single_top1
        if f is None or s is None:
            return ""
        what = "answering the single shot at observations" if f < s else "filtering"
        return f"the place filter was right at {f:.2f} of the mapping part's held-out views, the single shot at {s:.2f}: {what}"

    def to_json(self) -> dict[str, Any]:
        """JSON-ready flat dict: every field, the heading model as ``heading_kappa`` ... ``heading_cap`` (0: none)."""
        out = {k: v for k, v in asdict(self).items() if k != "heading"}
        hm = self.heading
        for key in _HEADING_KEYS:
            out[key] = 0.0 if hm is None else float(getattr(hm, key.removeprefix("heading_")))
        return out

    @classmethod
    def from_json(cls, data: Mapping[str, Any]) -> Calibration:
        """Inverse of :meth:`to_json` (unknown keys are ignored: a stored calibration also holds settings)."""
        if not isinstance(data, Mapping):
            raise InvalidParameterError(f"a stored calibration must be an object, got {type(data).__name__}")
        names = set(cls.__dataclass_fields__) - {"heading"}
        values: dict[str, Any] = {k: v for k, v in data.items() if k in names}
        hv = {k: data.get(k, 0.0) for k in _HEADING_KEYS}
        try:
            if float(hv["heading_kappa"]) > 0 and float(hv["heading_cap"]) > 0:
                values["heading"] = HeadingModel(**{k.removeprefix("heading_"): float(v) for k, v in hv.items()})
            return cls(**values)
        except (TypeError, ValueError) as err:
            raise InvalidParameterError(f"invalid stored calibration ({err})") from err


#: The pose filter's settings a place database stored with its calibration before they
#: were a :class:`~fingerloc.config.Config` (still written, for scripts that read them).
_SETTING_KEYS = {
    "alpha": "alpha",
    "start_at_first_observation": "start_at_first_observation",
    "gap_metres": "gap_m",
    "challenger_switch_nats": "challenger_switch_nats",
    "scan_fresh": "scan_fresh",
    "lost_after": "lost_after",
    "lost_statistic": "lost_statistic",
    "lost_uniform": "lost_uniform",
    "hold_margin": "hold_margin",
    "tie_break": "tie_break",
}


def stored_calibration(calibration: Calibration, config: Config) -> dict[str, Any]:
    """What a place database stores as its calibration: the learned values, the filter's
    settings under their former flat names, and the whole ``config``."""
    pf = config.pose_filter
    out = calibration.to_json()
    for key, name in _SETTING_KEYS.items():
        out[key] = getattr(pf, name)
    out["challenger"] = pf.strategy == "challenger"
    out["config"] = config.to_json()
    return out


def read_calibration(data: Mapping[str, Any]) -> tuple[Calibration, Config]:
    """A stored calibration (:func:`stored_calibration`) read back: the values and the config.

    A database written before the config was stored gives its flat settings
    over the default config.
    """
    if not isinstance(data, Mapping):
        raise InvalidParameterError(f"a stored calibration must be an object, got {type(data).__name__}")
    cal = Calibration.from_json(data)
    stored = data.get("config")
    if stored is not None:
        return cal, Config.from_json(stored)
    pf = {name: data[key] for key, name in _SETTING_KEYS.items() if key in data}
    if data.get("challenger"):
        pf["strategy"] = "challenger"
    return cal, Config().with_(pose_filter=pf)


def step_distances(positions: Any) -> FArray:
    """Metres travelled from each step to the next, shape (n,) (entry 0 is 0)."""
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    d = np.zeros(pos.shape[0])
    if pos.shape[0] > 1:
        d[1:] = np.hypot(*np.diff(pos, axis=0).T)
    return d


def mapping_graph(positions: Any, centres: Any, labels: Sequence[str] | None = None) -> tuple[PlaceGraph, float]:
    """The place graph and ``metres_per_move`` of a mapping part.

    Parameters
    ----------
    positions : array_like, shape (n, 2)
        The mapping part's positions in order, metres.
    centres : array_like, shape (P, 2)
        Place centres, metres.
    labels : sequence of str, optional
        Place names (default ``"0" .. "P-1"``).

    Returns
    -------
    graph : PlaceGraph
    metres_per_move : float
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(centres, dtype=np.float64).reshape(-1, 2)
    places = [str(j) for j in range(c.shape[0])] if labels is None else [str(x) for x in labels]
    near = nearest_place_sequence(pos, c)
    g = PlaceGraph.from_sequence(places, [places[j] for j in near.tolist()])
    return g, _metres_per_move(pos, near) if pos.shape[0] > 1 else 1.0


def held_out_scores(fit_score: FitScore, labels: Any, fold: Any, n_places: int, scored: Any = None) -> tuple[FArray, IArray]:
    """Scores of each fold's rows by a recogniser fit on the other fold, shape (n_rows, n_places).

    Places absent from a training fold score ``-inf``. Rows come fold 0
    first, then fold 1 (:func:`held_out_rows` gives their positions).
    ``scored`` (bool, one per row): only those rows are scored (each fold's
    recogniser is still fit on every row of the other fold).
    """
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    f_ = np.asarray(fold, dtype=np.int64).reshape(-1)
    keep = _scored_mask(scored, f_.size)
    rows: list[FArray] = []
    ys: list[IArray] = []
    for f in (0, 1):
        tr = np.flatnonzero(f_ != f)
        te = np.flatnonzero((f_ == f) & keep)
        if tr.size == 0 or te.size == 0:
            continue
        present = np.unique(y[tr])
        remap = np.full(n_places, -1, dtype=np.int64)
        remap[present] = np.arange(present.size)
        s = np.asarray(fit_score(tr, remap[y[tr]], te), dtype=np.float64)
        full = np.full((te.size, n_places), -np.inf)
        full[:, present] = s
        rows.append(full)
        ys.append(y[te])
    if not rows:
        return np.zeros((0, n_places)), np.zeros(0, np.int64)
    return np.concatenate(rows), np.concatenate(ys)


def held_out_rows(fold: Any, scored: Any = None) -> IArray:
    """Positions of :func:`held_out_scores`' rows among the training rows (fold 0's, then fold 1's)."""
    f_ = np.asarray(fold, dtype=np.int64).reshape(-1)
    if any(not np.any(f_ == f) for f in (0, 1)):  # a fold without training rows scores nothing
        return np.zeros(0, np.int64)
    keep = _scored_mask(scored, f_.size)
    return np.concatenate([np.flatnonzero((f_ == f) & keep) for f in (0, 1)])


def _scored_mask(scored: Any, n: int) -> NDArray[np.bool_]:
    if scored is None:
        return np.ones(n, dtype=bool)
    keep = np.asarray(scored, dtype=bool).reshape(-1)
    if keep.size != n:
        raise InvalidParameterError(f"scored must have one entry per training row ({n}), got {keep.size}")
    return keep


@dataclass(frozen=True, slots=True)
class HeldOut:
    """The held-out calibration of a mapping part (:func:`held_out_calibration`).

    Attributes
    ----------
    beta : float
    rows : int
        Usable held-out rows (0: ``beta = 1``).
    scores : ndarray, shape (n, P)
        Each training row's ``log P(place | obs)`` from a model fit on the other fold.
    labels : ndarray of int, shape (n,)
    index : ndarray of int, shape (n,)
        Position of each row among the training rows.
    fold : ndarray of int, shape (n_train,), optional
        The fold (0 / 1) of every training row the scores were computed with.
    """

    beta: float
    rows: int
    scores: FArray
    labels: IArray
    index: IArray
    fold: IArray | None = None


def held_out_calibration(
    fit_score: FitScore,
    train_idx: Any,
    labels: Any,
    n_places: int,
    *,
    by_visits: bool = True,
    min_rows: int = 10,
    scored: Any = None,
) -> HeldOut:
    """``beta`` from held-out scores of the training rows, with the scores themselves (module docstring).

    Folds by alternate visits (``by_visits``); fewer than ``min_rows`` usable
    rows (:attr:`CalibrationConfig.min_rows <fingerloc.config.CalibrationConfig>`): alternate rows.
    ``scored`` (bool, one per training row): only those rows are held out and
    scored, by recognisers fit on every row of the other fold (a sample of a
    long mapping part: the cost grows with the rows scored times the rows).
    """
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    fold = visit_folds(train_idx, y) if by_visits else np.arange(y.size) % 2
    s, yy = held_out_scores(fit_score, y, fold, n_places, scored)
    usable = int(np.sum(np.isfinite(s[np.arange(yy.size), yy]))) if yy.size else 0
    if usable < min_rows:
        fold = np.arange(y.size) % 2
        s, yy = held_out_scores(fit_score, y, fold, n_places, scored)
        usable = int(np.sum(np.isfinite(s[np.arange(yy.size), yy]))) if yy.size else 0
    beta = fit_likelihood_scale(s, yy) if usable else 1.0
    return HeldOut(float(beta), usable, s, yy, held_out_rows(fold, scored) if yy.size else np.zeros(0, np.int64), fold)


def fit_scale(
    fit_score: FitScore, train_idx: Any, labels: Any, n_places: int, *, by_visits: bool = True, min_rows: int = 10
) -> tuple[float, int]:
    """``beta`` from held-out scores of the training rows, and the number of usable rows (module docstring).

    Parameters
    ----------
    fit_score : FitScore
        Row indices are positions in ``labels`` (0 .. n_train - 1).
    train_idx : array_like of int, shape (n_train,)
        The training rows' indices in the run (for the visits).
    labels : array_like of int, shape (n_train,)
    n_places : int
    by_visits : bool, default True
        Folds by alternate visits; False: alternate rows.
    """
    h = held_out_calibration(fit_score, train_idx, labels, n_places, by_visits=by_visits, min_rows=min_rows)
    return h.beta, h.rows


def model_fit_score(options: Mapping[str, Any], observations: Sequence[Observation]) -> FitScore:
    """A :data:`FitScore` over ``observations`` with a :class:`~fingerloc.model.PlaceModel` of these options.

    Places are labelled ``"0" .. "k-1"``; the scores are the model's
    log-posterior, column ``j`` = place ``j``.
    """
    from .presets import model_from_options

    def fit_model(tr: IArray, y: IArray) -> Any:
        return model_from_options(options).fit([observations[i] for i in tr.tolist()], [str(v) for v in y.tolist()])

    return model_fit_score_of(fit_model, observations)


def model_fit_score_of(fit_model: Callable[[IArray, IArray], Any], observations: Sequence[Observation]) -> FitScore:
    """A :data:`FitScore` from ``fit_model(train_rows, train_labels) -> model`` over ``observations``.

    The model is fit on labels ``"0" .. "k-1"`` (``fit_model``'s to do); the
    scores are its log-posterior, column ``j`` = place ``j``
    (:func:`posterior_columns`).
    """

    def fit_score(tr: IArray, y: IArray, te: IArray) -> FArray:
        return posterior_columns(fit_model(tr, y), [observations[i] for i in te.tolist()], int(y.max()) + 1)

    return fit_score


class PlaceColumns:
    """A model's places in a given column order, looked up once for many calls.

    Parameters
    ----------
    model : PlaceModel
        Fitted; its ``classes_`` name the places.
    labels : sequence of str, optional
        ``labels[j]``: the place of column ``j`` (default ``str(j)`` for ``j < n_places``).
    n_places : int, optional
        Number of columns (default ``len(labels)``).

    :meth:`posterior` is :func:`posterior_columns` and :meth:`headings` is
    :func:`implied_headings`; the column of each of the model's places and
    each place's views with their recorded headings are found once (the
    streaming tracker keeps one for every step).
    """

    def __init__(self, model: Any, labels: Sequence[str] | None = None, n_places: int | None = None) -> None:
        if labels is None:
            if n_places is None:
                raise InvalidParameterError("PlaceColumns needs labels or n_places")
            labels = [str(j) for j in range(n_places)]
        self.model = model
        self.labels = [str(x) for x in labels]
        self.n_places = len(self.labels) if n_places is None else int(n_places)
        col = {lab: j for j, lab in enumerate(self.labels)}
        last: dict[int, int] = {}  # column -> the model's index of its place (a column named twice: the later)
        for k, c in enumerate(model.classes_):
            j = col.get(str(c))
            if j is not None:
                last[j] = k
        self._cols = np.fromiter(last.keys(), dtype=np.int64, count=len(last))
        self._classes = np.fromiter(last.values(), dtype=np.int64, count=len(last))
        self._views: list[tuple[Any, FArray]] | None = None

    def posterior(self, observations: Sequence[Observation]) -> FArray:
        """``log P(place | observation)``, shape (n, n_places); places the model does not hold score ``-inf``."""
        out = np.full((len(observations), self.n_places), -np.inf)
        if not observations:
            return out
        lp = np.asarray(self.model.predict_log_proba(list(observations)), dtype=np.float64)
        out[:, self._cols] = lp[:, self._classes]
        return out

    def _place_views(self) -> list[tuple[Any, FArray]]:
        """Per column: the model's key of its place (None when unknown) and its views' recorded headings (rad)."""
        if self._views is None:
            places = getattr(self.model, "places_", {})
            by_name = {str(k): k for k in places}
            views: list[tuple[Any, FArray]] = []
            for lab in self.labels:
                key = by_name.get(lab)
                obs = [] if key is None else places[key].observations
                views.append((key, np.array([np.nan if o.pose is None else float(o.pose[2]) for o in obs])))
            self._views = views
        return self._views

    def headings(self, observations: Sequence[Observation], columns: Any = None, own: Any = None) -> FArray:
        """The heading each observation implies at each place, radians, shape (n, len(labels)) (:func:`implied_headings`)."""
        obs = list(observations)
        out = np.full((len(obs), len(self.labels)), np.nan)
        if not obs:
            return out
        if own is not None:
            return self._own_headings(obs, own, out)
        views = self._place_views()
        cols = range(len(self.labels)) if columns is None else np.unique(np.asarray(columns, dtype=np.int64)).tolist()
        known = [j for j in cols if views[j][0] is not None]
        if len(obs) == 1:  # one call for every place: the model's loop over (observation, place) pairs
            if known:
                h, v = self.model.headings_with_reference(obs * len(known), [views[j][0] for j in known])
                for i, j in enumerate(known):
                    _absolute(out[:, j], views[j][1], h[i : i + 1], v[i : i + 1])
            return out
        prepare = getattr(self.model, "prepare_headings", None)
        if prepare is not None and len(cols) > 1:
            prepare(obs)  # one batch of alignments for every place below (the same headings)
        for j in known:
            key, theta = views[j]
            h, v = self.model.headings_with_reference(obs, [key] * len(obs))
            _absolute(out[:, j], theta, h, v)
        return out

    def _own_headings(self, obs: list[Observation], own: Any, out: FArray) -> FArray:
        """``out[i, own[i]]``: observation ``i``'s heading at its one place (column ``own[i]``; -1: none), one model call."""
        cols = np.asarray(own, dtype=np.int64).reshape(-1)
        if cols.size != len(obs):
            raise InvalidParameterError(f"own must give one column per observation ({len(obs)}), got {cols.size}")
        views = self._place_views()
        sel = [i for i, j in enumerate(cols.tolist()) if 0 <= j < len(views) and views[j][0] is not None]
        if sel:
            h, v = self.model.headings_with_reference([obs[i] for i in sel], [views[int(cols[i])][0] for i in sel])
            for k, i in enumerate(sel):
                j = int(cols[i])
                _absolute(out[i : i + 1, j], views[j][1], h[k : k + 1], v[k : k + 1])
        return out


def _absolute(out: FArray, theta: FArray, h: FArray, v: IArray) -> None:
    """``out[i] = theta[v[i]] - h[i]`` (h in degrees), wrapped to [-pi, pi), where view ``v[i]`` and ``h[i]`` exist."""
    ok = (v >= 0) & (v < theta.size) & np.isfinite(h)
    if np.any(ok):
        out[ok] = np.mod(theta[v[ok]] - np.radians(h[ok]) + math.pi, 2 * math.pi) - math.pi


def posterior_columns(model: Any, observations: Sequence[Observation], n_places: int, labels: Sequence[str] | None = None) -> FArray:
    """``log P(place | observation)`` with columns in a given place order, shape (n, n_places).

    ``labels[j]`` is the label of column ``j`` (default ``str(j)``); places
    the model does not hold score ``-inf``.
    """
    return PlaceColumns(model, labels, n_places).posterior(observations)


def implied_headings(
    model: Any, observations: Sequence[Observation], labels: Sequence[str], columns: Any = None, own: Any = None
) -> FArray:
    """The robot's heading each observation implies at each place, radians in the views' frame, shape (n, P).

    For place ``labels[j]``, :meth:`~fingerloc.model.PlaceModel.headings_with_reference`
    gives the heading ``h`` (degrees) of the observation against the place's
    best-matching training view (the fingerprint's cyclic alignment, or the
    profile's); that view's recorded pose ``(x, y, theta)`` (the mapping
    run's) makes it absolute. The model's convention is *bearing in the
    view = bearing in the observation - h* (``localize --json`` reports
    ``-h`` as ``heading_deg``: the README's *b + heading_deg*), so the
    robot's heading is ``theta - h`` (on the shared logs' mapping passes: median error 3-6 deg
    at the true place on aces and intel with this sign, 25-37 deg with the
    other; docs/RESULTS.md). NaN where a place is unknown to the model, has no estimate, or
    its view has no pose. ``columns`` (indices into ``labels``): only those places are
    computed, the others are NaN (the same values where computed). ``own`` (shape (n,), an
    index into ``labels`` per observation, -1 for none): only each observation's own
    place is computed (one model call for all), the others are NaN.
    """
    return PlaceColumns(model, labels).headings(observations, columns, own)


def model_fit_headings(fit_model: Callable[[IArray, IArray], Any], observations: Sequence[Observation]) -> FitHeadings:
    """A :data:`FitHeadings` from ``fit_model(train_rows, train_labels) -> model`` over ``observations``.

    The model needs :meth:`~fingerloc.model.PlaceModel.headings_with_reference`
    and training views that carry their poses (:func:`implied_headings`).
    """

    def fit_headings(tr: IArray, y: IArray, te: IArray, own: Any = None) -> FArray:
        model = fit_model(tr, y)
        return implied_headings(model, [observations[i] for i in te.tolist()], [str(k) for k in range(int(y.max()) + 1)], own=own)

    return fit_headings


def held_out_headings(
    fit_headings: FitHeadings, labels: Any, held: HeldOut, n_places: int, *, own_only: bool = False
) -> FArray | None:
    """Implied headings (:func:`implied_headings`) of the held-out rows of ``held``, rows as ``held.scores``; None without folds.

    ``fit_headings(train_rows, train_labels, test_rows, own=None)`` fits the same
    recogniser as the calibration's ``fit_score`` on those training rows
    (labels ``0 .. k - 1``, as :func:`held_out_scores` remaps them) and
    gives the test rows' implied headings at each of the ``k`` places.
    ``own_only``: only at each row's own place (what the heading model is
    fitted on; the other entries NaN): one heading a row instead of one a
    row and place.
    """
    if held.fold is None or held.index.size == 0:
        return None
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    parts: list[FArray] = []
    for f in (0, 1):
        tr, te = np.flatnonzero(held.fold != f), held.index[held.fold[held.index] == f]
        if tr.size == 0 or te.size == 0:
            continue
        present = np.unique(y[tr])
        remap = np.full(n_places, -1, dtype=np.int64)
        remap[present] = np.arange(present.size)
        full = np.full((te.size, n_places), np.nan)
        if own_only:
            full[:, present] = fit_headings(tr, remap[y[tr]], te, own=remap[y[te]])
        else:
            full[:, present] = fit_headings(tr, remap[y[tr]], te)
        parts.append(full)
    return np.concatenate(parts) if parts else None


def with_heading_model(
    calibration: Calibration,
    held: HeldOut,
    headings: Any,
    headings_true: Any,
    *,
    reverse: bool = True,
    slope: bool = True,
    temper_metres: float = 8.0,
) -> Calibration:
    """The calibration with the pose filter's heading model fitted on the mapping part's held-out rows.

    ``headings`` (rows as ``held.scores``): :func:`held_out_headings`;
    ``headings_true``: each held-out row's recorded heading (radians). The
    error at the row's own place and the row's log-probability of it
    (``beta``-scaled softmax) fit :func:`~fingerloc.map.pose_filter.fit_heading_model`.
    ``temper_metres``: the heading evidence's own tempering
    (``heading_temper_metres``). Unchanged when there are too few estimates.
    """
    h = np.asarray(headings, dtype=np.float64)
    rows = np.arange(held.labels.size)
    if h.shape != held.scores.shape or rows.size == 0:
        return calibration
    s = calibration.beta * np.where(np.isnan(held.scores), -np.inf, held.scores)
    with np.errstate(invalid="ignore"):
        top = np.max(s, axis=1, keepdims=True)
        x = (s - top - np.log(np.sum(np.exp(s - top), axis=1, keepdims=True)))[rows, held.labels]
    true = np.asarray(headings_true, dtype=np.float64).reshape(-1)
    hm = fit_heading_model(true - h[rows, held.labels], x if slope else None, reverse=reverse, slope=slope)
    if hm is None:
        return calibration
    return replace(calibration, heading=hm, heading_temper_metres=float(temper_metres))


def calibrate_labelled(options: Mapping[str, Any], observations: Sequence[Observation], *, min_rows: int = 10) -> Calibration:
    """The likelihood scale of labelled observations in visiting order (``fingerloc learn``).

    The file order stands for the visiting order: folds by alternate visits
    (:func:`fit_scale`), a model with ``options`` fit on one fold scoring the
    other. Only ``beta``, ``calibration_rows``, ``n_train`` and ``kidnap``
    are set; the rest keeps the defaults (no positions are known).
    """
    labels = [str(o.label) for o in observations]
    order = list(dict.fromkeys(labels))
    col = {lab: j for j, lab in enumerate(order)}
    y = np.array([col[lab] for lab in labels], dtype=np.int64)
    beta, rows = fit_scale(model_fit_score(options, observations), np.arange(y.size), y, len(order), min_rows=min_rows)
    return Calibration(
        beta=float(beta), metres_per_move=None, kidnap=1.0 / (y.size + 2), n_train=int(y.size), calibration_rows=rows
    )
