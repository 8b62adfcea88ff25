"""The Bayesian program: :class:`PlaceModel` (SPEC.md §4).

Decomposition, with the feature sets independent given the place::

    P(Loc VE CP Ex B Fp) = P(Loc) P(VE|Loc) P(CP|Loc) P(Ex|Loc) P(B|Loc) P(Fp|Loc)

Parametric forms:

* ``P(Loc)`` uniform;
* ``P(f | loc) = prod_{x in f} p_MOG(x | theta_{f,loc})`` for ``f`` in VE, CP,
  Ex, B, ``theta_{f,loc}`` fit by EM on all training bearings of ``f`` at
  ``loc`` (:mod:`fingerloc.mog`);
* ``P(Fp | loc) = 1 / (GlobalAlignment(Fp, fp_loc) + 1)`` (``fp_likelihood="paper"``).

Beyond the paper (opt-in): the range term ``R``, ``P(R | loc) ∝ exp(-lambda_R
d(R, R_loc))``, ``d`` the L1 distance of cumulative range histograms (an earth
mover's distance between the distributions of beam ranges, heading-free) to
the nearest training scan of ``loc``, ``lambda_R`` fit on the training data
(see :class:`PlaceModel`). It needs observations carrying their raw range
profile (``Observation.ranges``).

The question ``P(Loc | VE CP Ex B Fp)`` is answered in log space and normalised
over the learned places.

Choices the paper leaves open (each documented on the parameter it concerns):

* **A place with no training bearings of a feature type** gets the uniform
  density ``1 / (2 pi)`` for that type: it says nothing for or against a
  bearing. (Fitting a mixture needs at least one bearing.)
* **An observation with no bearings of a type**: the product over an empty set
  is 1, so that term adds ``log 1 = 0`` to every place (no evidence).
* **A field of view narrower than the full circle** (a 180 deg laser): each
  mixture is renormalised to the part of the circle the query saw, i.e.
  ``p(x | loc, x seen) = p_MOG(x) / P_MOG(seen)``, since a sensor cannot
  report a bearing it did not look at. The mass is integrated numerically on a
  grid of ``fov_grid`` points and floored at ``min_fov_mass``. For ``Fp``
  (``cyclic=False``) the letters of each stored fingerprint outside the query's
  field of view are dropped before aligning, so empty space the query did not
  see costs nothing.
* **More mixture components than training bearings**: the mixture is fit
  with as many components as distinct bearings (:func:`fingerloc.mog.fit_mixtures`).
* **No NaN, no division by zero**: densities are evaluated in log space; a
  row whose every place has log-likelihood ``-inf`` gets the uniform posterior.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from .angles import TWO_PI, wrap
from .errors import InvalidParameterError, NotFittedError
from .fingerprint import Fingerprint, make_fingerprint
from .observation import FULL_FOV, Observation

__all__ = ["MOG_TERMS", "TERMS", "PlaceData", "PlaceModel"]

#: Terms of the Bayesian program computed from mixtures of Gaussians.
MOG_TERMS: tuple[str, ...] = ("VE", "CP", "Ex", "B")
#: The paper's terms (the default).
PAPER_TERMS: tuple[str, ...] = (*MOG_TERMS, "Fp")
#: Every term a model may use: the paper's and the range term ``R`` (our extension).
TERMS: tuple[str, ...] = (*PAPER_TERMS, "R")

FArray = NDArray[np.float64]
LOG_UNIFORM = -math.log(TWO_PI)

FpLikelihood = Literal["paper", "exp"]
FpReference = Literal["all", "medoid", "consensus"]


@dataclass(slots=True)
class PlaceData:
    """What the model keeps of one learned place.

    Attributes
    ----------
    label : str
    observations : list of Observation
        The training observations.
    fingerprints : list of Fingerprint
        One per training observation.
    mixtures : dict
        Term -> ``(weights, means, sigmas)`` arrays of shape ``(K,)``
        (radians); a term absent from the dict had no training bearing.
    medoid : int
        Index of the training fingerprint with the least summed cost to the others.
    consensus : Fingerprint or None
        The place's average fingerprint (``fp_reference="consensus"``).
    """

    label: str
    observations: list[Observation]
    fingerprints: list[Fingerprint]
    mixtures: dict[str, tuple[FArray, FArray, FArray]] = field(default_factory=dict)
    medoid: int = 0
    consensus: Fingerprint | None = None


class PlaceModel:
    """The Bayesian program of Tapus et al. (ICRA 2004) over learned places.

    scikit-learn-like: the constructor stores its arguments; :meth:`fit` learns.

    Parameters
    ----------
    n_components : int, default 5
        Mixture components per place and feature type (``k`` of Tables I, IV).
    terms : sequence of str, default ("VE", "CP", "Ex", "B", "Fp")
        Terms of the decomposition to use; any non-empty subset (the paper's
        ablations: ``("VE",)``, ``("Ex",)``, ``("VE", "Ex")``, ``("VE", "Ex", "Fp")``)
        of the paper's terms, plus the range term ``"R"`` (our extension,
        module docstring).
    fp_likelihood : {"paper", "exp"}, default "paper"
        ``"paper"``: ``P(Fp|loc) = 1 / (cost + 1)``. ``"exp"``:
        ``P(Fp|loc) ∝ exp(-lambda * cost)``, ``lambda`` chosen on the training
        data to maximise the leave-one-out log-probability of the right place
        under the fingerprint term alone (``fp_lambda_``).
    fp_reference : {"all", "medoid", "consensus"}, default "all"
        Which stored fingerprint(s) stand for a place: ``"all"`` takes the least
        cost over its training fingerprints; ``"medoid"`` the training
        fingerprint with the least summed cost to the others; ``"consensus"``
        an average fingerprint (:func:`consensus_fingerprint`).
    cyclic : bool, default False
        Align over every rotation of the stored fingerprint (unknown heading);
        :meth:`headings` then estimates the heading.
    costs : fingerloc.align.CostModel, optional
        Alignment costs; unit costs (Levenshtein) by default, as in the paper.
    weights : mapping of str to float, or "fit", optional
        Per-term weight multiplying its log-likelihood (default 1 each; the
        paper's program has all weights 1). ``"fit"``: weights learned from
        the training data (:meth:`fit`; ``weights_``): the views of each place
        are split in two halves (alternate views), a model fit on one half
        gives the per-term log-likelihoods of the other, and the weights
        maximise the held-out log-probability of the right place. The terms'
        independence assumption makes a term with many bearings (VE) count
        many times over; fitted weights say how far each term is to be
        trusted, and they also calibrate the posterior's sharpness.
    unknown_prior : float, default 0
        Prior probability that an observation comes from no learned place.
        0 (the paper) disables the "unknown" hypothesis; see
        :meth:`predict_unknown_proba`.
    outlier_weight : float, default 0
        Weight of a uniform component mixed into every place's density,
        ``(1 - w) p_MOG + w / (2 pi)``, so one spurious bearing cannot veto a
        place. 0 is the paper's form.
    min_sigma_deg, tol, max_iter, n_init : mixture fitting (:func:`fingerloc.mog.fit_mixtures`).
    empty_step_deg, merge_tol_deg, laser_letters : fingerprint generation
        (:func:`fingerloc.make_fingerprint`); ``laser_letters=True`` writes
        extremities and wall segments into the string (our extension for
        laser-only robots).
    range_bin_m, range_max_m : float, default 0.25 and 10
        Bin width and last bin edge (metres) of the range histograms of the
        ``R`` term; ranges beyond ``range_max_m`` and beams without return
        share one last bin.
    fov_grid : int, default 720
        Grid points used to integrate a mixture over a partial field of view.
    min_fov_mass : float, default 1e-3
        Floor of a mixture's mass inside a partial field of view.
    random_state : int or numpy.random.Generator, optional
        Seeds the mixtures' initialisation.
    """

    def __init__(
        self,
        n_components: int = 5,
        *,
        terms: Sequence[str] = PAPER_TERMS,
        fp_likelihood: FpLikelihood = "paper",
        fp_reference: FpReference = "all",
        cyclic: bool = False,
        costs: Any = None,
        weights: Mapping[str, float] | Literal["fit"] | None = None,
        unknown_prior: float = 0.0,
        outlier_weight: float = 0.0,
        min_sigma_deg: float = 1.0,
        tol: float = 1e-6,
        max_iter: int = 500,
        n_init: int = 3,
        empty_step_deg: float = 20.0,
        merge_tol_deg: float = 5.0,
        laser_letters: bool = False,
        range_bin_m: float = 0.25,
        range_max_m: float = 10.0,
        fov_grid: int = 720,
        min_fov_mass: float = 1e-3,
        random_state: int | np.random.Generator | None = 0,
    ) -> None:
        self.n_components = n_components
        self.terms = tuple(terms)
        self.fp_likelihood = fp_likelihood
        self.fp_reference = fp_reference
        self.cyclic = cyclic
        self.costs = costs
        self.weights: dict[str, float] | str | None = dict(weights) if isinstance(weights, Mapping) else weights
        self.unknown_prior = unknown_prior
        self.outlier_weight = outlier_weight
        self.min_sigma_deg = min_sigma_deg
        self.tol = tol
        self.max_iter = max_iter
        self.n_init = n_init
        self.empty_step_deg = empty_step_deg
        self.merge_tol_deg = merge_tol_deg
        self.laser_letters = laser_letters
        self.range_bin_m = range_bin_m
        self.range_max_m = range_max_m
        self.fov_grid = fov_grid
        self.min_fov_mass = min_fov_mass
        self.random_state = random_state

    # -- parameters ----------------------------------------------------------
    def get_params(self) -> dict[str, Any]:
        """The constructor arguments (JSON-ready except ``costs`` and ``random_state``)."""
        return {
            "n_components": self.n_components,
            "terms": list(self.terms),
            "fp_likelihood": self.fp_likelihood,
            "fp_reference": self.fp_reference,
            "cyclic": self.cyclic,
            "costs": self.costs,
            "weights": self.weights,
            "unknown_prior": self.unknown_prior,
            "outlier_weight": self.outlier_weight,
            "min_sigma_deg": self.min_sigma_deg,
            "tol": self.tol,
            "max_iter": self.max_iter,
            "n_init": self.n_init,
            "empty_step_deg": self.empty_step_deg,
            "merge_tol_deg": self.merge_tol_deg,
            "laser_letters": self.laser_letters,
            "range_bin_m": self.range_bin_m,
            "range_max_m": self.range_max_m,
            "fov_grid": self.fov_grid,
            "min_fov_mass": self.min_fov_mass,
            "random_state": self.random_state,
        }

    def _validate(self) -> None:
        if not isinstance(self.n_components, (int, np.integer)) or isinstance(self.n_components, bool) or self.n_components < 1:
            raise InvalidParameterError(f"n_components must be an integer >= 1, got {self.n_components!r}")
        if not self.terms:
            raise InvalidParameterError("terms must name at least one term")
        for t in self.terms:
            if t not in TERMS:
                raise InvalidParameterError(f"unknown term {t!r} in terms (expected some of {', '.join(TERMS)})")
        if len(set(self.terms)) != len(self.terms):
            raise InvalidParameterError(f"terms must not repeat a term, got {list(self.terms)!r}")
        if self.fp_likelihood not in ("paper", "exp"):
            raise InvalidParameterError(f"fp_likelihood must be 'paper' or 'exp', got {self.fp_likelihood!r}")
        if self.fp_reference not in ("all", "medoid", "consensus"):
            raise InvalidParameterError(
                f"fp_reference must be 'all', 'medoid' or 'consensus', got {self.fp_reference!r}"
            )
        if isinstance(self.weights, str):
            if self.weights != "fit":
                raise InvalidParameterError(f"weights must be a mapping of term -> weight or 'fit', got {self.weights!r}")
        elif self.weights is not None and not isinstance(self.weights, Mapping):
            raise InvalidParameterError(f"weights must be a mapping of term -> weight or 'fit', got {self.weights!r}")
        for name, w in (self.weights if isinstance(self.weights, Mapping) else {}).items():
            if name not in TERMS:
                raise InvalidParameterError(f"weights: unknown term {name!r}")
            if not (math.isfinite(w) and w >= 0):
                raise InvalidParameterError(f"weights[{name!r}] must be a finite number >= 0, got {w!r}")
        if not (0.0 <= self.unknown_prior < 1.0):
            raise InvalidParameterError(f"unknown_prior must be in [0, 1), got {self.unknown_prior!r}")
        if not (0.0 <= self.outlier_weight < 1.0):
            raise InvalidParameterError(f"outlier_weight must be in [0, 1), got {self.outlier_weight!r}")
        if not (0 < self.range_bin_m < self.range_max_m and math.isfinite(self.range_max_m)):
            raise InvalidParameterError(
                f"range_bin_m and range_max_m must satisfy 0 < range_bin_m < range_max_m, "
                f"got {self.range_bin_m!r} and {self.range_max_m!r}"
            )
        if not (isinstance(self.fov_grid, int) and self.fov_grid >= 36):
            raise InvalidParameterError(f"fov_grid must be an integer >= 36, got {self.fov_grid!r}")
        if not (0.0 < self.min_fov_mass <= 1.0):
            raise InvalidParameterError(f"min_fov_mass must be in (0, 1], got {self.min_fov_mass!r}")

    # -- learning ------------------------------------------------------------
    def fit(self, observations: Sequence[Observation], labels: Sequence[str] | None = None) -> PlaceModel:
        """Learn one place per distinct label.

        Parameters
        ----------
        observations : sequence of Observation, length n
        labels : sequence of str, length n, optional
            The place of each observation; by default each observation's ``label``.

        Returns
        -------
        self
        """
        self._validate()
        self.places_: dict[str, PlaceData] = {}
        self.lambdas_: dict[str, float] = {}
        self.unknown_costs_: dict[str, float] = {}
        self.weights_: dict[str, float] = {}
        self._add(observations, labels, refit_global=True)
        if self.weights == "fit":
            self.weights_ = self._fit_term_weights()
        return self

    def add_places(self, observations: Sequence[Observation], labels: Sequence[str] | None = None) -> PlaceModel:
        """Learn more observations without refitting the other places.

        Observations of a new label create a place; observations of a known
        label are added to that place, which alone is refit. The global
        calibration of the distance terms (``lambdas_``, ``unknown_costs_``) is kept.
        """
        if not hasattr(self, "places_"):
            return self.fit(observations, labels)
        self._validate()
        self._add(observations, labels, refit_global=False)
        return self

    def _add(self, observations: Sequence[Observation], labels: Sequence[str] | None, *, refit_global: bool) -> None:
        obs = list(observations)
        if not obs:
            raise InvalidParameterError("fit needs at least one observation")
        labs = [o.label for o in obs] if labels is None else [str(x) for x in labels]
        if len(labs) != len(obs):
            raise InvalidParameterError(f"labels: one label per observation is needed, got {len(labs)} for {len(obs)}")
        for i, lab in enumerate(labs):
            if lab is None or lab == "":
                raise InvalidParameterError(f"observation {i} has no place label (give labels= or set each label)")
        groups: dict[str, list[Observation]] = {}
        for o, lab in zip(obs, labs, strict=True):
            groups.setdefault(str(lab), []).append(o if o.label == lab else o.with_label(str(lab)))
        for lab, group in groups.items():
            old = self.places_.get(lab)
            allobs = (old.observations if old is not None else []) + group
            fps = [self._fingerprint(o) for o in allobs]
            self.places_[lab] = PlaceData(lab, allobs, fps)
        self._fit_mixtures([self.places_[lab] for lab in groups])
        self._fit_references([self.places_[lab] for lab in groups])
        self.classes_ = np.array(list(self.places_), dtype=object)
        self._index_references()
        if refit_global:
            self._calibrate()

    def _fingerprint(self, obs: Observation) -> Fingerprint:
        return make_fingerprint(
            obs,
            empty_step_deg=self.empty_step_deg,
            merge_tol_deg=self.merge_tol_deg,
            laser_letters=self.laser_letters,
        )

    def _fit_mixtures(self, places: list[PlaceData]) -> None:
        from .mog import fit_mixtures

        jobs: list[tuple[PlaceData, str]] = []
        samples: list[FArray] = []
        for p in places:
            p.mixtures = {}
            for term in MOG_TERMS:
                if term not in self.terms:
                    continue
                x = np.concatenate([o.bearings(term) for o in p.observations])
                if x.size:
                    jobs.append((p, term))
                    samples.append(x)
        if not samples:
            return
        ms = fit_mixtures(
            samples,
            self.n_components,
            tol=self.tol,
            max_iter=self.max_iter,
            n_init=self.n_init,
            min_sigma_deg=self.min_sigma_deg,
            random_state=self.random_state,
        )
        for i, (p, term) in enumerate(jobs):
            p.mixtures[term] = (ms.weights[i].copy(), ms.means[i].copy(), ms.sigmas[i].copy())

    def _fit_references(self, places: list[PlaceData]) -> None:
        if "Fp" not in self.terms:
            return
        from .align import alignment_costs

        for p in places:
            if len(p.fingerprints) > 1:
                d = alignment_costs(p.fingerprints, p.fingerprints, cyclic=self.cyclic, costs=self.costs)
                p.medoid = int(np.argmin(d.sum(axis=1)))
            else:
                p.medoid = 0
            if self.fp_reference == "consensus":
                p.consensus = consensus_fingerprint(p.fingerprints, costs=self.costs, cyclic=self.cyclic)

    def _index_references(self) -> None:
        """Flatten the stored fingerprints: ``_ref_fps`` and the place index of each."""
        refs: list[Fingerprint] = []
        owner: list[int] = []
        for j, p in enumerate(self.places_.values()):
            if self.fp_reference == "all":
                chosen = p.fingerprints
            elif self.fp_reference == "medoid":
                chosen = [p.fingerprints[p.medoid]]
            else:
                chosen = [p.consensus if p.consensus is not None else p.fingerprints[p.medoid]]
            refs += chosen
            owner += [j] * len(chosen)
        self._ref_fps = refs
        self._ref_owner = np.asarray(owner, dtype=np.int64)
        # references are grouped by place: place j owns columns _ref_starts[j]:_ref_starts[j+1]
        self._ref_starts = np.searchsorted(self._ref_owner, np.arange(len(self.places_)))
        self.__dict__.pop("_crop_cache", None)
        self.__dict__.pop("_fov_cache", None)
        if "R" in self.terms:
            descs: list[FArray] = []
            rowner: list[int] = []
            for j, p in enumerate(self.places_.values()):
                for o in p.observations:
                    if o.ranges is not None:
                        descs.append(self._range_descriptor(o))
                        rowner.append(j)
            width = self._range_bins().size + 1
            self._range_refs = np.stack(descs) if descs else np.zeros((0, width))
            self._range_owner = np.asarray(rowner, dtype=np.int64)
        self._stack_mixtures()

    def _stack_mixtures(self) -> None:
        """Stack every place's mixtures into ``(P, K)`` arrays per term; ``_has[term]`` marks fitted places."""
        self._mix: dict[str, tuple[FArray, FArray, FArray, NDArray[np.bool_]]] = {}
        places = list(self.places_.values())
        for term in MOG_TERMS:
            if term not in self.terms:
                continue
            k = max([p.mixtures[term][0].size for p in places if term in p.mixtures], default=1)
            w = np.zeros((len(places), k))
            m = np.zeros((len(places), k))
            s = np.ones((len(places), k))
            has = np.zeros(len(places), dtype=bool)
            for j, p in enumerate(places):
                if term in p.mixtures:
                    pw, pm, ps = p.mixtures[term]
                    w[j, : pw.size], m[j, : pm.size], s[j, : ps.size] = pw, pm, ps
                    has[j] = True
            self._mix[term] = (w, m, s, has)

    @property
    def fp_lambda_(self) -> float:
        """``lambda`` of ``fp_likelihood="exp"`` (1 until calibrated)."""
        return self.lambdas_.get("Fp", 1.0)

    def _distance_terms(self) -> list[str]:
        """Terms whose likelihood is a function of a distance to the place's references."""
        return [t for t in ("Fp", "R") if t in self.terms]

    def _term_distances(self, term: str, observations: Sequence[Observation]) -> FArray:
        """Distance of each observation to each place for a distance term, shape (n, P)."""
        if term == "Fp":
            return self.fingerprint_costs(observations)
        return self.range_distances(observations)

    def _calibrate(self, max_queries: int = 2000) -> None:
        """Leave-one-out distances on the training data -> ``lambdas_`` and ``unknown_costs_``.

        For each distance term, ``unknown_costs_[term]`` is the median distance
        of a training observation to the nearest *other* place, and
        ``lambdas_[term]`` (``exp`` forms: ``R`` always, ``Fp`` with
        ``fp_likelihood="exp"``) maximises the mean leave-one-out log-probability
        of the right place under that term alone. At most ``max_queries``
        training observations (a seeded sample) serve as queries, so learning
        stays linear in the number of places.
        """
        places = list(self.places_.values())
        obs = [o for p in places for o in p.observations]
        owner = np.array([j for j, p in enumerate(places) for _ in p.observations])
        if len(places) < 2:
            return
        rows = np.arange(len(obs))
        if len(obs) > max_queries:
            rows = np.sort(np.random.default_rng(0).choice(len(obs), max_queries, replace=False))
        for term in self._distance_terms():
            if term == "Fp" and self.fp_likelihood == "paper" and self.unknown_prior <= 0:
                continue
            if term == "R" and not any(o.ranges is not None for o in obs):
                continue
            d = self._loo_distances(term, obs, rows, owner, len(places))
            truth = owner[rows]
            ok = np.isfinite(d[np.arange(rows.size), truth])
            if not ok.any():
                continue
            c, t = d[ok], truth[ok]
            wrong = c.copy()
            wrong[np.arange(t.size), t] = np.inf
            nearest_wrong = wrong.min(axis=1)
            if np.isfinite(nearest_wrong).any():
                self.unknown_costs_[term] = float(np.median(nearest_wrong[np.isfinite(nearest_wrong)]))
            if term == "R" or self.fp_likelihood == "exp":
                self.lambdas_[term] = _fit_lambda(c, t)

    def _loo_distances(
        self, term: str, obs: list[Observation], rows: NDArray[np.int64], owner: NDArray[np.int64], n_places: int
    ) -> FArray:
        """Per-place least distance of training observations ``rows`` to the *other* training observations."""
        from .align import alignment_costs

        if term == "Fp":
            fps = [fp for p in self.places_.values() for fp in p.fingerprints]
            d = alignment_costs([fps[i] for i in rows], fps, cyclic=self.cyclic, costs=self.costs)
        else:
            from scipy.spatial.distance import cdist

            has = np.array([o.ranges is not None for o in obs])
            desc = np.zeros((len(obs), self._range_bins().size + 1))
            desc[has] = self._range_refs  # the descriptors _index_references made, in the same order
            d = cdist(desc[rows], desc, metric="cityblock")
            d[:, ~has] = np.inf
            d[~has[rows]] = np.inf
        d[np.arange(rows.size), rows] = np.inf  # leave one out
        return _min_per_place(d, np.searchsorted(owner, np.arange(n_places)))

    # -- inference ---------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "places_"):
            raise NotFittedError("this PlaceModel is not fitted yet: call fit(observations, labels) first")

    def _weight(self, term: str) -> float:
        if self.weights == "fit":
            return float(getattr(self, "weights_", {}).get(term, 1.0))
        return float((self.weights if isinstance(self.weights, Mapping) else {}).get(term, 1.0))

    def _fit_term_weights(self) -> dict[str, float]:
        """Per-term weights maximising the held-out log-probability of the right place (``weights="fit"``).

        Two folds: alternate views of each place. Places with one view are
        absent from one fold's model; rows whose place is absent are not
        used. Fewer than two places with a held-out row: every weight 1.
        """
        from scipy.optimize import minimize

        params = self.get_params()
        params["weights"] = None
        terms = list(self.terms)
        col = {str(c): j for j, c in enumerate(self.classes_)}
        rows: dict[str, list[FArray]] = {t: [] for t in terms}
        truth: list[NDArray[np.int64]] = []
        for fold in (0, 1):
            train: list[Observation] = []
            test: list[Observation] = []
            for p in self.places_.values():
                for i, o in enumerate(p.observations):
                    (test if i % 2 == fold else train).append(o)
            have = {o.label for o in train}
            test = [o for o in test if o.label in have]
            if len(have) < 2 or not test:
                continue
            sub = PlaceModel(**params).fit(train)
            ll = sub.term_log_likelihoods(test)
            cols = np.array([col[str(c)] for c in sub.classes_], dtype=np.int64)
            for t in terms:
                full = np.full((len(test), len(col)), -np.inf)
                full[:, cols] = ll[t]
                rows[t].append(full)
            truth.append(np.array([col[str(o.label)] for o in test], dtype=np.int64))
        if not truth:
            return {t: 1.0 for t in terms}
        y = np.concatenate(truth)
        mats = []
        for t in terms:
            m = np.vstack(rows[t])
            finite = m[np.isfinite(m)]
            floor = (float(finite.min()) if finite.size else 0.0) - 100.0
            mats.append(np.where(np.isfinite(m), m, floor))  # a place a term rules out: far below every seen value
        present = np.isfinite(np.vstack(rows[terms[0]]))  # places of the fold's model
        stack = np.stack(mats)  # (T, n, P)

        def nll(log_w: FArray) -> float:
            joint = np.tensordot(np.exp(log_w), stack, axes=1)
            joint = np.where(present, joint, -np.inf)
            return -float(np.mean(joint[np.arange(y.size), y] - logsumexp(joint, axis=1)))

        res = minimize(nll, np.zeros(len(terms)), method="L-BFGS-B", bounds=[(-9.0, 5.0)] * len(terms))
        return {t: float(w) for t, w in zip(terms, np.exp(res.x), strict=True)}

    def _fov_log_mass(self, term: str, fov: tuple[tuple[float, float], ...]) -> FArray:
        """log of each place's mixture mass inside ``fov``, shape (P,); 0 for the full circle."""
        w, m, s, has = self._mix[term]
        if any(width >= TWO_PI - 1e-12 for _, width in fov):
            return np.zeros(w.shape[0])
        cache: dict[Any, FArray] = self.__dict__.setdefault("_fov_cache", {})
        key = (term, fov)
        if key in cache:
            return cache[key]
        grid = wrap(-np.pi + (np.arange(self.fov_grid) + 0.5) * TWO_PI / self.fov_grid)
        inside = np.zeros(grid.size, dtype=bool)
        for start, width in fov:
            inside |= np.mod(grid - start, TWO_PI) <= width
        dens = np.exp(self._place_log_density(grid[inside], w, m, s, has))  # (P, g)
        mass = dens.sum(axis=1) * TWO_PI / self.fov_grid
        out = np.log(np.clip(mass, self.min_fov_mass, 1.0))
        cache[key] = out
        return out

    def _place_log_density(self, x: FArray, w: FArray, m: FArray, s: FArray, has: NDArray[np.bool_]) -> FArray:
        """log p(x_i | place) for every place, shape (P, n); uniform for places without a mixture."""
        from .mog import mixture_log_density

        out = np.full((w.shape[0], x.size), LOG_UNIFORM)
        if x.size and has.any():
            out[has] = mixture_log_density(x, w[has], m[has], s[has])
        if self.outlier_weight > 0:
            out = np.logaddexp(np.log1p(-self.outlier_weight) + out, math.log(self.outlier_weight) + LOG_UNIFORM)
        return out

    def term_log_likelihoods(self, observations: Sequence[Observation]) -> dict[str, FArray]:
        """Per-term log-likelihoods ``log P(term | loc)``, each of shape ``(n, P)``, unweighted.

        Columns follow :attr:`classes_`.
        """
        self._check_fitted()
        obs = list(observations)
        out: dict[str, FArray] = {}
        n_places = len(self.places_)
        for term in self.terms:
            if term == "Fp":
                out["Fp"] = self._fp_log_likelihood(obs)
                continue
            if term == "R":
                out["R"] = -self.lambdas_.get("R", 1.0) * self.range_distances(obs)
                continue
            w, m, s, has = self._mix[term]
            ll = np.zeros((len(obs), n_places))
            for i, o in enumerate(obs):
                x = o.bearings(term)
                if x.size == 0:
                    continue
                ll[i] = self._place_log_density(x, w, m, s, has).sum(axis=1) - x.size * self._fov_log_mass(term, o.fov)
            out[term] = ll
        return out

    def fingerprint_costs(self, observations: Sequence[Observation]) -> FArray:
        """Alignment cost of each observation to each place, shape ``(n, P)`` (per ``fp_reference``)."""
        self._check_fitted()
        from .align import alignment_costs

        obs = list(observations)
        qfps = [self._fingerprint(o) for o in obs]
        n_places = len(self.places_)
        out = np.full((len(obs), n_places), np.inf)
        # group queries by field of view: references are cropped to a narrower query fov
        groups: dict[Any, list[int]] = {}
        for i, o in enumerate(obs):
            groups.setdefault(o.fov, []).append(i)
        for fov, idx in groups.items():
            refs = self._references_for(fov)
            d = alignment_costs([qfps[i] for i in idx], refs, cyclic=self.cyclic, costs=self.costs)
            out[idx] = _min_per_place(d, self._ref_starts)
        return out

    def _range_bins(self) -> FArray:
        return np.arange(self.range_bin_m, self.range_max_m + 1e-9, self.range_bin_m)

    def _range_descriptor(self, obs: Observation) -> FArray:
        return range_descriptor(obs, self._range_bins())

    def range_distances(self, observations: Sequence[Observation]) -> FArray:
        """Range-term distance of each observation to each place, shape ``(n, P)``.

        The L1 distance between cumulative range histograms (``range_bin_m``
        bins up to ``range_max_m``, then one bin for farther or no return),
        least over the place's training observations that carry ranges. Rows
        of observations without ranges are 0 (the term says nothing); a place
        without any training ranges gets the row's largest finite distance.
        """
        self._check_fitted()
        from scipy.spatial.distance import cdist

        obs = list(observations)
        n_places = len(self.places_)
        out = np.zeros((len(obs), n_places))
        idx = [i for i, o in enumerate(obs) if o.ranges is not None]
        if not idx or self._range_refs.shape[0] == 0:
            return out
        q = np.stack([self._range_descriptor(obs[i]) for i in idx])
        d = cdist(q, self._range_refs, metric="cityblock")
        per = np.full((len(idx), n_places), np.inf)
        starts = np.searchsorted(self._range_owner, np.arange(n_places))
        has = np.bincount(self._range_owner, minlength=n_places) > 0
        per[:, has] = _min_per_place(d, starts[has])
        worst = np.max(np.where(np.isfinite(per), per, -np.inf), axis=1, keepdims=True)
        out[idx] = np.where(np.isfinite(per), per, worst)
        return out

    def _references_for(self, fov: tuple[tuple[float, float], ...]) -> Any:
        """The stored fingerprints as a validated batch, cropped to a partial query ``fov`` (cached)."""
        from .align import FingerprintBatch

        if self.cyclic or any(width >= TWO_PI - 1e-12 for _, width in fov):
            fov = FULL_FOV
        cache: dict[Any, Any] = self.__dict__.setdefault("_crop_cache", {})
        if fov not in cache:
            refs = self._ref_fps if fov == FULL_FOV else [_crop(fp, fov) for fp in self._ref_fps]
            cache[fov] = FingerprintBatch(refs)
        return cache[fov]

    def _fp_log_likelihood(self, obs: list[Observation]) -> FArray:
        c = self.fingerprint_costs(obs)
        if self.fp_likelihood == "paper":
            return -np.log1p(c)  # P(Fp|loc) = 1 / (cost + 1)
        return -self.fp_lambda_ * c  # P(Fp|loc) ∝ exp(-lambda cost)

    def _joint_log_likelihood(self, terms: Mapping[str, FArray]) -> FArray:
        total = sum(self._weight(t) * ll for t, ll in terms.items())
        return np.asarray(total, dtype=np.float64)

    def joint_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """Weighted sum of the terms' log-likelihoods, unnormalised, shape ``(n, P)``.

        ``log P(Loc) + sum_term w_term log P(term | Loc)`` up to a constant;
        :meth:`predict_log_proba` normalises it over the places.
        """
        self._check_fitted()
        return self._joint_log_likelihood(self.term_log_likelihoods(observations))

    def predict_log_proba(self, observations: Sequence[Observation]) -> FArray:
        """``log P(Loc | observation)`` normalised over the learned places, shape ``(n, P)``.

        Rows whose joint log-likelihood is ``-inf`` for every place get the
        uniform posterior.
        """
        self._check_fitted()
        return _normalise(self._joint_log_likelihood(self.term_log_likelihoods(observations)))

    def predict_proba(self, observations: Sequence[Observation]) -> FArray:
        """Posterior over the learned places, shape ``(n, P)``; rows sum to 1; columns follow :attr:`classes_`."""
        return np.exp(self.predict_log_proba(observations))

    def predict(self, observations: Sequence[Observation]) -> NDArray[np.object_]:
        """Most probable place of each observation, shape ``(n,)``."""
        best = np.argmax(self.predict_log_proba(observations), axis=1)
        return self.classes_[best]

    def rank(self, observations: Sequence[Observation]) -> NDArray[np.int64]:
        """Rank of every place for each observation, shape ``(n, P)``; 1 = best, ties count against."""
        return rank_scores(self.predict_log_proba(observations))

    def rank_of(self, observations: Sequence[Observation], labels: Sequence[str] | None = None) -> NDArray[np.int64]:
        """Rank of the true place of each observation, shape ``(n,)`` (ties count against)."""
        obs = list(observations)
        labs = [o.label for o in obs] if labels is None else list(labels)
        ranks = self.rank(obs)
        col = {c: j for j, c in enumerate(self.classes_)}
        out = np.empty(len(obs), dtype=np.int64)
        for i, lab in enumerate(labs):
            if lab not in col:
                raise InvalidParameterError(f"label {lab!r} of observation {i} is not a learned place")
            out[i] = ranks[i, col[lab]]
        return out

    def score(self, observations: Sequence[Observation], labels: Sequence[str] | None = None) -> float:
        """Right classification rate (top-1) on labelled observations, in ``[0, 1]``."""
        return float(np.mean(self.rank_of(observations, labels) == 1))

    def predict_unknown_proba(self, observations: Sequence[Observation]) -> FArray:
        """Probability that each observation comes from no learned place, shape ``(n,)``.

        The "unknown" hypothesis has prior ``unknown_prior`` and a background
        likelihood: the uniform density ``1 / (2 pi)`` per bearing for the
        mixture terms (renormalised to the field of view like the places), and
        for ``Fp`` and ``R`` the term's likelihood at ``unknown_costs_[term]``,
        the median distance of a training observation to the nearest *other*
        place. A view
        that matches some place better than views usually match wrong places
        is then attributed to a known place. Zero when ``unknown_prior`` is 0.
        """
        self._check_fitted()
        obs = list(observations)
        if self.unknown_prior <= 0:
            return np.zeros(len(obs))
        terms = self.term_log_likelihoods(obs)
        joint = self._joint_log_likelihood(terms)
        bg = np.zeros(len(obs))
        for term in terms:
            if term in ("Fp", "R"):
                c = self.unknown_costs_.get(term, 0.0)
                if term == "Fp" and self.fp_likelihood == "paper":
                    bg += self._weight(term) * -math.log1p(c)
                elif term == "Fp":
                    bg += self._weight(term) * -self.fp_lambda_ * c
                else:  # R: observations without ranges have a zero row, so the background is 0 too
                    has = np.array([o.ranges is not None for o in obs], dtype=float)
                    bg += self._weight(term) * -self.lambdas_.get("R", 1.0) * c * has
            else:
                for i, o in enumerate(obs):
                    n = o.bearings(term).size
                    # uniform density on the seen part of the circle
                    bg[i] += self._weight(term) * n * (LOG_UNIFORM - math.log(max(o.fov_coverage(), 1e-12)))
        n_places = joint.shape[1]
        known = logsumexp(joint, axis=1) + math.log((1 - self.unknown_prior) / n_places)
        unknown = bg + math.log(self.unknown_prior)
        return np.exp(unknown - np.logaddexp(known, unknown))

    def headings(self, observations: Sequence[Observation], places: Sequence[str] | None = None) -> FArray:
        """Heading estimate (degrees) of each observation relative to a place's stored views.

        For each observation, the best cyclic alignment against the given
        place's fingerprints (default: its most probable place) gives the
        rotation, turned into degrees from the letters' bearings. NaN where no
        estimate exists (empty fingerprints).
        """
        self._check_fitted()
        from .align import cyclic_alignment

        obs = list(observations)
        if places is None:
            places = list(self.predict(obs))
        out = np.full(len(obs), np.nan)
        for i, (o, lab) in enumerate(zip(obs, places, strict=True)):
            q = self._fingerprint(o)
            best = None
            for fp in self.places_[str(lab)].fingerprints:
                r = cyclic_alignment(q, fp, costs=self.costs)
                if best is None or r.cost < best.cost:
                    best = r
            if best is not None and best.heading_deg is not None:
                out[i] = best.heading_deg
        return out


def range_descriptor(obs: Observation, bins: FArray) -> FArray:
    """Cumulative histogram of an observation's beam ranges, shape ``(len(bins) + 1,)``.

    ``bins`` are the upper edges (metres) of all but the last bin; ranges at
    or beyond the last edge and beams without return fall in the last bin.
    The histogram is normalised to sum 1 before the cumulative sum, so the
    last entry is 1 and L1 distances between descriptors are earth mover's
    distances (in bins) between the range distributions.
    """
    if obs.ranges is None:
        raise InvalidParameterError("the range term needs observations with ranges (Observation.ranges)")
    r = obs.ranges
    idx = np.searchsorted(bins, np.where(np.isfinite(r), r, np.inf), side="right")
    h = np.bincount(np.minimum(idx, bins.size), minlength=bins.size + 1).astype(np.float64)
    total = h.sum()
    return np.cumsum(h / total) if total > 0 else np.ones(bins.size + 1)


def _fit_lambda(c: FArray, truth: NDArray[np.int64]) -> float:
    """``lambda`` maximising the mean ``log softmax(-lambda c)[truth]`` (leave-one-out distances ``c``)."""
    from scipy.optimize import minimize_scalar

    cf = np.where(np.isfinite(c), c, np.nanmax(np.where(np.isfinite(c), c, np.nan)) * 10 + 1)
    rows = np.arange(truth.size)

    def nll(log_lam: float) -> float:
        ll = -math.exp(log_lam) * cf
        return float(-(ll[rows, truth] - logsumexp(ll, axis=1)).mean())

    res = minimize_scalar(nll, bounds=(math.log(1e-3), math.log(1e4)), method="bounded")
    return float(math.exp(res.x))


def _min_per_place(d: FArray, starts: NDArray[np.int64]) -> FArray:
    """Column-group minima: ``out[:, j] = d[:, starts[j]:starts[j+1]].min(axis=1)``, shape (n, P)."""
    if d.shape[0] == 0:
        return np.zeros((0, starts.size))
    return np.minimum.reduceat(d, starts, axis=1)


def _normalise(joint: FArray) -> FArray:
    joint = np.asarray(joint, dtype=np.float64)
    if joint.shape[1] == 0:
        raise NotFittedError("the model has no place")
    dead = np.asarray(~np.isfinite(joint).any(axis=1) | np.isnan(joint).any(axis=1), dtype=bool)
    safe = np.where(dead[:, None], 0.0, np.nan_to_num(joint, nan=-np.inf, posinf=np.finfo(float).max))
    return safe - logsumexp(safe, axis=1, keepdims=True)


def rank_scores(scores: FArray) -> NDArray[np.int64]:
    """Rank of each column per row, 1 = highest score; ties count against (all tied get the worst rank)."""
    s = np.asarray(scores, dtype=np.float64)
    # rank = number of columns scoring at least as high (itself included)
    order = np.sort(s, axis=1)  # ascending
    n = s.shape[1]
    ge = n - np.stack([np.searchsorted(order[i], s[i], side="left") for i in range(s.shape[0])]) if s.size else np.zeros_like(s)
    return np.asarray(ge, dtype=np.int64)


def _crop(fp: Fingerprint, fov: tuple[tuple[float, float], ...]) -> Fingerprint:
    """The letters of ``fp`` whose bearing lies inside ``fov`` (ranges of (start, width) radians)."""
    keep = np.zeros(len(fp), dtype=bool)
    for start, width in fov:
        keep = keep | np.asarray(np.mod(fp.bearings - start, TWO_PI) <= width)
    if keep.all():
        return fp
    letters = "".join(ch for ch, k in zip(fp.letters, keep, strict=True) if k)
    return Fingerprint(letters, fp.bearings[keep])


def consensus_fingerprint(
    fingerprints: Sequence[Fingerprint],
    *,
    costs: Any = None,
    cyclic: bool = False,
    max_rounds: int = 3,
) -> Fingerprint:
    """An average fingerprint of a place: an approximate median string.

    The median string minimises the summed alignment cost to the place's
    fingerprints. Finding it exactly is NP-hard, so we start from the medoid
    (the best of the given strings) and improve it greedily: for ``max_rounds``
    rounds, try deleting each letter, substituting it, and inserting a letter
    of the alphabet at each position, keeping any edit that lowers the summed
    cost. The result is never worse than the medoid. Letter bearings come from
    the medoid (inserted letters take their neighbour's bearing).
    """
    from .align import alignment_costs
    from .fingerprint import ALPHABET

    fps = list(fingerprints)
    if not fps:
        raise InvalidParameterError("consensus_fingerprint needs at least one fingerprint")
    if len(fps) == 1:
        return fps[0]
    d = alignment_costs(fps, fps, cyclic=cyclic, costs=costs)
    medoid = fps[int(np.argmin(d.sum(axis=1)))]
    best_s = medoid.letters
    best_b = list(medoid.bearings)

    def total(strings: list[str]) -> FArray:
        return alignment_costs(strings, fps, cyclic=cyclic, costs=costs).sum(axis=1)

    best_cost = float(total([best_s])[0])
    used = sorted(set("".join(fp.letters for fp in fps)) | {"n"}, key=ALPHABET.index)
    for _ in range(max_rounds):
        cands: list[tuple[str, list[float]]] = []
        s, b = best_s, best_b
        for i in range(len(s)):
            cands.append((s[:i] + s[i + 1 :], b[:i] + b[i + 1 :]))
            for ch in used:
                if ch != s[i]:
                    cands.append((s[:i] + ch + s[i + 1 :], b))
        for i in range(len(s) + 1):
            bb = b[i - 1] if i > 0 else (b[0] if b else 0.0)
            for ch in used:
                cands.append((s[:i] + ch + s[i:], [*b[:i], bb, *b[i:]]))
        if not cands:
            break
        tot = total([c[0] for c in cands])
        j = int(np.argmin(tot))
        if tot[j] >= best_cost - 1e-12:
            break
        best_cost = float(tot[j])
        best_s, best_b = cands[j]
    return Fingerprint(best_s, np.asarray(best_b, dtype=np.float64))
