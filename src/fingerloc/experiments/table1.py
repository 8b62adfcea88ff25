"""The paper's Table I: classifying simulated places by MOG likelihood (docs/METHOD.md §5).

Protocol (Tapus et al. 2004, section V-A, as restated in docs/METHOD.md §5): ten
synthetic places; for each, four observations of N vertical-edge bearings,
similar but not identical, every bearing disturbed by Gaussian noise of
standard deviation 5 deg; one mixture of k components fit by EM on the union
of a place's four observations (4 N bearings); each of the 40 observations is
then given to the place under whose mixture it is most likely,
``argmax_loc sum_j log p_MOG(x_j | theta_loc)``. The figure is the share of
right answers, averaged over independent trials.

How the places are made alike
-----------------------------
The paper does not say; independent uniform bearings make every cell about
100 %. We simulate from the model the paper itself assumes, ``P(VE | Loc) =
prod_j p(x_j | Loc)``: the vertical edges of an observation are independent
draws from a bearing density of the place. Offices along one corridor share a
layout (door, window frames, shelves, cupboard at about the same bearings),
so one trial draws one *layout* of ``n_edges`` edge bearings uniformly on the
circle, shared by the ten places, and each place moves every edge by its own
Gaussian offset of standard deviation ``place_spread_deg``. An observation of
N features picks N of its place's edges at random (independently, so an edge
may be seen twice, as by two nearby detections) and disturbs each bearing by
the 5 deg noise. The four observations of a place are thus similar but not
identical: other draws, other noise.

``place_spread_deg`` says how alike the places are: 0 makes ten identical
places, large values independent ones (~100 %). Even identical places score
above chance (10 %) because each observation is among the training data of
its own place's mixture (the paper's protocol), an advantage that shrinks as
N grows.
``n_edges`` defaults to 6, the paper's own count of vertical edges per real
office measurement (5.6, Table II). The default spread,
:data:`DEFAULT_PLACE_SPREAD_DEG`, is the value whose mean accuracy over the 21
cells is closest to the paper's mean (sweep in docs/RESULTS.md): that single
number sets the overall level; the trends across k and N, and the table's
shape, are not fitted.

We first tried places that share the *same* N features, each place moving
each one (observations = the place's N bearings plus noise). That gives the
"more components help" trend but not "more features help": a k-component
mixture summarises N > k features, the per-feature offsets of two places
average out inside a component as N grows while the evidence grows with N, and
the two cancel (accuracy flat in N; figures in docs/RESULTS.md). Drawing an
observation's features from a place density, as the paper's model does,
makes the evidence grow with N.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from ..errors import InvalidParameterError
from ..mog import DEFAULT_MIN_SIGMA_DEG, DEFAULT_N_INIT, fit_mixtures, mixture_log_density
from ..parallel import check_cluster_options, run_tasks

__all__ = [
    "DEFAULT_N_EDGES",
    "DEFAULT_PLACE_SPREAD_DEG",
    "PAPER_K",
    "PAPER_N",
    "PAPER_TABLE1",
    "Table1Result",
    "make_observations",
    "make_places",
    "run_table1",
]

#: Components per mixture in the paper's rows.
PAPER_K: tuple[int, ...] = (3, 4, 5)
#: Features per observation in the paper's columns.
PAPER_N: tuple[int, ...] = (5, 10, 15, 20, 25, 30, 35)
#: The paper's Table I, right classifications in percent, rows k = 3, 4, 5.
PAPER_TABLE1: tuple[tuple[float, ...], ...] = (
    (55.5, 81.5, 93.0, 93.5, 96.0, 97.5, 99.5),
    (66.5, 93.0, 98.0, 95.0, 98.0, 99.5, 99.0),
    (80.0, 98.5, 98.0, 99.5, 100.0, 99.5, 100.0),
)
#: Default standard deviation (deg) of a place's offset of each shared layout edge.
DEFAULT_PLACE_SPREAD_DEG = 10.0
#: Default number of edges of the shared layout (the paper's 5.6 VE per real measurement).
DEFAULT_N_EDGES = 6


@dataclass(frozen=True, slots=True)
class Table1Result:
    """Accuracies of the Table I protocol.

    Attributes
    ----------
    k : tuple of int
        Components, one per row.
    n : tuple of int
        Features per observation, one per column.
    per_trial : ndarray, shape (trials, len(k), len(n))
        Share of the observations classified right, in [0, 1], per trial.
    params : dict
        The generator and EM settings (JSON-ready).
    """

    k: tuple[int, ...]
    n: tuple[int, ...]
    per_trial: NDArray[np.float64]
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def accuracy(self) -> NDArray[np.float64]:
        """Mean accuracy over trials, shape (len(k), len(n)), in [0, 1]."""
        return np.asarray(self.per_trial.mean(axis=0), dtype=np.float64)

    @property
    def stderr(self) -> NDArray[np.float64]:
        """Standard error of the mean over trials, shape (len(k), len(n)) (0 for one trial)."""
        t = self.per_trial.shape[0]
        if t < 2:
            return np.zeros(self.per_trial.shape[1:])
        return np.asarray(self.per_trial.std(axis=0, ddof=1) / np.sqrt(t), dtype=np.float64)

    def paper(self) -> NDArray[np.float64] | None:
        """The paper's cells for these k and n, in [0, 1], or None if some cell is not in the paper."""
        if not (set(self.k) <= set(PAPER_K) and set(self.n) <= set(PAPER_N)):
            return None
        tab = np.asarray(PAPER_TABLE1) / 100.0
        return np.asarray(tab[np.ix_([PAPER_K.index(k) for k in self.k], [PAPER_N.index(n) for n in self.n])])

    def to_json(self) -> dict[str, Any]:
        """``{"k", "N", "accuracy", "stderr", "paper", ...settings}``, accuracies in [0, 1]."""
        paper = self.paper()
        return {
            "k": list(self.k),
            "N": list(self.n),
            "accuracy": np.round(self.accuracy, 6).tolist(),
            "stderr": np.round(self.stderr, 6).tolist(),
            "paper": None if paper is None else paper.tolist(),
            "trials": int(self.per_trial.shape[0]),
            **self.params,
        }


