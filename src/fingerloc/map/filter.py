"""A discrete Bayes (Markov) filter over the places of the topological map (docs/METHOD.md §6).

The paper answers ``P(Loc | observation)`` for one observation at a time and
notes that when the right place is not first it is usually second or third.
The filter carries that information along a trajectory: the belief over places
``b_t(x) = P(x_t = x | z_1..z_t)`` is

* **predicted** with a transition model ``T[i, j] = P(x_t = j | x_{t-1} = i)``::

      b_t^-(j) = sum_i b_{t-1}(i) T[i, j]

* **updated** with the likelihood of the step's observation (any single-shot
  method's per-place log-likelihood, e.g. :meth:`PlaceModel.joint_log_likelihood`)::

      b_t(j) = b_t^-(j) P(z_t | j) / sum_k b_t^-(k) P(z_t | k)

everything in log space. A step without an observation is a prediction only.

The transition model (:class:`TransitionModel`) is built from the place graph
(:class:`fingerloc.map.graph.PlaceGraph`): per step, stay at place ``i`` with
probability ``stay[i]`` or move to a neighbour ``j`` with probability
``(1 - stay[i]) move[i, j]``, both estimated from the mapping pass's counts with
additive smoothing; then a small uniform term ``eps`` is mixed in,
``T = (1 - eps) K + eps / P``, so that a kidnapped robot (a jump the graph does
not allow) is still reachable and the filter recovers. With odometry (metres
travelled since the previous step), the number of place changes is modelled as
a continuous-time Markov chain in distance: ``K(d) = expm(d / L (M - I))``,
``L`` the mean distance travelled per place change while mapping; a robot
standing still then stays put and a long drive can cross several places.

When the places' positions are known (a map made from a run with poses),
the graph's chain can be replaced by a *metric* kernel
(:meth:`TransitionModel.from_positions`): after travelling ``d`` metres the
robot is at place ``j`` with a weight ``exp(-|c_i - c_j|^2 / (2 (s + d)^2))``
(``s``: the map's place spacing, how far inside a place's cell the robot
may already be). The graph's chain moves on at the mapping run's mean rate
``d / L`` whatever the robot sees, so a belief made sure by a few repeated
views lags a place behind at every place change; the kernel lets the views
decide between neighbours (:func:`check_place_filter` measures both on
the mapping part; docs/RESULTS.md).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._lse import logsumexp  # scipy.special.logsumexp, bit for bit, without its per-call overhead
from .._types import FArray
from ..errors import InvalidParameterError
from ..validation import check_int
from .graph import PlaceGraph

__all__ = [
    "FilterResult",
    "MarkovFilter",
    "PlaceFilterCheck",
    "TransitionModel",
    "check_place_filter",
    "entropy_bits",
    "fit_likelihood_scale",
    "fit_outlier_weight",
    "metres_per_move",
    "run_filter",
]


#: Largest condition number of the move matrix's eigenvectors for the fast odometry path.
EIG_MAX_COND = 1e6
#: Above this many places, odometry predictions propagate the belief vector instead of forming the matrix.
EIG_VECTOR_MIN_PLACES = 100


def _check_distance(distance: Any) -> float:
    d = float(distance)
    if not (math.isfinite(d) and d >= 0):
        raise InvalidParameterError(f"a travelled distance must be a finite number of metres >= 0, got {distance!r}")
    return d


def _lse(x: FArray) -> float:
    """``log sum exp x`` of one row with a finite maximum (faster than scipy's for small rows)."""
    m = float(np.max(x))
    return m + math.log(float(np.sum(np.exp(x - m))))


def _ro(a: Any) -> FArray:
    arr = np.array(a, dtype=np.float64)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, slots=True)
