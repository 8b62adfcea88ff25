"""The Bayesian program: :class:`PlaceModel` (docs/METHOD.md §4), a combination of terms.

Decomposition, with the feature sets independent given the place::

    P(Loc VE CP Ex B Fp R A) = P(Loc) P(VE|Loc) P(CP|Loc) P(Ex|Loc) P(B|Loc) P(Fp|Loc) P(R|Loc) P(A|Loc)

Each factor is a *term* (:mod:`fingerloc.terms`): the angle-space mixtures
(VE, CP, Ex, B), the fingerprint string (Fp), the range term (R, our
extension for 2D lasers) and the appearance term (A, our extension for
cameras: a heading-free description of the whole view). :class:`PlaceModel` only combines them: per-term
weights, the prior, the "unknown place" hypothesis, normalisation, and (an
option) rotating the observation by the heading the fingerprint alignment
estimates before the mixtures score it. The question ``P(Loc | ...)`` is
answered in log space and normalised over the learned places; a row whose
every place has log-likelihood ``-inf`` gets the uniform posterior.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Hashable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray
from scipy.special import logsumexp

from ._estimator import ParamsMixin
from ._lse import logsumexp_rows
from ._types import FArray
from .errors import InvalidParameterError, NotFittedError
from .metrics import rank_scores
from .observation import Observation
from .terms import (
    MOG_TERMS,
    AppearanceTerm,
    FingerprintTerm,
    KeypointTerm,
    MixtureTerm,
    ProfileTerm,
    RangeTerm,
    Term,
    consensus_fingerprint,
    fit_mixture_terms,
)
from .validation import check_bool, check_choice, check_int, check_number

__all__ = ["MOG_TERMS", "PAPER_TERMS", "TERMS", "PlaceData", "PlaceModel", "consensus_fingerprint", "rank_scores"]

#: The paper's terms (the default).
PAPER_TERMS: tuple[str, ...] = (*MOG_TERMS, "Fp")
#: Every term a model may use: the paper's, the range term ``R``, the appearance term ``A``, the
#: aligned-profile term ``AP`` and the local-feature term ``K`` (our extensions).
TERMS: tuple[str, ...] = (*PAPER_TERMS, "R", "A", "AP", "K")


FpLikelihood = Literal["paper", "exp"]
FpReference = Literal["all", "medoid", "consensus"]


@dataclass(slots=True)
class PlaceData:
    """One learned place: its label (as given to :meth:`PlaceModel.fit`) and its training observations."""

    label: Hashable
    observations: list[Observation]


class PlaceModel(ParamsMixin):
    """The Bayesian program of Tapus et al. (ICRA 2004) over learned places.

    A scikit-learn estimator: the constructor stores its arguments untouched,
    :meth:`get_params` / :meth:`set_params`, ``sklearn.base.clone`` works;
    :meth:`fit` learns, fitted attributes end in ``_``.

    Parameters
    ----------
    n_components : int, default 5
        Mixture components per place and feature type (``k`` of Tables I, IV).
    terms : sequence of str, default ("VE", "CP", "Ex", "B", "Fp")
        Terms of the decomposition, any non-empty subset of ``TERMS``.
    fp_likelihood : {"paper", "exp"}, default "paper"
        ``"paper"``: ``P(Fp|loc) = 1 / (cost + 1)``. ``"exp"``:
        ``P(Fp|loc) ∝ exp(-lambda * cost)``, ``lambda`` chosen leave-one-out
        on the training data.
    fp_reference : {"all", "medoid", "consensus"}, default "all"
        Which stored fingerprint(s) stand for a place (:class:`fingerloc.terms.FingerprintTerm`).
    cyclic : bool, default False
        Align over every rotation of the stored fingerprints (heading unknown).
    costs : fingerloc.align.CostModel, optional
        Alignment costs; unit costs (Levenshtein) by default, as in the paper.
    weights : mapping of str to float, or "fit", optional
        Per-term weight multiplying its log-likelihood (default 1 each, the
        paper's program). ``"fit"``: weights learned from the training data
        (``weights_``): the views of each place are split in two halves
        (alternate views), terms fit on one half give the per-term
        log-likelihoods of the other, and the weights maximise the held-out
        log-probability of the right place. The independence assumption
        makes a term with many bearings (VE) count many times over; fitted
        weights say how far each term is to be trusted.
    unknown_prior : float, default 0
        Prior probability that an observation comes from no learned place
        (:meth:`predict_unknown_proba`); 0, the paper, disables it.
    outlier_weight : float, default 0
        Weight of a uniform component mixed into every mixture,
        ``(1 - w) p_MOG + w / (2 pi)``.
    rotate_mixtures : bool, default False
        Heading unknown: score the mixture terms after turning each
        observation by the heading the fingerprint alignment estimates for
        each place (needs ``"Fp"`` in ``terms``; best with ``cyclic=True``).
    temper : bool, default False
        Fit one factor ``temper_`` multiplying the weighted sum of the terms'
        log-likelihoods, so that the posterior's confidence matches its
        accuracy: the held-out log-probability of the right place on two
        folds of the training views (as ``weights="fit"``) is maximised. The
        terms are calibrated one by one; their sum counts shared evidence
        more than once, which makes the posterior overconfident.
    min_sigma_deg, tol, max_iter, n_init : mixture fitting (:func:`fingerloc.mog.fit_mixtures`).
    empty_step_deg, merge_tol_deg, laser_letters : fingerprint generation
        (:func:`fingerloc.make_fingerprint`); ``laser_letters=True`` writes
        extremities and wall segments into the string (laser-only robots).
    range_bin_m, range_max_m : float, default 0.25 and 10
        Bin width and last bin edge (metres) of the range term's histograms.
    fov_grid : int, default 720
        Grid points used to integrate a mixture over a partial field of view.
    min_fov_mass : float, default 1e-3
        Floor of a mixture's mass inside a partial field of view.
    random_state : int or numpy.random.Generator, optional
        Seeds the mixtures' initialisation.

    Attributes
    ----------
    classes_ : ndarray of object, shape (P,)
        The place labels, in order of first appearance, of the type given.
    places_ : dict
        Label -> :class:`PlaceData`.
    terms_ : dict
        Term name -> fitted :class:`fingerloc.terms.Term`.
    weights_ : dict
        Term name -> fitted weight (``weights="fit"`` only).
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
        rotate_mixtures: bool = False,
        temper: bool = False,
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
        self.terms = terms
        self.fp_likelihood = fp_likelihood
        self.fp_reference = fp_reference
        self.cyclic = cyclic
        self.costs = costs
        self.weights = weights
        self.unknown_prior = unknown_prior
        self.outlier_weight = outlier_weight
        self.rotate_mixtures = rotate_mixtures
        self.temper = temper
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
    def _checked(self) -> dict[str, Any]:
        """The validated parameters (terms as a tuple, weights as a dict or "fit")."""
        check_int("n_components", self.n_components, minimum=1)
        if isinstance(self.terms, str) or not isinstance(self.terms, Sequence):
            raise InvalidParameterError(f"terms must be a sequence of term names, got {self.terms!r}")
        terms = tuple(self.terms)
        if not terms:
            raise InvalidParameterError("terms must name at least one term")
        for t in terms:
            if t not in TERMS:
                raise InvalidParameterError(f"unknown term {t!r} in terms (expected some of {', '.join(TERMS)})")
        if len(set(terms)) != len(terms):
            raise InvalidParameterError(f"terms must not repeat a term, got {list(terms)!r}")
        check_choice("fp_likelihood", self.fp_likelihood, ("paper", "exp"))
        check_choice("fp_reference", self.fp_reference, ("all", "medoid", "consensus"))
        check_bool("cyclic", self.cyclic)
        check_bool("rotate_mixtures", self.rotate_mixtures)
        check_bool("temper", self.temper)
        check_bool("laser_letters", self.laser_letters)
        if self.rotate_mixtures and "Fp" not in terms:
            raise InvalidParameterError("rotate_mixtures needs the Fp term in terms (it gives the headings)")
        weights: dict[str, float] | str
        if isinstance(self.weights, str):
            if self.weights != "fit":
                raise InvalidParameterError(f"weights must be a mapping of term -> weight or 'fit', got {self.weights!r}")
            weights = "fit"
        elif self.weights is None:
            weights = {}
        elif isinstance(self.weights, Mapping):
            weights = {}
            for name, w in self.weights.items():
                if name not in TERMS:
                    raise InvalidParameterError(f"weights: unknown term {name!r}")
                weights[name] = check_number(f"weights[{name!r}]", w, minimum=0.0)
        else:
            raise InvalidParameterError(f"weights must be a mapping of term -> weight or 'fit', got {self.weights!r}")
        check_number("unknown_prior", self.unknown_prior, minimum=0.0, maximum=1.0, high_open=True)
        check_number("outlier_weight", self.outlier_weight, minimum=0.0, maximum=1.0, high_open=True)
        check_number("range_bin_m", self.range_bin_m, minimum=0.0, low_open=True)
        check_number("range_max_m", self.range_max_m, minimum=0.0, low_open=True)
        if not self.range_bin_m < self.range_max_m:
            raise InvalidParameterError(
                f"range_bin_m must be < range_max_m, got {self.range_bin_m!r} and {self.range_max_m!r}"
            )
        check_int("fov_grid", self.fov_grid, minimum=36)
        check_number("min_fov_mass", self.min_fov_mass, minimum=0.0, maximum=1.0, low_open=True)
        check_number("empty_step_deg", self.empty_step_deg, minimum=0.0, low_open=True)
        check_number("merge_tol_deg", self.merge_tol_deg, minimum=0.0)
        return {"terms": terms, "weights": weights}

    def _make_terms(self, terms: tuple[str, ...]) -> dict[str, Term]:
        """Fresh, unfitted terms, in the order of ``terms``."""
        out: dict[str, Term] = {}
        for name in terms:
            if name in MOG_TERMS:
                out[name] = MixtureTerm(
                    name,
                    n_components=self.n_components,
                    min_sigma_deg=self.min_sigma_deg,
                    tol=self.tol,
                    max_iter=self.max_iter,
                    n_init=self.n_init,
                    outlier_weight=self.outlier_weight,
                    fov_grid=self.fov_grid,
                    min_fov_mass=self.min_fov_mass,
                    random_state=self.random_state,
                )
            elif name == "Fp":
                out[name] = FingerprintTerm(
                    likelihood=self.fp_likelihood,
                    reference=self.fp_reference,
                    cyclic=self.cyclic,
                    costs=self.costs,
                    empty_step_deg=self.empty_step_deg,
                    merge_tol_deg=self.merge_tol_deg,
                    laser_letters=self.laser_letters,
                    need_unknown=self.unknown_prior > 0,
                )
            elif name == "R":
                out[name] = RangeTerm(bin_m=self.range_bin_m, max_m=self.range_max_m)
            elif name == "AP":
                out[name] = ProfileTerm()
            elif name == "K":
                out[name] = KeypointTerm()
            else:
                out[name] = AppearanceTerm()
        return out

    # -- learning ------------------------------------------------------------
    def fit(self, observations: Sequence[Observation], labels: Sequence[Hashable] | None = None) -> PlaceModel:
        """Learn one place per distinct label.

        Parameters
        ----------
        observations : sequence of Observation, length n
        labels : sequence of hashable, length n, optional
            The place of each observation (any hashable type, kept as given
            in ``classes_``); by default each observation's ``label``.

        Returns
        -------
        self
        """
        checked = self._checked()
        groups = _group(observations, labels)
        self.places_ = {lab: PlaceData(lab, obs) for lab, obs in groups.items()}
        self.classes_ = _classes(self.places_)
        self.terms_ = self._fit_terms(checked["terms"], list(groups.values()))
        self.weights_: dict[str, float] = {}
        self.temper_ = self._fit_temper(checked["terms"]) if self.temper else 1.0
        if checked["weights"] == "fit":
            self.weights_ = self._fit_term_weights(checked["terms"])
        self._drop_scans()
        return self

    def _drop_scans(self) -> None:
        """Keep the places' views without their raw laser scans once the range term has described them.

        The range term keeps each view's beam counts; nothing else of the model reads a stored
        view's ranges, and the place database does not store them either (a model read back has
        none). A scan is most of a view's memory (1,081 float64 ranges and bearings: 17 KB): a map
        of 300,000 views would hold gigabytes of them.
        """
        if not isinstance(self.terms_.get("R"), RangeTerm):
            return
        for place in self.places_.values():
            if any(o.ranges is not None for o in place.observations):
                place.observations = [_without_scan(o) for o in place.observations]

    def _fit_terms(self, names: tuple[str, ...], groups: list[list[Observation]]) -> dict[str, Term]:
        terms = self._make_terms(names)
        fit_mixture_terms(_mixture_terms(terms), groups, range(len(groups)), fresh=True)
        for t in terms.values():
            if not isinstance(t, MixtureTerm):
                t.fit(groups)
        return terms

    def add_places(self, observations: Sequence[Observation], labels: Sequence[Hashable] | None = None) -> PlaceModel:
        """Learn more observations without refitting the other places.

        Observations of a new label create a place; observations of a known
        label are added to that place, which alone is refit. The terms'
        global calibration (``lambda``, unknown-place costs) is kept.
        """
        if not hasattr(self, "places_"):
            return self.fit(observations, labels)
        self._checked()
        new = _group(observations, labels)
        changed: list[int] = []
        index = {lab: j for j, lab in enumerate(self.places_)}
        for lab, obs in new.items():
            old = self.places_.get(lab)
            self.places_[lab] = PlaceData(lab, (old.observations if old is not None else []) + obs)
            changed.append(index.get(lab, len(index)))
            index.setdefault(lab, len(index))
        self.classes_ = _classes(self.places_)
        groups = [p.observations for p in self.places_.values()]
        fit_mixture_terms(_mixture_terms(self.terms_), groups, changed, fresh=False)
        for t in self.terms_.values():
            if not isinstance(t, MixtureTerm):
                t.update(groups, changed)
        self._drop_scans()
        return self

    def _held_out(self, names: tuple[str, ...]) -> tuple[FArray, NDArray[np.int64], NDArray[np.bool_]] | None:
        """Per-term held-out log-likelihoods ``(T, n, P)``, the true places ``(n,)`` and the places present ``(n, P)``.

        Two folds: alternate views of each place. Places with one view are
        absent from one fold's terms; rows whose place is absent are not
        used. None with fewer than two places with a held-out row.
        """
        n_places = len(self.places_)
        rows: dict[str, list[FArray]] = {t: [] for t in names}
        truth: list[NDArray[np.int64]] = []
        for fold in (0, 1):
            train: list[list[Observation]] = []
            cols: list[int] = []
            test: list[Observation] = []
            test_truth: list[int] = []
            for j, p in enumerate(self.places_.values()):
                tr = [o for i, o in enumerate(p.observations) if i % 2 != fold]
                if tr:
                    train.append(tr)
                    cols.append(j)
                    te = [o for i, o in enumerate(p.observations) if i % 2 == fold]
                    test += te
                    test_truth += [j] * len(te)
            if len(train) < 2 or not test:
                continue
            terms = self._fit_terms(names, train)
            ll = self._term_log_likelihoods(terms, test)
            for t in names:
                full = np.full((len(test), n_places), -np.inf)
                full[:, cols] = ll[t]
                rows[t].append(full)
            truth.append(np.array(test_truth, dtype=np.int64))
        if not truth:
            return None
        y = np.concatenate(truth)
        mats = []
        for t in names:
            m = np.vstack(rows[t])
            finite = m[np.isfinite(m)]
            floor = (float(finite.min()) if finite.size else 0.0) - 100.0
            mats.append(np.where(np.isfinite(m), m, floor))  # a place a term rules out: far below every seen value
        present = np.isfinite(np.vstack(rows[names[0]]))  # places of the fold's terms
        stack = np.stack(mats)  # (T, n, P)
        return stack, y, present

    def _fit_term_weights(self, names: tuple[str, ...]) -> dict[str, float]:
        """Per-term weights maximising the held-out log-probability of the right place (``weights="fit"``).

        :meth:`_held_out`'s folds; without them, every weight 1.
        """
        from scipy.optimize import minimize

        held = self._held_out(names)
        if held is None:
            return {t: 1.0 for t in names}
        stack, y, present = held

        def nll(log_w: FArray) -> float:
            joint = np.tensordot(np.exp(log_w), stack, axes=1)
            joint = np.where(present, joint, -np.inf)
            return -float(np.mean(joint[np.arange(y.size), y] - logsumexp(joint, axis=1)))

        res = minimize(nll, np.zeros(len(names)), method="L-BFGS-B", bounds=[(-9.0, 5.0)] * len(names))
        return {t: float(w) for t, w in zip(names, np.exp(res.x), strict=True)}

    def _fit_temper(self, names: tuple[str, ...]) -> float:
        """The factor ``temper_`` (``temper=True``): maximum held-out log-probability of the right place.

        The weighted sum of :meth:`_held_out`'s log-likelihoods (the weights
        as given; ``weights="fit"`` counts 1 each here), times a factor in
        ``[exp(-6), exp(2)]``; 1 without held-out rows.
        """
        from scipy.optimize import minimize_scalar

        held = self._held_out(names)
        if held is None:
            return 1.0
        stack, y, present = held
        w = np.array([1.0 if self.weights == "fit" else self._weight(t) for t in names])
        joint = np.where(present, np.tensordot(w, stack, axes=1), -np.inf)
        rows = np.arange(y.size)

        def nll(log_tau: float) -> float:
            z = math.exp(log_tau) * joint
            return -float(np.mean(z[rows, y] - logsumexp(z, axis=1)))

        res = minimize_scalar(nll, bounds=(-6.0, 2.0), method="bounded")
        return float(math.exp(res.x))

    # -- inference -------------------------------------------------------------
    def _check_fitted(self) -> None:
        if not hasattr(self, "terms_"):
            raise NotFittedError("this PlaceModel is not fitted yet: call fit(observations, labels) first")

    def _weight(self, term: str) -> float:
        if self.weights == "fit":
            return float(self.weights_.get(term, 1.0))
        return float((self.weights if isinstance(self.weights, Mapping) else {}).get(term, 1.0))

    def _term_log_likelihoods(self, terms: Mapping[str, Term], observations: Sequence[Observation]) -> dict[str, FArray]:
        obs = _observations(observations)
        out: dict[str, FArray] = {}
        rotations = None
        fp = self.terms_.get("Fp")
        if self.rotate_mixtures and fp is not None and any(isinstance(t, MixtureTerm) for t in terms.values()):
            head = fp.headings(obs)
            rotations = None if head is None else -np.nan_to_num(head, nan=0.0)
        for name, t in terms.items():
            out[name] = t.log_likelihood(obs, rotations=rotations if isinstance(t, MixtureTerm) else None)
        return out

    def term_log_likelihoods(self, observations: Sequence[Observation]) -> dict[str, FArray]:
        """Per-term log-likelihoods ``log P(term | loc)``, each of shape ``(n, P)``, unweighted; columns follow ``classes_``."""
        self._check_fitted()
        return self._term_log_likelihoods(self.terms_, observations)

    def _joint(self, terms: Mapping[str, FArray]) -> FArray:
        """``sum_t w_t ll_t`` over the terms of non-zero weight (one of weight 0 adds nothing), tempered."""
        weights = {t: self._weight(t) for t in terms}
        weighted = [weights[t] * ll for t, ll in terms.items() if weights[t] != 0.0]
        if not weighted:
            shape = next(iter(terms.values())).shape if terms else (0, len(self.classes_))
            return np.zeros(shape)
        return np.asarray(sum(weighted), dtype=np.float64) * self.__dict__.get("temper_", 1.0)

    def combine(self, term_log_likelihoods: Mapping[str, FArray]) -> FArray:
        """The weighted sum of per-term log-likelihoods (:meth:`term_log_likelihoods`' answer), shape ``(n, P)``.

        For callers that show the terms and the posterior without computing the terms twice:
        ``normalise_log(model.combine(terms))`` is :meth:`predict_log_proba`.
        """
        self._check_fitted()
        return self._joint(term_log_likelihoods)

    def joint_log_likelihood(self, observations: Sequence[Observation]) -> FArray:
        """Weighted sum of the terms' log-likelihoods, unnormalised, shape ``(n, P)``.

        ``log P(Loc) + sum_term w_term log P(term | Loc)`` up to a constant;
        :meth:`predict_log_proba` normalises it over the places.
        """
        self._check_fitted()
        weighted = {name: t for name, t in self.terms_.items() if self._weight(name) != 0.0}  # the others add nothing
        if not weighted:
            return np.zeros((len(_observations(observations)), len(self.classes_)))
        return self._joint(self._term_log_likelihoods(weighted, observations))

    def predict_log_proba(self, observations: Sequence[Observation]) -> FArray:
        """``log P(Loc | observation)`` normalised over the learned places, shape ``(n, P)``."""
        return normalise_log(self.joint_log_likelihood(observations))

    def predict_proba(self, observations: Sequence[Observation]) -> FArray:
        """Posterior over the learned places, shape ``(n, P)``; rows sum to 1; columns follow :attr:`classes_`."""
        return np.exp(self.predict_log_proba(observations))

    def predict(self, observations: Sequence[Observation]) -> NDArray[np.object_]:
        """Most probable place of each observation, shape ``(n,)``, labels of the type given to :meth:`fit`."""
        best = np.argmax(self.predict_log_proba(observations), axis=1)
        return self.classes_[best]

    def rank(self, observations: Sequence[Observation]) -> NDArray[np.int64]:
        """Rank of every place for each observation, shape ``(n, P)``; 1 = best, ties count against."""
        return rank_scores(self.predict_log_proba(observations))

    def column_of(self, label: Hashable) -> int:
        """Column of a place label in ``classes_`` (its string form is accepted too)."""
        self._check_fitted()
        col = self.__dict__.get("_col")
        if col is None or len(col) < len(self.classes_):
            col = {}
            for j, c in enumerate(self.classes_):
                col.setdefault(str(c), j)
                col[c] = j
            self._col = col
        try:
            return int(col[label])
        except (KeyError, TypeError):
            raise InvalidParameterError(f"{label!r} is not a learned place") from None

    def rank_of(self, observations: Sequence[Observation], labels: Sequence[Hashable] | None = None) -> NDArray[np.int64]:
        """Rank of the true place of each observation, shape ``(n,)`` (ties count against)."""
        obs = _observations(observations)
        labs = [o.label for o in obs] if labels is None else list(labels)
        if len(labs) != len(obs):
            raise InvalidParameterError(f"labels: one label per observation is needed, got {len(labs)} for {len(obs)}")
        ranks = self.rank(obs)
        out = np.empty(len(obs), dtype=np.int64)
        for i, lab in enumerate(labs):
            try:
                out[i] = ranks[i, self.column_of(lab)]
            except InvalidParameterError:
                raise InvalidParameterError(f"label {lab!r} of observation {i} is not a learned place") from None
        return out

    def score(self, observations: Sequence[Observation], labels: Sequence[Hashable] | None = None) -> float:
        """Right classification rate (top-1) on labelled observations."""
        return float(np.mean(self.rank_of(observations, labels) == 1))

    def predict_unknown_proba(self, observations: Sequence[Observation]) -> FArray:
        """Probability that each observation comes from no learned place, shape ``(n,)``.

        The "unknown" hypothesis has prior ``unknown_prior`` and a background
        likelihood from each term (:meth:`fingerloc.terms.Term.unknown_log_likelihood`):
        the uniform density on the seen arc for the mixtures, and for the
        distance terms their likelihood at the median distance of a training
        view to the nearest *other* place. Zero when ``unknown_prior`` is 0.
        """
        self._check_fitted()
        obs = _observations(observations)
        if self.unknown_prior <= 0:
            return np.zeros(len(obs))
        joint = self.joint_log_likelihood(obs)
        bg = np.zeros(len(obs))
        for name, t in self.terms_.items():
            bg += self._weight(name) * t.unknown_log_likelihood(obs)
        bg *= self.__dict__.get("temper_", 1.0)
        n_places = joint.shape[1]
        known = logsumexp(joint, axis=1) + math.log((1 - self.unknown_prior) / n_places)
        unknown = bg + math.log(self.unknown_prior)
        return np.exp(unknown - np.logaddexp(known, unknown))

    def headings(self, observations: Sequence[Observation], places: Sequence[Hashable] | None = None) -> FArray:
        """Heading estimate (degrees) of each observation relative to a place's stored views.

        For each observation, the best cyclic alignment against the given
        place's training fingerprints (default: its most probable place)
        gives the angle to add to the stored view's bearings to bring them
        onto the observation's. NaN where no estimate exists.
        """
        return self.headings_with_reference(observations, places)[0]

    def prepare_headings(self, observations: Sequence[Observation]) -> None:
        """Align the observations against every training view in one batch, for headings at many places.

        :meth:`headings_with_reference` for these observations at every
        place (one call per place) then reuses the batch: the same headings,
        without aligning each observation again per place. Worth it when
        headings at most places are wanted (:func:`fingerloc.pipeline.tracker.implied_headings`);
        for one place per observation it would align against every view
        for nothing.
        """
        self._check_fitted()
        fp = self.terms_.get("Fp")
        if isinstance(fp, FingerprintTerm):
            fp.remember(_observations(observations))

    def headings_with_reference(
        self, observations: Sequence[Observation], places: Sequence[Hashable] | None = None
    ) -> tuple[FArray, NDArray[np.int64]]:
        """:meth:`headings`, and the index of the place's training view each heading is measured against (-1: none)."""
        h, ref, _ = self.heading_sources(observations, places)
        return h, ref

    def heading_sources(
        self, observations: Sequence[Observation], places: Sequence[Hashable] | None = None
    ) -> tuple[FArray, NDArray[np.int64], list[str | None]]:
        """:meth:`headings_with_reference`, and what each heading comes from.

        In order: with the local-feature term ``K``, the relative rotation
        verified against the place's best-matching view
        (:meth:`fingerloc.terms.KeypointTerm.heading_at`; ``"keypoints"``);
        with the aligned-profile term ``AP``, the best-matching view's
        profile (``"profile"``); else the fingerprint string's cyclic
        alignment (``"fingerprint"``). None where no heading exists.
        """
        self._check_fitted()
        ap = self.terms_.get("AP")
        kt = self.terms_.get("K")
        fp = self.terms_.get("Fp")
        if not isinstance(fp, FingerprintTerm):  # a model without the string term: its fingerprints, for headings only
            fp = self.__dict__.get("_heading_term")
            if fp is None or len(fp.fingerprints_) != len(self.places_):
                fp = FingerprintTerm(
                    costs=self.costs,
                    empty_step_deg=self.empty_step_deg,
                    merge_tol_deg=self.merge_tol_deg,
                    laser_letters=self.laser_letters,
                ).fit([p.observations for p in self.places_.values()])
                self._heading_term = fp
        obs = _observations(observations)
        labs = list(self.predict(obs)) if places is None else list(places)
        out = np.full(len(obs), np.nan)
        ref = np.full(len(obs), -1, dtype=np.int64)
        src: list[str | None] = [None] * len(obs)
        for i, (o, lab) in enumerate(zip(obs, labs, strict=True)):
            col = self.column_of(lab)
            # every source gives "bearing in the view = bearing in o + h": the fingerprint's convention is -h
            if isinstance(kt, KeypointTerm) and o.keypoints is not None:
                hk, v, _ = kt.heading_at(o, col)
                if hk is not None:
                    out[i], ref[i], src[i] = float(np.mod(-hk, 360.0)), v, "keypoints"
                    continue
            if isinstance(ap, ProfileTerm) and o.profile is not None:
                hp, v = ap.heading_at(o, col)
                if hp is not None:
                    out[i], ref[i], src[i] = float(np.mod(-hp, 360.0)), v, "profile"
                    continue
            h, v = fp.heading_at(o, col)
            if h is not None:
                out[i], src[i] = h, "fingerprint"
            ref[i] = v
        return out, ref, src

    # -- state -------------------------------------------------------------------
    @property
    def fp_lambda_(self) -> float:
        """``lambda`` of ``fp_likelihood="exp"`` (1 until calibrated)."""
        self._check_fitted()
        t = self.terms_.get("Fp")
        return float(t.lambda_) if isinstance(t, FingerprintTerm) else 1.0

    def to_state(self) -> dict[str, Any]:
        """The fitted model as plain data: ``params`` (as :meth:`get_params`), ``labels``,
        ``observations`` (per place), ``terms`` (name -> the term's state), ``weights`` (fitted)."""
        self._check_fitted()
        return {
            "params": self.get_params(),
            "labels": list(self.classes_),
            "observations": [list(p.observations) for p in self.places_.values()],
            "terms": {name: t.to_state() for name, t in self.terms_.items()},
            "weights": dict(self.weights_),
            "temper": float(self.__dict__.get("temper_", 1.0)),
        }

    @classmethod
    def from_state(cls, state: Mapping[str, Any]) -> PlaceModel:
        """A fitted model from :meth:`to_state`'s data; a term without stored state is refit from the observations."""
        model = cls(**state["params"])
        checked = model._checked()
        labels = list(state["labels"])
        groups = [list(g) for g in state["observations"]]
        if len(labels) != len(groups) or len(set(labels)) != len(labels):
            raise InvalidParameterError("state: labels must be distinct, one per group of observations")
        model.places_ = {lab: PlaceData(lab, g) for lab, g in zip(labels, groups, strict=True)}
        model.classes_ = _classes(model.places_)
        fresh = model._make_terms(checked["terms"])
        stored = state.get("terms", {})
        missing = [n for n in fresh if n not in stored]
        if missing:
            fitted = model._fit_terms(tuple(missing), groups)
            fresh.update(fitted)
        for name, t in fresh.items():
            if name in stored:
                t.set_state(stored[name], groups)
        model.terms_ = fresh
        model.weights_ = {str(k): float(v) for k, v in state.get("weights", {}).items()}
        model._drop_scans()
        model.temper_ = float(state.get("temper", 1.0))
        return model


def _without_scan(o: Observation) -> Observation:
    """``o`` without its raw scan (``ranges``, ``range_bearings``): a shallow copy, the other fields shared."""
    if o.ranges is None:
        return o
    out = object.__new__(Observation)
    for name in _OBSERVATION_FIELDS:  # a frozen dataclass: its fields are set once, here on a new copy
        object.__setattr__(out, name, None if name in ("ranges", "range_bearings") else getattr(o, name))
    return out


_OBSERVATION_FIELDS = tuple(f.name for f in dataclasses.fields(Observation))


def _observations(observations: Sequence[Observation]) -> list[Observation]:
    obs = list(observations)
    for i, o in enumerate(obs):
        if not isinstance(o, Observation):
            raise InvalidParameterError(f"observations[{i}] must be an Observation, got {type(o).__name__}")
    return obs


def _group(observations: Sequence[Observation], labels: Sequence[Hashable] | None) -> dict[Hashable, list[Observation]]:
    """Observations grouped by place label, in order of first appearance (labels kept as given)."""
    obs = _observations(observations)
    if not obs:
        raise InvalidParameterError("fit needs at least one observation")
    labs: list[Any] = [o.label for o in obs] if labels is None else list(labels)
    if len(labs) != len(obs):
        raise InvalidParameterError(f"labels: one label per observation is needed, got {len(labs)} for {len(obs)}")
    groups: dict[Hashable, list[Observation]] = {}
    for i, (o, lab) in enumerate(zip(obs, labs, strict=True)):
        if lab is None or lab == "" or (isinstance(lab, float) and math.isnan(lab)):
            raise InvalidParameterError(f"observation {i} has no place label (give labels= or set each label)")
        if not isinstance(lab, Hashable):
            raise InvalidParameterError(f"labels[{i}] must be hashable (a string or a number), got {lab!r}")
        text = str(lab)
        groups.setdefault(lab, []).append(o if o.label == text else o.with_label(text))
    return groups


def _classes(places: Mapping[Hashable, PlaceData]) -> NDArray[np.object_]:
    out = np.empty(len(places), dtype=object)
    for j, lab in enumerate(places):
        out[j] = lab
    return out


def _mixture_terms(terms: Mapping[str, Term]) -> list[MixtureTerm]:
    """The mixture terms in fitting order (place by place, then VE, CP, Ex, B)."""
    return [t for name in MOG_TERMS if isinstance(t := terms.get(name), MixtureTerm)]


def normalise_log(joint: FArray) -> FArray:
    """Rows of log-likelihoods normalised to log-probabilities; a row with no finite entry becomes uniform."""
    joint = np.asarray(joint, dtype=np.float64)
    if joint.shape[1] == 0:
        raise NotFittedError("the model has no place")
    dead = np.asarray(~np.isfinite(joint).any(axis=1) | np.isnan(joint).any(axis=1), dtype=bool)
    safe = np.where(dead[:, None], 0.0, np.nan_to_num(joint, nan=-np.inf, posinf=np.finfo(float).max))
    return safe - logsumexp_rows(safe)