def make_places(rng: np.random.Generator, n_places: int, n_edges: int, place_spread_deg: float) -> NDArray[np.float64]:
    """Edge bearings of ``n_places`` alike places: one shared layout, moved per place.

    Parameters
    ----------
    rng : numpy.random.Generator
    n_places, n_edges : int
    place_spread_deg : float
        Standard deviation (deg) of each place's offset of each layout edge.

    Returns
    -------
    ndarray, shape (n_places, n_edges)
        Bearings in radians (not wrapped).
    """
    layout = rng.uniform(-np.pi, np.pi, n_edges)
    return np.asarray(layout + rng.normal(0.0, np.deg2rad(place_spread_deg), (n_places, n_edges)))


def make_observations(
    rng: np.random.Generator, places: NDArray[np.float64], n_observations: int, n_features: int, noise_deg: float
) -> NDArray[np.float64]:
    """Observations of each place: features drawn from its edges, plus bearing noise.

    Parameters
    ----------
    rng : numpy.random.Generator
    places : ndarray, shape (n_places, n_edges)
        Edge bearings (radians), from :func:`make_places`.
    n_observations, n_features : int
    noise_deg : float
        Standard deviation of the bearing noise, degrees.

    Returns
    -------
    ndarray, shape (n_places, n_observations, n_features)
        Bearings in radians (not wrapped).
    """
    n_places, n_edges = places.shape
    pick = rng.integers(0, n_edges, (n_places, n_observations, n_features))
    edges = np.take_along_axis(np.broadcast_to(places[:, None, :], (n_places, n_observations, n_edges)), pick, axis=2)
    return np.asarray(edges + rng.normal(0.0, np.deg2rad(noise_deg), edges.shape))