class TransitionModel:
    """Stay / move-to-a-neighbour transitions between places, with uniform mixing.

    Attributes
    ----------
    stay : ndarray, shape (P,)
        Probability of staying at each place during one step (no odometry).
    move : ndarray, shape (P, P)
        Row ``i``: where the robot goes when it leaves place ``i`` (rows sum to
        1; a place with no neighbour has ``move[i, i] = 1``).
    uniform_mix : float
        ``eps`` in [0, 1): weight of the uniform transition mixed into every row.
    metres_per_move : float or None
        ``L``, mean metres travelled per place change; used when a step comes
        with a travelled distance. ``None``: distances are ignored.
    centres : ndarray, shape (P, 2), or None
        Place positions (metres): with them the transitions are the metric
        kernel of :meth:`from_positions` (``stay``, ``move`` and
        ``metres_per_move`` are then not used by :meth:`matrix`).
    spread_metres : float or None
        ``s`` of the metric kernel (metres, > 0; with ``centres``).
    """

    stay: FArray
    move: FArray
    uniform_mix: float = 0.0
    metres_per_move: float | None = None
    centres: FArray | None = None
    spread_metres: float | None = None

    def __post_init__(self) -> None:
        stay = np.asarray(self.stay, dtype=np.float64).reshape(-1)
        move = np.asarray(self.move, dtype=np.float64)
        p = stay.size
        if p < 1:
            raise InvalidParameterError("a transition model needs at least one place")
        if move.shape != (p, p):
            raise InvalidParameterError(f"move must have shape ({p}, {p}) to match stay, got {move.shape}")
        if not (np.all(np.isfinite(stay)) and np.all((stay >= 0) & (stay <= 1))):
            raise InvalidParameterError("stay probabilities must be in [0, 1]")
        if not (np.all(np.isfinite(move)) and np.all(move >= 0)) or not np.allclose(move.sum(axis=1), 1.0, atol=1e-9):
            raise InvalidParameterError("move must be non-negative with rows summing to 1")
        if not (0.0 <= self.uniform_mix < 1.0):
            raise InvalidParameterError(f"uniform_mix must be in [0, 1), got {self.uniform_mix!r}")
        if self.metres_per_move is not None and not (math.isfinite(self.metres_per_move) and self.metres_per_move > 0):
            raise InvalidParameterError(
                f"metres_per_move must be a positive number of metres, got {self.metres_per_move!r}"
            )
        object.__setattr__(self, "stay", _ro(stay))
        object.__setattr__(self, "move", _ro(move))
        if (self.centres is None) != (self.spread_metres is None):
            raise InvalidParameterError("centres and spread_metres go together (both or neither)")
        if self.centres is not None:
            c = np.asarray(self.centres, dtype=np.float64)
            if c.shape != (p, 2) or not np.all(np.isfinite(c)):
                raise InvalidParameterError(f"centres must be a finite array of shape ({p}, 2), got {c.shape}")
            sp = self.spread_metres
            if not (isinstance(sp, (int, float)) and math.isfinite(sp) and sp > 0):
                raise InvalidParameterError(f"spread_metres must be a positive number of metres, got {sp!r}")
            object.__setattr__(self, "centres", _ro(c))
            object.__setattr__(self, "spread_metres", float(sp))

    @property
    def metric(self) -> bool:
        """True when the transitions are the metric kernel of :meth:`from_positions`."""
        return self.centres is not None

    @property
    def n_places(self) -> int:
        """Number of places ``P``."""
        return int(self.stay.size)

    # -- constructors ------------------------------------------------------------------------------
    @classmethod
    def uniform(cls, n_places: int) -> TransitionModel:
        """Every place equally likely after every step (``T = 1 / P``): the filter is then single-shot."""
        n_places = check_int("n_places", n_places, minimum=1)
        move = np.full((n_places, n_places), 1.0 / max(1, n_places - 1))
        np.fill_diagonal(move, 0.0)
        if n_places == 1:
            move[0, 0] = 1.0
        return cls(stay=np.full(n_places, 1.0 / n_places), move=move)

    @classmethod
    def from_graph(
        cls,
        graph: PlaceGraph,
        places: Sequence[str] | None = None,
        *,
        alpha: float = 1.0,
        uniform_mix: float | None = None,
        metres_per_move: float | None = None,
        symmetric: bool = True,
    ) -> TransitionModel:
        """Estimate stay / move probabilities from the graph's counts.

        With ``C`` the count matrix (``C[i, i]`` steps spent at ``i``,
        ``C[i, j]`` passages ``i -> j``) and ``a = alpha``::

            stay[i]    = (C[i, i] + a) / (C[i, i] + out_i + 2 a)      # out_i = sum_{j != i} C[i, j]
            move[i, j] = (S[i, j] + a) / sum_{k in N(i)} (S[i, k] + a)  for j in N(i)

        ``S = C + C^T`` off the diagonal when ``symmetric`` (a corridor is
        usable both ways), ``N(i)`` the neighbours of ``i`` in the graph.

        Parameters
        ----------
        graph : PlaceGraph
        places : sequence of str, optional
            Row / column order (default the graph's); use the model's ``classes_``.
        alpha : float, default 1.0
            Additive (Laplace) smoothing of the counts, >= 0.
        uniform_mix : float, optional
            ``eps``; default ``1 / (N + 2)`` with ``N`` the number of counted
            steps: Laplace's rule of succession for an event (a jump the graph
            does not explain) never seen in ``N`` steps of mapping.
        metres_per_move : float, optional
            ``L`` for odometry (see :func:`metres_per_move`).
        symmetric : bool, default True
        """
        if not (math.isfinite(alpha) and alpha >= 0):
            raise InvalidParameterError(f"alpha must be a finite number >= 0, got {alpha!r}")
        c = graph.count_matrix(places)
        p = c.shape[0]
        diag = np.diag(c).copy()
        off = c - np.diag(diag)
        out = off.sum(axis=1)
        denom = diag + out + 2 * alpha
        stay = np.divide(diag + alpha, denom, out=np.ones(p), where=denom > 0)
        adj = graph.adjacency(places, symmetric=symmetric)
        s = off + off.T if symmetric else off
        w = np.where(adj, s + alpha, 0.0)
        rows = w.sum(axis=1)
        move = np.divide(w, rows[:, None], out=np.zeros((p, p)), where=rows[:, None] > 0)
        for i in np.flatnonzero(rows <= 0):
            nb = np.flatnonzero(adj[i])
            if nb.size:  # adjacent places with zero weight (alpha = 0, no count): spread evenly
                move[i, nb] = 1.0 / nb.size
            else:  # no neighbour at all: the robot can only stay
                move[i, i] = 1.0
                stay[i] = 1.0
        if uniform_mix is None:
            uniform_mix = 1.0 / (float(c.sum()) + 2.0)
        return cls(stay=stay, move=move, uniform_mix=float(uniform_mix), metres_per_move=metres_per_move)

    @classmethod
    def from_positions(
        cls, centres: Any, spread_metres: float, *, uniform_mix: float = 0.0
    ) -> TransitionModel:
        """The metric kernel over places at known positions (module docstring).

        After a step of ``d`` metres (0 when the step has no distance) from
        place ``i`` the robot is at place ``j`` with probability
        proportional to ``exp(-|c_i - c_j|^2 / (2 (spread_metres + d)^2))``;
        then ``uniform_mix`` of the uniform transition is mixed in, as for
        :meth:`from_graph`.

        Parameters
        ----------
        centres : array_like, shape (P, 2)
            Place positions, metres.
        spread_metres : float
            ``s`` (> 0), e.g. the map's place spacing.
        uniform_mix : float, default 0.0
            ``eps``, e.g. ``1 / (N + 2)`` for ``N`` counted steps of mapping.
        """
        c = np.asarray(centres, dtype=np.float64)
        if c.ndim != 2 or c.shape[1] != 2 or c.shape[0] < 1:
            raise InvalidParameterError(f"centres must have shape (P >= 1, 2), got {c.shape}")
        p = c.shape[0]
        k = _metric_kernel(_squared_distances(c), float(spread_metres)) if math.isfinite(float(spread_metres)) and float(spread_metres) > 0 else np.eye(p)
        stay = np.diag(k).copy()
        off = k - np.diag(stay)
        rows = off.sum(axis=1)
        move = np.divide(off, rows[:, None], out=np.eye(p), where=rows[:, None] > 0)
        return cls(stay=np.clip(stay, 0.0, 1.0), move=move, uniform_mix=float(uniform_mix), centres=c,
                   spread_metres=spread_metres)  # fmt: skip

    # -- the matrix ----------------------------------------------------------------------------------
    def matrix(self, distance: float | None = None) -> FArray:
        """Transition matrix ``T[i, j] = P(x_t = j | x_{t-1} = i)``, shape (P, P), rows sum to 1.

        Parameters
        ----------
        distance : float, optional
            Metres travelled during the step (odometry). Used only when
            :attr:`metres_per_move` is set: ``K = expm(d / L (move - I))``;
            otherwise ``K = diag(stay) + diag(1 - stay) move``.
        """
        p = self.n_places
        if self.centres is not None:
            d = 0.0 if distance is None else _check_distance(distance)
            assert self.spread_metres is not None
            k = _metric_kernel(_squared_distances(self.centres), self.spread_metres + d)
        elif distance is not None and self.metres_per_move is not None:
            d = _check_distance(distance)
            rate = d / self.metres_per_move
            from scipy.linalg import expm  # imported when used: localize never needs it

            k = expm(rate * (self.move - np.eye(p))) if rate > 0 else np.eye(p)
            k = np.clip(k, 0.0, None)
            k /= k.sum(axis=1, keepdims=True)
        else:
            k = np.diag(self.stay) + (1.0 - self.stay)[:, None] * self.move
        eps = self.uniform_mix
        return (1.0 - eps) * k + eps / p  # T = (1 - eps) K + eps / P