def _check(name: str, values: Sequence[int], minimum: int) -> tuple[int, ...]:
    out = tuple(int(v) for v in values)
    if not out or any(v < minimum for v in out):
        raise InvalidParameterError(f"{name} must be a non-empty list of ints >= {minimum}, got {list(values)}")
    return out


@dataclass(frozen=True)
class _Trial:
    """One Table I trial: its observations and the generator state of each fit (picklable, for Dask)."""

    obs: NDArray[np.float64]  # (places, observations, n_max) bearings, radians
    states: tuple[dict[str, Any], ...]  # per k: the bit generator state fit_mixtures starts from
    ks: tuple[int, ...]
    ns: tuple[int, ...]
    held_out: bool
    n_init: int
    min_sigma_deg: float


def _run_trial(task: _Trial) -> NDArray[np.float64]:
    """Accuracies of one trial, shape (len(ks), len(ns))."""
    obs = task.obs
    n_places, n_observations = obs.shape[0], obs.shape[1]
    ns_t, held_out = task.ns, task.held_out
    truth = np.repeat(np.arange(n_places), n_observations)  # label of each observation
    n_obs_all = n_places * n_observations
    out = np.empty((len(task.ks), len(ns_t)))
    for a, k in enumerate(task.ks):
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = task.states[a]
        samples = [obs[p, :, :n].ravel() for n in ns_t for p in range(n_places)]
        if held_out:  # one more mixture per observation: its place without it
            samples += [
                np.delete(obs[p, :, :n], o, axis=0).ravel()
                for n in ns_t
                for p in range(n_places)
                for o in range(n_observations)
            ]
        fit = fit_mixtures(samples, k, n_init=task.n_init, min_sigma_deg=task.min_sigma_deg, random_state=rng)
        base = len(ns_t) * n_places
        for b, n in enumerate(ns_t):
            sl = slice(b * n_places, (b + 1) * n_places)
            x = obs[:, :, :n].reshape(-1)  # (places * observations * n,)
            ll = mixture_log_density(x, fit.weights[sl], fit.means[sl], fit.sigmas[sl])
            score = ll.reshape(n_places, n_obs_all, n).sum(axis=2)  # (model, observation)
            if held_out:
                lo = slice(base + b * n_obs_all, base + (b + 1) * n_obs_all)
                own = mixture_log_density(x, fit.weights[lo], fit.means[lo], fit.sigmas[lo])
                own_score = own.reshape(n_obs_all, n_obs_all, n).sum(axis=2).diagonal()
                score[truth, np.arange(n_obs_all)] = own_score
            out[a, b] = float(np.mean(score.argmax(axis=0) == truth))
    return out


def run_table1(
    *,
    trials: int = 20,
    seed: int = 0,
    ks: Sequence[int] = PAPER_K,
    ns: Sequence[int] = PAPER_N,
    n_places: int = 10,
    n_observations: int = 4,
    n_edges: int = DEFAULT_N_EDGES,
    observation_model: str = "draws",
    evaluation: str = "resubstitution",
    noise_deg: float = 5.0,
    place_spread_deg: float = DEFAULT_PLACE_SPREAD_DEG,
    n_init: int = DEFAULT_N_INIT,
    min_sigma_deg: float = DEFAULT_MIN_SIGMA_DEG,
    on_trial: Callable[[int], None] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
) -> Table1Result:
    """Run the Table I protocol (module docstring) and return the accuracies.

    Parameters
    ----------
    trials : int
        Independent repetitions (new layout, places and noise each).
    seed : int
        Seed of everything random (data and EM seeding).
    ks, ns : sequence of int
        Components per mixture (rows) and features per observation (columns).
    n_places, n_observations : int
        Places (10 in the paper) and observations per place (4).
    n_edges : int
        Edges of the shared layout, hence of every place (module docstring).
        Ignored by the ``"fixed"`` model.
    observation_model : {"draws", "fixed"}
        ``"draws"`` (default): an observation's N features are drawn from its
        place's edges (module docstring). ``"fixed"``: the layout has N
        features, each place moves each one, and every observation is its
        place's N bearings plus noise (the first generator we tried).
    evaluation : {"resubstitution", "held-out"}
        ``"resubstitution"`` (default, the paper's protocol as docs/METHOD.md reads
        it): an observation is scored against its place's mixture fit on all
        four observations, itself included. ``"held-out"``: against a mixture
        of its place fit on the other three (the other places keep all four).
    noise_deg : float
        Bearing noise of an observation, standard deviation in degrees (5).
    place_spread_deg : float
        How different the places are (module docstring); degrees, >= 0.
    n_init, min_sigma_deg : passed to :func:`fingerloc.mog.fit_mixtures`.
    on_trial : callable, optional
        Called with the number of trials done after each trial.
    workers, scheduler : optional
        Run the trials on a Dask cluster (see :func:`fingerloc.parallel.run_tasks`):
        ``workers`` local worker processes, or the scheduler at this address.
        The result is the same as the serial run's.
    """
    check_cluster_options(workers, scheduler)
    ks_t = _check("ks", ks, 1)
    ns_t = _check("ns", ns, 1)
    if not isinstance(trials, int) or trials < 1:
        raise InvalidParameterError(f"trials must be an int >= 1, got {trials!r}")
    if evaluation not in ("resubstitution", "held-out"):
        raise InvalidParameterError(f"evaluation must be 'resubstitution' or 'held-out', got {evaluation!r}")
    held_out = evaluation == "held-out"
    if held_out and n_observations < 2:
        raise InvalidParameterError("held-out evaluation needs n_observations >= 2")
    if observation_model not in ("draws", "fixed"):
        raise InvalidParameterError(f"observation_model must be 'draws' or 'fixed', got {observation_model!r}")
    if n_places < 2 or n_observations < 1 or n_edges < 1:
        raise InvalidParameterError(
            f"need n_places >= 2, n_observations >= 1 and n_edges >= 1, got {n_places}, {n_observations}, {n_edges}"
        )
    for name, v in (("noise_deg", noise_deg), ("place_spread_deg", place_spread_deg)):
        if not (np.isfinite(v) and v >= 0):
            raise InvalidParameterError(f"{name} must be a finite number >= 0, got {v!r}")
    rng = np.random.default_rng(seed)
    n_max = max(ns_t)
    n_samples = len(ns_t) * n_places * (1 + (n_observations if held_out else 0))  # mixtures per fit_mixtures call
    # The data of every trial, and the generator state each fit_mixtures call starts from, are drawn here in
    # the serial order (so the figures do not depend on how the trials run); the fits run as independent tasks.
    tasks: list[_Trial] = []
    for _ in range(trials):
        if observation_model == "draws":
            places = make_places(rng, n_places, n_edges, place_spread_deg)
            obs = make_observations(rng, places, n_observations, n_max, noise_deg)
        else:  # "fixed": N shared features per place; the first N of the N_max ones
            places = make_places(rng, n_places, n_max, place_spread_deg)
            obs = places[:, None, :] + rng.normal(0.0, np.deg2rad(noise_deg), (n_places, n_observations, n_max))
        states = []
        for k in ks_t:
            states.append(dict(rng.bit_generator.state))
            rng.random((n_samples, n_init, k))  # what fit_mixtures draws from the generator, and nothing else
        tasks.append(_Trial(obs, tuple(states), ks_t, ns_t, held_out, n_init, min_sigma_deg))
    rows = run_tasks(_run_trial, tasks, workers=workers, scheduler=scheduler, on_done=on_trial)
    per_trial = np.stack(rows) if rows else np.empty((0, len(ks_t), len(ns_t)))
    params = {
        "seed": seed,
        "n_places": n_places,
        "n_observations": n_observations,
        "n_edges": n_edges,
        "observation_model": observation_model,
        "evaluation": evaluation,
        "noise_deg": noise_deg,
        "place_spread_deg": place_spread_deg,
        "n_init": n_init,
        "min_sigma_deg": min_sigma_deg,
    }
    return Table1Result(k=ks_t, n=ns_t, per_trial=per_trial, params=params)