def _squared_distances(centres: FArray) -> FArray:
    """Squared distances between the rows of ``centres``, shape (P, P)."""
    c = np.asarray(centres, dtype=np.float64)
    return np.asarray(((c[:, None, :] - c[None, :, :]) ** 2).sum(axis=2), dtype=np.float64)


def _metric_kernel(sq: FArray, scale: float) -> FArray:
    """Rows ``exp(-sq / (2 scale^2))`` normalised to sum to 1."""
    k = np.exp(-0.5 * sq / (scale * scale))
    return np.asarray(k / k.sum(axis=1, keepdims=True), dtype=np.float64)


def metres_per_move(positions: Any, places: Any) -> float:
    """Mean metres travelled per change of place along a trajectory (``L`` of :class:`TransitionModel`).

    Parameters
    ----------
    positions : array_like, shape (n, 2)
        Robot positions at the steps, metres.
    places : array_like of int, shape (n,)
        Place at each step (``-1`` = none; a change to or from ``-1`` is not counted).

    Returns
    -------
    float
        Total distance / number of place changes (the total distance when
        there is no change, so the estimate stays finite).
    """
    pos = np.asarray(positions, dtype=np.float64).reshape(-1, 2)
    lab = np.asarray(places, dtype=np.int64).reshape(-1)
    if pos.shape[0] != lab.size:
        raise InvalidParameterError(
            f"positions and places must have the same length, got {pos.shape[0]} and {lab.size}"
        )
    if lab.size < 2:
        raise InvalidParameterError("metres_per_move needs at least two steps")
    dist = float(np.hypot(*np.diff(pos, axis=0).T).sum())
    changes = int(np.sum((lab[1:] != lab[:-1]) & (lab[1:] >= 0) & (lab[:-1] >= 0)))
    return dist / max(changes, 1) if dist > 0 else 1.0


def entropy_bits(log_p: Any) -> FArray:
    """Entropy of log-probability rows, bits, shape (n,) (or a float for one row); ``0 log 0 = 0``."""
    lp = np.asarray(log_p, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        terms = np.where(np.isneginf(lp), 0.0, np.exp(lp) * lp)
    h = -terms.sum(axis=-1) / math.log(2.0)
    return np.maximum(h, 0.0)


def fit_likelihood_scale(scores: Any, labels: Any, *, bounds: tuple[float, float] = (1e-3, 1e3)) -> float:
    """The scale ``beta`` making ``beta * scores`` calibrated log-likelihoods.

    Maximises the mean log-probability of the true place under
    ``softmax(beta * scores)`` over held-out rows (rows whose true place
    scores ``-inf`` are left out). This turns any method's scores (a
    similarity, a negative distance, an overconfident log-likelihood) into the
    per-step log-likelihoods the filter needs; choose it on data that are not
    the queries (the mapping pass, cross-validated).

    Parameters
    ----------
    scores : array_like, shape (n, P)
        Higher = more likely; ``-inf`` allowed.
    labels : array_like of int, shape (n,)
    bounds : (float, float)
        Search interval of ``beta``.

    Returns
    -------
    float
    """
    s = np.asarray(scores, dtype=np.float64)
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    if s.ndim != 2 or s.shape[0] != y.size:
        raise InvalidParameterError(f"scores must have shape (n, P) with n = {y.size}, got {s.shape}")
    if not (0 < bounds[0] < bounds[1]):
        raise InvalidParameterError(f"bounds must satisfy 0 < low < high, got {bounds!r}")
    s = np.where(np.isnan(s), -np.inf, s)
    keep = np.isfinite(s[np.arange(y.size), y]) if y.size else np.zeros(0, bool)
    s, y = s[keep], y[keep]
    if y.size == 0:
        raise InvalidParameterError("fit_likelihood_scale needs at least one row whose true place scores > -inf")
    # shift each row so its finite maximum is 0 (softmax is shift-invariant)
    finite_max = np.max(np.where(np.isfinite(s), s, -np.inf), axis=1, keepdims=True)
    s = s - finite_max
    true = s[np.arange(y.size), y]

    def nll(log_beta: float) -> float:
        b = math.exp(log_beta)
        return float(-(b * true - logsumexp(b * s, axis=1)).mean())

    from scipy.optimize import minimize_scalar

    res = minimize_scalar(nll, bounds=(math.log(bounds[0]), math.log(bounds[1])), method="bounded",
                          options={"xatol": 1e-4})  # fmt: skip
    return float(math.exp(res.x))


def fit_outlier_weight(log_likelihood: Any, labels: Any, *, bounds: tuple[float, float] = (1e-4, 0.999)) -> float:
    """How often a front end's answer is noise: ``rho`` of the robust likelihood ``(1 - rho) softmax(l) + rho / P``.

    The reliability the sensor has proved on held-out data (the mapping
    pass, cross-validated, as for :func:`fit_likelihood_scale`): ``rho``
    maximises the mean log-probability of the true place under the robust
    likelihood. A front end whose calibrated answers are seldom wrong gets a
    small ``rho`` (an observation can overrule the motion model); one whose
    confident answers are often wrong gets a large one.

    Parameters
    ----------
    log_likelihood : array_like, shape (n, P)
        Calibrated log-likelihood rows (``beta`` times the scores); ``-inf`` allowed.
    labels : array_like of int, shape (n,)
    bounds : (float, float)
        Search interval of ``rho``, inside ``(0, 1)``.

    Returns
    -------
    float
    """
    s = np.asarray(log_likelihood, dtype=np.float64)
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    if s.ndim != 2 or s.shape[0] != y.size or s.shape[1] < 1:
        raise InvalidParameterError(f"log_likelihood must have shape (n, P) with n = {y.size}, got {s.shape}")
    if not (0 < bounds[0] < bounds[1] < 1):
        raise InvalidParameterError(f"bounds must satisfy 0 < low < high < 1, got {bounds!r}")
    s = np.where(np.isnan(s), -np.inf, s)
    keep = np.any(np.isfinite(s), axis=1)
    s, y = s[keep], y[keep]
    if y.size == 0:
        raise InvalidParameterError("fit_outlier_weight needs at least one row with a finite entry")
    p = s.shape[1]
    soft = s[np.arange(y.size), y] - logsumexp(s, axis=1)  # log softmax of the true place (may be -inf)

    def nll(rho: float) -> float:
        return float(-np.mean(np.logaddexp(math.log1p(-rho) + soft, math.log(rho / p))))

    from scipy.optimize import minimize_scalar

    res = minimize_scalar(nll, bounds=bounds, method="bounded", options={"xatol": 1e-5})
    return float(res.x)


class MarkovFilter:
    """Step-by-step discrete Bayes filter over places, in log space.

    Parameters
    ----------
    transition : TransitionModel
    prior : array_like, shape (P,), optional
        Initial belief (probabilities, normalised here); uniform by default.

    Attributes
    ----------
    log_belief_ : ndarray, shape (P,)
        The current log-posterior (after :meth:`update`) or log-prediction.
    n_steps_ : int
        Steps taken since :meth:`reset`.
    """

    def __init__(self, transition: TransitionModel, *, prior: Any = None) -> None:
        self.transition = transition
        self.prior = prior
        self._fixed: FArray | None = None
        self._eig: tuple[Any, ...] | None = None
        self._sq: FArray | None = None
        self.reset()

    def reset(self) -> MarkovFilter:
        """Back to the prior."""
        p = self.transition.n_places
        if self.prior is None:
            lb = np.full(p, -math.log(p))
        else:
            pr = np.asarray(self.prior, dtype=np.float64).reshape(-1)
            if pr.size != p or not np.all(np.isfinite(pr)) or np.any(pr < 0) or pr.sum() <= 0:
                raise InvalidParameterError(f"prior must be {p} non-negative finite numbers, not all 0")
            with np.errstate(divide="ignore"):
                lb = np.log(pr / pr.sum())
        self.log_belief_: FArray = lb
        self.n_steps_ = 0
        return self

    def _eigen(self) -> bool:
        """Build (once) ``M - I = V diag(w) V^-1``; False when ``V`` is too ill-conditioned to use."""
        if self._eig is None:
            t = self.transition
            w, v = np.linalg.eig(t.move - np.eye(t.n_places))
            ok = np.linalg.cond(v) < EIG_MAX_COND
            self._eig = (w, v, np.linalg.inv(v)) if ok else ()
        return bool(self._eig)

    def transition_matrix(self, distance: float | None = None) -> FArray:
        """:meth:`TransitionModel.matrix`, cached; with odometry through one eigendecomposition.

        ``expm(r (M - I)) = V diag(exp(r w)) V^-1`` with ``M - I = V diag(w) V^-1``,
        computed once per filter (a move matrix from symmetric counts is similar
        to a symmetric one, so ``V`` is well conditioned); falls back to
        :func:`scipy.linalg.expm` when it is not.
        """
        t = self.transition
        if t.centres is not None:
            assert t.spread_metres is not None
            if self._sq is None:
                self._sq = _squared_distances(t.centres)
            d = 0.0 if distance is None else _check_distance(distance)
            if d == 0.0 and self._fixed is not None:
                return self._fixed
            k = _metric_kernel(self._sq, t.spread_metres + d)
            out = (1.0 - t.uniform_mix) * k + t.uniform_mix / t.n_places
            if d == 0.0:
                self._fixed = out
            return out
        if distance is None or t.metres_per_move is None:
            if self._fixed is None:
                self._fixed = t.matrix()
            return self._fixed
        d = _check_distance(distance)
        if not self._eigen():
            return t.matrix(d)
        w, v, vinv = self._eig  # type: ignore[misc]
        k = np.real((v * np.exp(d / t.metres_per_move * w)) @ vinv)
        k = np.clip(k, 0.0, None)
        k /= k.sum(axis=1, keepdims=True)
        eps = t.uniform_mix
        return (1.0 - eps) * k + eps / t.n_places

    def predict(self, distance: float | None = None) -> FArray:
        """Apply the transition model: ``b^-(j) = sum_i b(i) T[i, j]`` (log space); returns the log-prediction."""
        b = self.log_belief_
        m = float(np.max(b))
        p = np.exp(b - m)  # belief scaled by exp(-max b)
        tm = self.transition
        if (
            distance is not None
            and tm.centres is None
            and tm.metres_per_move is not None
            and tm.n_places > EIG_VECTOR_MIN_PLACES
            and _check_distance(distance) >= 0
            and self._eigen()
        ):
            # b K = ((b V) exp(r w)) V^-1: O(P^2) instead of forming K
            w, v, vinv = self._eig  # type: ignore[misc]
            q = np.clip(np.real(((p @ v) * np.exp(float(distance) / tm.metres_per_move * w)) @ vinv), 0.0, None)
            q *= p.sum() / q.sum()
            q = (1.0 - tm.uniform_mix) * q + tm.uniform_mix * p.sum() / tm.n_places
        else:
            q = p @ self.transition_matrix(distance)  # sum_i b_i T_ij
        with np.errstate(divide="ignore"):
            pred = np.log(q) + m
        self.log_belief_ = pred - _lse(pred)
        return self.log_belief_.copy()

    def update(self, log_likelihood: Any) -> FArray:
        """Multiply in one observation's likelihood: ``b(j) ∝ b^-(j) P(z | j)`` (log space).

        Parameters
        ----------
        log_likelihood : array_like, shape (P,) or None
            Per-place log-likelihood (any additive constant); ``-inf`` = the
            place cannot have produced the observation. ``None`` or a row of
            NaN = no observation (the belief is unchanged). When no place with
            predicted mass can explain the observation, it is ignored (no NaN).

        Returns
        -------
        ndarray, shape (P,)
            The log-posterior.
        """
        if log_likelihood is None:
            return self.log_belief_.copy()
        ll = np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        p = self.transition.n_places
        if ll.size != p:
            raise InvalidParameterError(f"a log-likelihood row must have {p} entries, got {ll.size}")
        nan = np.isnan(ll)
        if np.all(nan):
            return self.log_belief_.copy()
        if np.any(nan) or np.any(ll == np.inf):
            raise InvalidParameterError("a log-likelihood row must be all NaN (no observation) or hold no NaN / +inf")
        post = self.log_belief_ + ll
        if not np.any(np.isfinite(post)):
            return self.log_belief_.copy()
        self.log_belief_ = post - _lse(post)
        return self.log_belief_.copy()

    def step(self, log_likelihood: Any = None, distance: float | None = None) -> FArray:
        """One filter step: predict (except on the very first step), then update; returns the log-posterior."""
        if self.n_steps_ > 0:
            self.predict(distance)
        self.n_steps_ += 1
        return self.update(log_likelihood)


@dataclass(frozen=True, slots=True)
class FilterResult:
    """Output of :func:`run_filter`.

    Attributes
    ----------
    log_posterior : ndarray, shape (n_steps, P)
        Log-posterior after each step.
    best : ndarray of int, shape (n_steps,)
        Most probable place per step (lowest index among ties).
    best_probability : ndarray, shape (n_steps,)
    entropy_bits : ndarray, shape (n_steps,)
    """

    log_posterior: FArray
    best: NDArray[np.int64]
    best_probability: FArray
    entropy_bits: FArray

    @classmethod
    def from_log_posterior(cls, log_posterior: Any) -> FilterResult:
        """The result of a sequence of log-posteriors, shape (n_steps, P)."""
        out = np.asarray(log_posterior, dtype=np.float64)
        n = out.shape[0]
        best = np.argmax(out, axis=1).astype(np.int64) if n else np.zeros(0, np.int64)
        return cls(
            log_posterior=out,
            best=best,
            best_probability=np.exp(out[np.arange(n), best]) if n else np.zeros(0),
            entropy_bits=entropy_bits(out) if n else np.zeros(0),
        )


class SharedPlaceSteps:
    """The beliefs of a :class:`MarkovFilter` along one run, recorded once and replayed (private).

    Several pose-filter runs that differ only in the pose filter's settings
    (:func:`fingerloc.pipeline.tracker.tune_pose_filter`'s grid) run the same
    place filter alongside on the same steps. :meth:`filter` gives a filter
    over ``transition`` that records each call's resulting belief on the
    first run and, on the next runs, takes the recorded belief while its
    calls are the same (``predict`` with the same distance, ``update`` with
    the same row, the same transition model); from the first call that
    differs it computes for itself (its state is its belief). The beliefs
    are those it would compute: the computation is deterministic.
    """

    def __init__(self) -> None:
        self.transition: TransitionModel | None = None
        self.calls: list[tuple[tuple[Any, ...], FArray]] = []

    def filter(self, transition: TransitionModel) -> MarkovFilter:
        """A place filter over ``transition`` that uses (and extends) the record."""
        if self.transition is None:
            self.transition = transition
        same = self.transition is transition or (
            self.transition.metres_per_move == transition.metres_per_move
            and self.transition.uniform_mix == transition.uniform_mix
            and self.transition.stay.tobytes() == np.asarray(transition.stay).tobytes()
            and self.transition.move.tobytes() == np.asarray(transition.move).tobytes()
            and self.transition.spread_metres == transition.spread_metres
            and _same_centres(self.transition.centres, transition.centres)
        )
        return _ReplayMarkovFilter(transition, self if same else None)


def _same_centres(a: FArray | None, b: FArray | None) -> bool:
    if a is None or b is None:
        return a is None and b is None
    return a.tobytes() == np.asarray(b).tobytes()


class _ReplayMarkovFilter(MarkovFilter):
    """A :class:`MarkovFilter` that replays :class:`SharedPlaceSteps` while its calls match."""

    def __init__(self, transition: TransitionModel, record: SharedPlaceSteps | None) -> None:
        self._record = record
        self._i = 0
        self._own = record is None
        super().__init__(transition)

    def reset(self) -> MarkovFilter:
        super().reset()
        self._i, self._own = 0, self._record is None
        return self

    def _step(self, key: tuple[Any, ...], live: Any) -> FArray:
        rec, i = self._record, self._i
        self._i = i + 1
        if not self._own and rec is not None:
            if i < len(rec.calls):
                if rec.calls[i][0] == key:
                    self.log_belief_ = rec.calls[i][1].copy()
                    return self.log_belief_.copy()
                self._own = True
            else:
                out = live()
                rec.calls.append((key, self.log_belief_.copy()))
                return out
        return live()  # type: ignore[no-any-return]

    def predict(self, distance: float | None = None) -> FArray:
        key = ("predict", None if distance is None else float(distance))
        return self._step(key, lambda: MarkovFilter.predict(self, distance))

    def update(self, log_likelihood: Any) -> FArray:
        row = None if log_likelihood is None else np.asarray(log_likelihood, dtype=np.float64)
        key = ("update", None if row is None else (row.shape, row.tobytes()))
        return self._step(key, lambda: MarkovFilter.update(self, log_likelihood))


def run_filter(
    log_likelihood: Any,
    transition: TransitionModel,
    *,
    distances: Any = None,
    observed: Any = None,
    prior: Any = None,
) -> FilterResult:
    """Filter a sequence of per-step log-likelihoods along a trajectory.

    Parameters
    ----------
    log_likelihood : array_like, shape (n_steps, P)
        Row ``t``: the single-shot log-likelihood of each place at step ``t``
        (unnormalised is fine); a row of NaN = no observation (prediction only).
    transition : TransitionModel
    distances : array_like, shape (n_steps,), optional
        Metres travelled from step ``t - 1`` to step ``t`` (entry 0 unused);
        used when ``transition.metres_per_move`` is set.
    observed : array_like of bool, shape (n_steps,), optional
        False marks prediction-only steps (whatever their row holds).
    prior : array_like, shape (P,), optional
        Belief before the first step (uniform by default).

    Returns
    -------
    FilterResult
    """
    ll = np.asarray(log_likelihood, dtype=np.float64)
    if ll.ndim != 2 or ll.shape[1] != transition.n_places:
        raise InvalidParameterError(f"log_likelihood must have shape (n_steps, {transition.n_places}), got {ll.shape}")
    n = ll.shape[0]
    dist = None if distances is None else np.asarray(distances, dtype=np.float64).reshape(-1)
    if dist is not None and dist.size != n:
        raise InvalidParameterError(f"distances must have one entry per step ({n}), got {dist.size}")
    obs = None if observed is None else np.asarray(observed, dtype=bool).reshape(-1)
    if obs is not None and obs.size != n:
        raise InvalidParameterError(f"observed must have one entry per step ({n}), got {obs.size}")
    f = MarkovFilter(transition, prior=prior)
    out = np.empty_like(ll)
    for t in range(n):
        row = None if (obs is not None and not obs[t]) else ll[t]
        out[t] = f.step(row, None if dist is None else float(dist[t]))
    return FilterResult.from_log_posterior(out)


@dataclass(frozen=True, slots=True)
class PlaceFilterCheck:
    """The place filter against the single shot along a run whose true places are known (:func:`check_place_filter`).

    Attributes
    ----------
    filter_top1, single_top1 : float
        Fraction of the scored steps where the filter's best place (after
        the step's observation), and the step's own best place, is the true one.
    rows : int
        Scored steps.
    use_filter : bool
        ``filter_top1 >= single_top1``: the filter earns its keep (ties: the filter).
    """

    filter_top1: float
    single_top1: float
    rows: int
    use_filter: bool

    def reason(self) -> str:
        """One line: which answer and why."""
        what = "filtering" if self.use_filter else "answering the single shot"
        return (
            f"the place filter is right at {self.filter_top1:.2f} of {self.rows} held-out mapping views, the single "
            f"shot at {self.single_top1:.2f}: {what}"
        )

    def to_json(self) -> dict[str, Any]:
        """Every field."""
        return {"filter_top1": self.filter_top1, "single_top1": self.single_top1, "rows": self.rows,
                "use_filter": self.use_filter}  # fmt: skip


def check_place_filter(
    log_likelihood: Any, transition: TransitionModel, labels: Any, *, distances: Any = None
) -> PlaceFilterCheck:
    """Does the discrete filter beat the single shot along a run whose true places are known (the mapping part)?

    Parameters
    ----------
    log_likelihood : array_like, shape (n_steps, P)
        Each step's single-shot log-likelihood row (NaN row: no observation),
        e.g. the mapping part's held-out rows (a model fit without each of
        them) at their steps, NaN at the others.
    transition : TransitionModel
    labels : array_like of int, shape (n_steps,)
        True place at the steps to score (``-1``: not scored; a scored step
        must be observed).
    distances : array_like, shape (n_steps,), optional
        Metres travelled into each step (:func:`run_filter`).

    Returns
    -------
    PlaceFilterCheck
    """
    ll = np.asarray(log_likelihood, dtype=np.float64)
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    if ll.ndim != 2 or ll.shape[0] != y.size:
        raise InvalidParameterError(f"log_likelihood must have shape (n_steps, P) with n_steps = {y.size}, got {ll.shape}")
    scored = y >= 0
    if np.any(np.all(np.isnan(ll[scored]), axis=1)):
        raise InvalidParameterError("every scored step needs an observation (a row without NaN)")
    n = int(scored.sum())
    if n == 0:
        return PlaceFilterCheck(0.0, 0.0, 0, False)
    res = run_filter(ll, transition, distances=distances)
    rows = np.where(np.isnan(ll[scored]), -np.inf, ll[scored])
    single = float(np.mean(np.argmax(rows, axis=1) == y[scored]))
    filt = float(np.mean(res.best[scored] == y[scored]))
    return PlaceFilterCheck(filt, single, n, filt >= single)
