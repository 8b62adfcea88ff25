"""The pose filter along a run, one step at a time: the one driver of every tracking variant.

:class:`PoseTracking` holds a :class:`~fingerloc.map.pose_filter.PoseFilter`
and what runs beside it, and takes one step at a time (:meth:`PoseTracking.step`):

1. the discrete place filter over the place graph (:class:`~fingerloc.map.filter.MarkovFilter`)
   predicts with the travelled distance and, at an observation, updates; its
   predicted belief is where a kidnapped robot is looked for (``relocalize``),
   and its posterior breaks near-ties between observations (``tie_break``);
2. the pose filter moves by the odometry increment; an increment longer than
   ``gap_metres`` is a gap in the run, and the next observation
   re-initialises the particles from the sensor, as the first one does
   (``start_at_first_observation``);
3. at an observation, its weight (the *tempering*: an observation counts
   fully after the robot travelled ``temper[0]`` metres or turned
   ``temper[1]`` radians since the previous one, in proportion before,
   :func:`~fingerloc.map.pose_filter.observation_weights`) and the
   *strategy* decide the update:

   * ``None``: the plain update (with the pose filter's own kidnapping
     term and, with a scan map, its lost rule);
   * :class:`SensorReset`: sensor resetting when the place filter has
     explained the views better for long (Page's CUSUM test; Lenser and
     Veloso 2000);
   * :class:`Challenger`: a second filter started from the sensor, adopted
     when its trajectory fits the views better;
   * :class:`Augmented`: Augmented MCL's adaptive re-drawing (Thrun, Burgard
     and Fox, *Probabilistic Robotics*, 2005, 8.3.5);
4. the answer: the posterior's most probable place at an observation;
   between observations it is held unless another place leads by
   ``hold_margin``, and near-ties within ``tie_break`` go to the place the
   place filter believes most (a particle filter's posterior between two
   places is a near-tie that two runs break differently).

:func:`run_pose_filter` runs it along whole arrays (the benchmark and the
tuning on the mapping part); the streaming tracker of
:mod:`fingerloc.pipeline.tracker` calls :meth:`PoseTracking.step` as the
data arrive. Both give the same answers for the same inputs and seed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .._lse import logsumexp
from .._types import FArray
from ..errors import InvalidParameterError
from ._checks import finite as _finite
from .filter import FilterResult, MarkovFilter, entropy_bits
from .pose_filter import PoseFilter
from .scan_map import ScanMap

__all__ = [
    "AnswerRule",
    "Augmented",
    "Challenger",
    "PoseStep",
    "PoseTracking",
    "SensorReset",
    "Tempering",
    "run_pose_filter",
]


@dataclass(frozen=True, slots=True)
class SensorReset:
    """Sensor resetting when the particles and the sensor disagree for long.

    At each observation with robust place likelihood ``p`` (tempered by the
    observation's weight ``w``), the evidence that the particles still hold
    the robot against the alternative (the place filter's predicted belief,
    else a uniform prior over the places) is ``r = w (log sum_j pose_j p_j -
    log sum_j alt_j p_j)``; the one-sided cumulative sum ``S = min(0, S +
    r)`` falls when observation after observation the alternative explains
    the views better. When ``S < -threshold`` (nats), ``fraction`` of the
    particles are re-drawn from the alternative's posterior ``alt_j p_j``
    (:meth:`~fingerloc.map.pose_filter.PoseFilter.reseed`) and ``S`` restarts at 0.

    Attributes
    ----------
    threshold : float
        Nats, >= 0.
    fraction : float, default 0.5
        In ``(0, 1]``.
    """

    threshold: float
    fraction: float = 0.5

    def __post_init__(self) -> None:
        _finite("threshold", self.threshold)
        if not 0 < _finite("fraction", self.fraction) <= 1:
            raise InvalidParameterError(f"fraction must be in (0, 1], got {self.fraction!r}")


@dataclass(frozen=True, slots=True)
class Challenger:
    """A challenger filter started from the sensor, adopted when its trajectory fits the views better.

    A kidnapped (or lost) pose filter recovers slowly: its kidnapping term
    re-draws a few particles with the views' likelihood, and those, with a
    guessed heading, seldom survive the next moves. When an observation is
    explained better by "the robot is anywhere" (the place filter's
    predicted belief, or uniform, times the robust likelihood) than by the
    incumbent's particles by more than ``spawn_nats``, a whole second filter
    (the *challenger*) is started from that observation (the places' prior
    times the likelihood, any heading) and moved by the same odometry. At
    each later observation both filters' log predictive likelihoods
    (:meth:`~fingerloc.map.pose_filter.PoseFilter.log_evidence`) are added to
    a log Bayes factor, which starts with the starting observation's ratio.
    A run of confident wrong single-shot answers seldom forms a trajectory
    consistent with the odometry and the place layout, so a challenger born
    of them loses and is dropped; after a real kidnapping the challenger's
    particles follow the robot and it wins within a few observations. The
    incumbent then adopts its particles. Answers are the incumbent's.

    Attributes
    ----------
    n_particles : int, default 1000
        Particles of the challenger (the incumbent keeps its own count).
    spawn_nats : float, default 0.0
    switch_nats : float, default 3.0
        The log Bayes factor that makes the switch.
    drop_nats : float, default 3.0
        The challenger is dropped when that factor falls below ``-drop_nats`` ...
    max_observations : int, default 10
        ... or after this many observations without a switch ...
    merged_tv : float, default 0.25
        ... or when its place posterior is within this total variation of
        the incumbent's (it has found the same track: no rival).
    tempered_evidence : bool, default True
        Compare the two trajectories with the tempered likelihoods (as the
        updates weigh them); False: every observation at full weight in the
        Bayes factor (the updates stay tempered).
    """

    n_particles: int = 1000
    spawn_nats: float = 0.0
    switch_nats: float = 3.0
    drop_nats: float = 3.0
    max_observations: int = 10
    merged_tv: float = 0.25
    tempered_evidence: bool = True

    def __post_init__(self) -> None:
        if isinstance(self.n_particles, bool) or not isinstance(self.n_particles, (int, np.integer)) or self.n_particles < 10:
            raise InvalidParameterError(f"n_particles must be an integer >= 10, got {self.n_particles!r}")
        _finite("switch_nats", self.switch_nats)
        _finite("drop_nats", self.drop_nats)
        if not math.isfinite(float(self.spawn_nats)):
            raise InvalidParameterError(f"spawn_nats must be finite, got {self.spawn_nats!r}")
        if isinstance(self.max_observations, bool) or not isinstance(self.max_observations, (int, np.integer)) or self.max_observations < 1:
            raise InvalidParameterError(f"max_observations must be an integer >= 1, got {self.max_observations!r}")


@dataclass(frozen=True, slots=True)
class Augmented:
    """Augmented MCL: a share of the belief re-drawn from the sensor when the views are explained worse than usual.

    Two exponential averages of the particles' mean observation likelihood
    ``l`` (:meth:`~fingerloc.map.pose_filter.PoseFilter.log_evidence`,
    untempered): ``w_slow += slow * w * (l - w_slow)``, ``w_fast += fast * w
    * (l - w_fast)`` (``w`` the observation's tempering weight; both start at
    the first ``l``, and again after a re-initialisation); the share ``s =
    min(cap, max(floor, 1 - (w_fast / w_slow) / threshold))``. When ``s``
    exceeds the filter's own tempered kidnapping probability, the update
    takes ``kidnap=s``: the belief becomes ``(1 - s)`` the tracked particles'
    posterior plus ``s`` the sensor's (the place filter's predicted belief, or
    uniform, times the likelihood), and fresh particles drawn there carry that share.

    Attributes
    ----------
    slow : float, default 0.05
    fast : float, default 0.5
        > ``slow`` (unless ``floor`` > 0 or not ``adaptive``).
    cap : float, default 0.5
        Largest share drawn afresh at one observation, in ``[0, 1]``.
    floor : float, default 0.0
        Smallest share drawn afresh at every observation (the constant
        sensor-drawn share of the mixture proposal of Thrun, Fox, Burgard and
        Dellaert 2001); 0 = only the adaptive share.
    threshold : float, default 1.0
        In ``(0, 1]``; 1 is the book's rule.
    relative : bool, default False
        Average the particles' likelihood relative to the sensor's own ("the
        robot is anywhere"), so that a view the front end gets wrong
        everywhere does not look like a kidnapping.
    reserve : int, default 0
        Particles drawn from the sensor at every observation and kept at
        their own small weight (the share) instead of being resampled with
        the tracked ones; 0 = the pose filter's own kidnapping component.
    adaptive : bool, default True
        False: no averages, the share is ``floor`` or the filter's own
        kidnapping probability.
    """

    slow: float = 0.05
    fast: float = 0.5
    cap: float = 0.5
    floor: float = 0.0
    threshold: float = 1.0
    relative: bool = False
    reserve: int = 0
    adaptive: bool = True

    def __post_init__(self) -> None:
        for name in ("slow", "fast", "cap", "floor"):
            v = float(getattr(self, name))
            if not (math.isfinite(v) and 0 <= v <= 1):
                raise InvalidParameterError(f"{name} must be in [0, 1], got {getattr(self, name)!r}")
        if isinstance(self.reserve, bool) or not isinstance(self.reserve, (int, np.integer)) or self.reserve < 0:
            raise InvalidParameterError(f"reserve must be an integer >= 0, got {self.reserve!r}")
        if not (math.isfinite(float(self.threshold)) and 0 < self.threshold <= 1):
            raise InvalidParameterError(f"threshold must be in (0, 1], got {self.threshold!r}")
        if self.adaptive and self.fast <= self.slow and self.floor == 0:
            raise InvalidParameterError(f"fast must exceed slow, got fast={self.fast!r}, slow={self.slow!r}")
        if self.floor > self.cap:
            raise InvalidParameterError(f"floor must not exceed cap, got {self.floor!r} > {self.cap!r}")


Strategy = SensorReset | Challenger | Augmented | None


class Tempering:
    """The weight of each observation from the motion since the previous one (step by step).

    An observation counts ``min(1, max(travelled / metres + |turned| /
    radians, 1e-3))``, the motion summed since the previous observation; the
    first observation counts 1 (:func:`~fingerloc.map.pose_filter.observation_weights`
    over a whole run gives the same numbers).
    """

    def __init__(self, metres: float, radians: float = math.inf) -> None:
        m = _finite("metres", metres)
        r = float(radians)
        if m <= 0 or not r > 0:
            raise InvalidParameterError(f"metres and radians must be > 0, got {metres!r}, {radians!r}")
        self.metres, self.radians = m, r
        self.reset()

    def reset(self) -> None:
        """Nothing travelled, no observation yet."""
        self.moved, self.turned, self.first = 0.0, 0.0, True

    def move(self, increment: FArray) -> None:
        """Add one odometry increment ``(dx, dy, dtheta)``."""
        self.moved += math.hypot(increment[0], increment[1])
        self.turned += abs(increment[2])

    def observe(self) -> float:
        """The weight of an observation now; the motion starts again from 0."""
        r = self.radians
        w = 1.0 if self.first else min(1.0, max(self.moved / self.metres + (self.turned / r if math.isfinite(r) else 0.0), 1e-3))
        self.moved, self.turned, self.first = 0.0, 0.0, False
        return w


class AnswerRule:
    """The answer at each step from the place posterior: the argmax at an observation, held and tie-broken between.

    A particle filter's place posterior between two observations is often a
    near-tie of two places' Voronoi cells, which two runs (other random
    draws) break differently. Between observations the previous answer ``k``
    stays unless another place's probability exceeds it by ``hold_margin``
    (then the argmax); then, among the places within ``tie_break`` of the
    answer, the one a deterministic belief (the place filter's) believes
    most. At an observed step the answer is the argmax; the posterior itself
    is never changed.

    Parameters
    ----------
    hold_margin : float, optional
        Probability (>= 0, ``inf``: hold until the next observation); ``None``: off.
    tie_break : float, optional
        Probability (>= 0; 0: exact ties only); ``None``: off.
    """

    def __init__(self, hold_margin: float | None = None, tie_break: float | None = None) -> None:
        if hold_margin is not None and (math.isnan(hold_margin) or hold_margin < 0):
            raise InvalidParameterError(f"hold_margin must be a probability difference >= 0 (or inf), got {hold_margin!r}")
        if tie_break is not None and (math.isnan(tie_break) or tie_break < 0 or math.isinf(tie_break)):
            raise InvalidParameterError(f"tie_break must be a probability difference >= 0, got {tie_break!r}")
        self.hold_margin = hold_margin
        self.tie_break = tie_break
        self.reset()

    def reset(self) -> None:
        """No previous answer."""
        self._held: int | None = None  # the hold rule's answer at the previous step

    def step(self, log_posterior: Any, observed: bool, tie_belief: Any = None) -> tuple[int, float]:
        """The answer (place index) and its probability at one step.

        ``tie_belief`` (shape (P,), log-probabilities or any scores, larger =
        more likely): the deterministic belief that breaks near-ties (needed
        with ``tie_break`` between observations).
        """
        lp = np.asarray(log_posterior, dtype=np.float64)
        best = int(np.argmax(lp))
        if observed or (self.hold_margin is None and self.tie_break is None):
            self._held = best
            return best, float(np.exp(lp[best]))
        p = np.exp(lp)
        if self.hold_margin is not None and self._held is not None and not p[best] > p[self._held] + float(self.hold_margin):
            best = self._held
        self._held = best
        if self.tie_break is not None:
            if tie_belief is None:
                raise InvalidParameterError("tie_break needs the deterministic belief of the step")
            tb = np.asarray(tie_belief, dtype=np.float64)
            cand = np.flatnonzero(p >= p[best] - float(self.tie_break))
            best = int(cand[np.argmax(np.nan_to_num(tb[cand], nan=-np.inf))])
        return best, float(p[best])


@dataclass(frozen=True, slots=True)
class PoseStep:
    """One step's answer of :class:`PoseTracking`.

    Attributes
    ----------
    log_posterior : ndarray, shape (P,)
        The place log-posterior (normalised).
    best : int
        The answer: the most probable place at an observation, the held or
        tie-broken one between observations.
    probability : float
        The posterior probability of ``best``.
    observed : bool
    """

    log_posterior: FArray
    best: int
    probability: float
    observed: bool


@dataclass(slots=True)
class _ChallengerState:
    rival: PoseFilter | None = None
    factor: float = 0.0
    age: int = 0
    switches: list[int] = field(default_factory=list)
    trace: list[tuple[int, str, float]] = field(default_factory=list)


class PoseTracking:
    """A pose filter driven one step at a time, with what runs beside it (module docstring).

    Parameters
    ----------
    pose_filter : PoseFilter
        Reset by :meth:`reset` (its random generator carries on).
    place_filter : MarkovFilter, optional
        The discrete filter over the same places run alongside (needed by
        ``relocalize`` and ``tie_break``).
    relocalize : bool, default True
        A kidnapped robot is looked for where the place filter's predicted
        belief is (else anywhere, uniformly).
    temper : (metres, radians), optional
        Weigh the observations by the motion between them (:class:`Tempering`);
        ``None``: every observation counts fully, unless :meth:`step` is given a weight.
    heading_temper : (metres, radians), optional
        The heading evidence's own tempering (default: the observations').
    start_at_first_observation : bool, default False
        Draw the particles at the first observation from the places' prior
        times its likelihood (a global localization from the sensor) instead
        of carrying the start prior blindly.
    gap_metres : float, optional
        An odometry increment longer than this is a gap in the run: the next
        observation re-initialises the particles as the first one does.
    strategy : SensorReset, Challenger or Augmented, optional
        How an observation updates the belief (module docstring); ``None``: plainly.
    hold_margin : float, optional
        Between observations, the previous answer stays unless another place's
        probability exceeds it by this much (``None``: the argmax).
    tie_break : float, optional
        Between observations, among the places within this probability of the
        answer, the one the place filter believes most (``None``: off).

    Attributes
    ----------
    t_ : int
        Steps taken since :meth:`reset`.
    resets_, switches_, challenger_trace_, shares_
        Per strategy: sensor resets; the challenger's switches (steps) and
        ``(step, event, log Bayes factor)`` events; Augmented MCL's ``(step, share)``.
    """

    def __init__(
        self,
        pose_filter: PoseFilter,
        *,
        place_filter: MarkovFilter | None = None,
        relocalize: bool = True,
        temper: tuple[float, float] | None = None,
        heading_temper: tuple[float, float] | None = None,
        start_at_first_observation: bool = False,
        gap_metres: float | None = None,
        strategy: Strategy = None,
        hold_margin: float | None = None,
        tie_break: float | None = None,
    ) -> None:
        self.pose_filter = pose_filter
        self.place_filter = place_filter
        if place_filter is not None and place_filter.transition.n_places != pose_filter.n_places:
            raise InvalidParameterError(
                f"the place filter has {place_filter.transition.n_places} places, need {pose_filter.n_places}"
            )
        if tie_break is not None and place_filter is None:
            raise InvalidParameterError("tie_break needs the place filter")
        if strategy is not None and not isinstance(strategy, (SensorReset, Challenger, Augmented)):
            raise InvalidParameterError(f"strategy must be SensorReset, Challenger, Augmented or None, got {strategy!r}")
        self.relocalize = bool(relocalize) and place_filter is not None
        self.temper = None if temper is None else Tempering(*temper)
        self.heading_temper = None if heading_temper is None else Tempering(*heading_temper)
        self.start_at_first_observation = bool(start_at_first_observation)
        self.gap = math.inf if gap_metres is None else _finite("gap_metres", gap_metres)
        self.strategy = strategy
        self.answers = AnswerRule(hold_margin, tie_break)
        self._start()  # the pose filter is not reset here: a run starts with reset() (run_pose_filter does)

    @property
    def n_places(self) -> int:
        """Number of places ``P``."""
        return self.pose_filter.n_places

    def reset(self) -> PoseTracking:
        """Back to the start of a run (the pose filter's particles drawn again from its start prior)."""
        self.pose_filter.reset()
        if self.place_filter is not None:
            self.place_filter.reset()
        self._start()
        return self

    def _start(self) -> None:
        """The driver's own state at the start of a run."""
        for tw in (self.temper, self.heading_temper):
            if tw is not None:
                tw.reset()
        self.t_ = 0
        self._lost = self.start_at_first_observation
        self.answers.reset()
        self._cusum = 0.0
        self.resets_ = 0
        self._challenger = _ChallengerState()
        self._w_slow = self._w_fast = math.nan
        self.shares_: list[tuple[int, float]] = []

    @property
    def switches_(self) -> list[int]:
        """The challenger's switches (steps)."""
        return self._challenger.switches

    @property
    def challenger_trace_(self) -> list[tuple[int, str, float]]:
        """The challenger's ``(step, event, log Bayes factor)`` events."""
        return self._challenger.trace

    def step(
        self,
        log_likelihood: Any = None,
        increment: Any = None,
        *,
        weight: float | None = None,
        heading_weight: float | None = None,
        headings: Any = None,
        points: Any = None,
        scan_map: ScanMap | None = None,
    ) -> PoseStep:
        """One step: move by ``increment``, then (with an observation) update; the answer.

        Parameters
        ----------
        log_likelihood : array_like, shape (P,), optional
            The observation's (scaled) single-shot log-likelihood per place;
            ``None`` or all NaN: no observation (prediction only).
        increment : array_like, shape (3,), optional
            Odometry ``(dx, dy, dtheta)`` since the previous step (robot frame
            of the previous step, metres and radians); ignored at the first
            step, ``None`` = no motion.
        weight : float, optional
            The observation's weight in ``(0, 1]`` (default: the tempering's, else 1).
        heading_weight : float, optional
            The heading evidence's weight (default: its own tempering's, else ``weight``).
        headings : array_like, shape (P,), optional
            The heading (radians, map frame) the observation implies at each
            place (NaN = none), used with the filter's heading model.
        points : array_like, shape (m, 2), optional
            The observation's laser end points (robot frame, metres), used
            with the filter's scan map.
        scan_map : ScanMap, optional
            Score ``points`` against this map instead of the filter's.

        Returns
        -------
        PoseStep
        """
        t = self.t_
        self.t_ += 1
        row = None if log_likelihood is None else np.asarray(log_likelihood, dtype=np.float64).reshape(-1)
        observed = row is not None and not bool(np.all(np.isnan(row)))
        inc = None
        if t > 0 and increment is not None:
            inc = np.asarray(increment, dtype=np.float64).reshape(-1)
            if inc.size != 3:
                raise InvalidParameterError(f"an odometry increment is 3 numbers (dx, dy, dtheta), got {increment!r}")
        elif t > 0:
            inc = np.zeros(3)
        pf = self.pose_filter
        # the place filter: its predicted belief (the kidnapping prior), then its update
        prior = None
        if self.place_filter is not None:
            pl = self.place_filter
            prior = pl.predict(math.hypot(inc[0], inc[1])) if inc is not None else pl.log_belief_
            if observed:
                assert row is not None
                pl.update(np.where(np.isnan(row), -np.inf, row))
        kidnap_prior = prior if self.relocalize else None
        if inc is not None:
            pf.predict(inc)
            if isinstance(self.strategy, Challenger) and self._challenger.rival is not None:
                self._challenger.rival.predict(inc)
            for tw in (self.temper, self.heading_temper):
                if tw is not None:
                    tw.move(inc)
            if math.hypot(inc[0], inc[1]) > self.gap:
                self._lost = True
                self._challenger.rival = None
        if not observed:
            return self._answer(pf.place_log_posterior(), False)
        assert row is not None
        w = self.temper.observe() if self.temper is not None else 1.0
        hw = self.heading_temper.observe() if self.heading_temper is not None else None
        if weight is not None:
            w = float(weight)
        if heading_weight is not None:
            hw = float(heading_weight)
        hd = None if headings is None else np.asarray(headings, dtype=np.float64).reshape(-1)
        q = None if points is None else np.asarray(points, dtype=np.float64).reshape(-1, 2)
        if isinstance(self.strategy, Challenger):
            out = self._observe_challenged(t, row, w, hw, kidnap_prior, hd, q, scan_map)
        elif isinstance(self.strategy, Augmented):
            out = self._observe_augmented(t, row, w, hw, kidnap_prior, hd, q, scan_map)
        else:
            out = self._observe(row, w, hw, kidnap_prior, hd, q, scan_map)
        return self._answer(out, True)

    # -- the strategies -----------------------------------------------------------------------------

    def _answer(self, log_posterior: FArray, observed: bool) -> PoseStep:
        """The step's answer (:class:`AnswerRule`, near-ties to the place filter's belief)."""
        tb = None if self.place_filter is None else self.place_filter.log_belief_
        best, prob = self.answers.step(log_posterior, observed, tb)
        return PoseStep(np.asarray(log_posterior, dtype=np.float64), best, prob, observed)

    def _reinitialise(self, row: FArray, prior: Any, hd: FArray | None, q: FArray | None, sm: ScanMap | None) -> FArray:
        """The particles re-drawn from the sensor (the first observation, after a gap)."""
        self._lost = False
        return self.pose_filter.update(row, 1.0, prior, kidnap=1.0, headings=hd, points=q, scan_map=sm)

    def _observe(
        self, row: FArray, w: float, hw: float | None, prior: Any, hd: FArray | None, q: FArray | None, sm: ScanMap | None
    ) -> FArray:
        """The plain update, with sensor resetting (:class:`SensorReset`) when it is the strategy."""
        pf = self.pose_filter
        reset = self.strategy if isinstance(self.strategy, SensorReset) else None
        theirs = None
        if reset is not None:
            lp = pf.place_likelihood(row)
            alt = np.full(pf.n_places, -math.log(pf.n_places)) if prior is None else prior
            mine = pf.place_log_posterior() + lp
            theirs = alt + lp
            self._cusum = min(0.0, self._cusum + w * (float(logsumexp(mine)) - float(logsumexp(theirs))))
        if self._lost:
            self._cusum = 0.0
            return self._reinitialise(row, prior, hd, q, sm)
        out = pf.update(row, w, prior, headings=hd, heading_weight=hw, points=q, scan_map=sm)
        if reset is not None and self._cusum < -reset.threshold:
            assert theirs is not None
            out = pf.reseed(theirs - logsumexp(theirs), reset.fraction)
            self._cusum = 0.0
            self.resets_ += 1
        return out

    def _observe_challenged(
        self, t: int, row: FArray, w: float, hw: float | None, prior: Any, hd: FArray | None, q: FArray | None,
        sm: ScanMap | None,
    ) -> FArray:  # fmt: skip
        """The update with a challenger (:class:`Challenger`)."""
        ch = self.strategy
        assert isinstance(ch, Challenger)
        st = self._challenger
        pf = self.pose_filter
        if self._lost:
            return self._reinitialise(row, prior, hd, q, sm)
        we = w if ch.tempered_evidence else 1.0
        mine = pf.log_evidence(row, we, hd)
        if st.rival is not None:
            st.factor += st.rival.log_evidence(row, we, hd) - mine
            st.rival.update(row, w, prior, headings=hd, heading_weight=hw, points=q, scan_map=sm)
            st.age += 1
            st.trace.append((t, "compare", st.factor))
        out = pf.update(row, w, prior, headings=hd, heading_weight=hw, points=q, scan_map=sm)
        if st.rival is not None:
            if st.factor > ch.switch_nats:
                out = pf.adopt(st.rival)
                st.switches.append(t)
                st.trace.append((t, "switch", st.factor))
                st.rival = None
                self.resets_ += 1
            elif (
                st.factor < -ch.drop_nats
                or st.age >= ch.max_observations
                or 0.5 * float(np.abs(np.exp(st.rival.place_log_posterior()) - np.exp(out)).sum()) < ch.merged_tv
            ):
                st.trace.append((t, "drop", st.factor))
                st.rival = None
            return out
        alt = np.full(pf.n_places, -math.log(pf.n_places)) if prior is None else np.asarray(prior, dtype=np.float64) - logsumexp(prior)
        anywhere = float(logsumexp(alt + we * pf.place_likelihood(row)))
        if anywhere - mine > ch.spawn_nats:
            st.rival = pf.spawn(ch.n_particles)
            st.rival.update(row, 1.0, prior, kidnap=1.0, headings=hd, points=q, scan_map=sm)
            st.factor, st.age = anywhere - mine, 0
            st.trace.append((t, "spawn", st.factor))
        return out

    def _observe_augmented(
        self, t: int, row: FArray, w: float, hw: float | None, prior: Any, hd: FArray | None, q: FArray | None,
        sm: ScanMap | None,
    ) -> FArray:  # fmt: skip
        """The update with Augmented MCL's share (:class:`Augmented`)."""
        aug = self.strategy
        assert isinstance(aug, Augmented)
        pf = self.pose_filter
        if self._lost:
            self._w_slow = self._w_fast = math.nan
            return self._reinitialise(row, prior, hd, q, sm)
        level = math.exp(pf.log_evidence(row, 1.0))
        if aug.relative:
            alt = np.full(pf.n_places, -math.log(pf.n_places)) if prior is None else np.asarray(prior, dtype=np.float64)
            level /= float(np.exp(logsumexp(alt - logsumexp(alt) + pf.place_likelihood(row))))
        if math.isnan(self._w_slow):
            self._w_slow = self._w_fast = level
        else:
            self._w_slow += aug.slow * w * (level - self._w_slow)
            self._w_fast += aug.fast * w * (level - self._w_fast)
        adaptive = self._w_slow > 0 and aug.adaptive
        share = max(aug.floor, 1.0 - self._w_fast / self._w_slow / aug.threshold) if adaptive else aug.floor
        share = min(aug.cap, share)
        eps = -math.expm1(w * math.log1p(-pf.kidnap))
        if share > eps:
            self.shares_.append((t, share))
        share = max(share, eps)
        extra: dict[str, Any] = {"headings": hd, "heading_weight": hw, "points": q, "scan_map": sm}
        if aug.reserve:
            return _update_with_reserve(pf, row, w, prior, share, aug.reserve, extra)
        if share > eps:
            return pf.update(row, w, prior, kidnap=share, **extra)
        return pf.update(row, w, prior, **extra)


def _update_with_reserve(
    pose_filter: PoseFilter, row: Any, weight: float, prior: Any, share: float, m: int, extra: dict[str, Any]
) -> FArray:
    """The update with kidnapping probability ``share``, its component kept as ``m`` particles of weight ``share / m``.

    The tracked particles are weighed and resampled to ``N`` (no kidnapping
    term), then ``m`` particles drawn from the sensor's posterior (``prior``
    times the observation's robust likelihood) are appended with total weight
    ``share``; the tracked ones keep ``1 - share``. The next update weighs
    all ``N + m`` and resamples to ``N``. Returns the place log-posterior, the exact mixture.
    """
    P = pose_filter.n_places
    lp = weight * pose_filter.place_likelihood(row)
    alt = np.full(P, -math.log(P)) if prior is None else np.asarray(prior, dtype=np.float64).reshape(-1)
    kid = alt - logsumexp(alt) + lp
    lse = float(logsumexp(kid))
    tracked = pose_filter.update(row, weight, prior, kidnap=0.0, **extra)
    if share <= 0 or not math.isfinite(lse):
        return tracked
    fresh = pose_filter._sample_at_places(kid, m, lse)
    pose_filter.particles_ = np.vstack([pose_filter.particles_, fresh])
    pose_filter.log_weights_ = np.concatenate(
        [pose_filter.log_weights_ + math.log1p(-share), np.full(m, math.log(share) - math.log(m))]
    )
    post = np.logaddexp(math.log1p(-share) + tracked, math.log(share) + (kid - lse))
    post = post - logsumexp(post)
    pose_filter._place_log_posterior = post
    return post.copy()


def run_pose_filter(
    log_likelihood: Any,
    increments: Any,
    tracking: PoseTracking | PoseFilter,
    *,
    weights: Any = None,
    heading_weights: Any = None,
    headings: Any = None,
    points: Sequence[Any] | None = None,
    scan_maps: Sequence[ScanMap | None] | None = None,
    **options: Any,
) -> FilterResult:
    """Run :class:`PoseTracking` (reset first) along whole arrays of steps.

    Parameters
    ----------
    log_likelihood : array_like, shape (n_steps, P)
        Row ``t``: the single-shot log-likelihood of each place at step ``t``;
        a row of NaN = no observation (prediction only).
    increments : array_like, shape (n_steps - 1, 3) or (n_steps, 3)
        Odometry from step ``t - 1`` to step ``t`` (robot frame); with
        ``n_steps`` rows, row 0 is ignored.
    tracking : PoseTracking or PoseFilter
        A bare :class:`~fingerloc.map.pose_filter.PoseFilter` is driven by
        ``PoseTracking(tracking, **options)``.
    weights : array_like, shape (n_steps,), optional
        Each observation's weight (default: the tempering's, else 1).
    heading_weights : array_like, shape (n_steps,), optional
        The heading evidence's own weight per step.
    headings : array_like, shape (n_steps, P), optional
        Row ``t``: the heading (radians) observation ``t`` implies at each place.
    points : sequence of (m, 2) arrays or None, length n_steps, optional
        Each step's laser end points (robot frame).
    scan_maps : sequence of ScanMap or None, length n_steps, optional
        The map each step's ``points`` are scored against instead of the filter's.
    **options
        :class:`PoseTracking`'s, with a bare pose filter.

    Returns
    -------
    FilterResult
    """
    drv = tracking if isinstance(tracking, PoseTracking) else PoseTracking(tracking, **options)
    if options and isinstance(tracking, PoseTracking):
        raise InvalidParameterError(f"options {sorted(options)} go with a bare PoseFilter, not a PoseTracking")
    ll = np.asarray(log_likelihood, dtype=np.float64)
    P = drv.n_places
    if ll.ndim != 2 or ll.shape[1] != P:
        raise InvalidParameterError(f"log_likelihood must have shape (n_steps, {P}), got {ll.shape}")
    n = ll.shape[0]
    inc = np.asarray(increments, dtype=np.float64).reshape(-1, 3) if n else np.zeros((0, 3))
    if inc.shape[0] == n and n:
        inc = inc[1:]
    if n and inc.shape[0] != n - 1:
        raise InvalidParameterError(f"increments must have n_steps - 1 ({n - 1}) or n_steps rows, got {inc.shape[0]}")
    per_step = {"weights": weights, "heading_weights": heading_weights}
    arrays: dict[str, FArray | None] = {}
    for name, v in per_step.items():
        arrays[name] = None if v is None else np.asarray(v, dtype=np.float64).reshape(-1)
        if arrays[name] is not None and arrays[name].size != n:  # type: ignore[union-attr]
            raise InvalidParameterError(f"{name} must have one entry per step ({n}), got {arrays[name].size}")  # type: ignore[union-attr]
    hds = None
    if headings is not None:
        hds = np.asarray(headings, dtype=np.float64)
        if hds.shape != ll.shape:
            raise InvalidParameterError(f"headings must have the log-likelihood's shape {ll.shape}, got {hds.shape}")
    for name, seq in (("points", points), ("scan_maps", scan_maps)):
        if seq is not None and len(seq) != n:
            raise InvalidParameterError(f"{name} must have one entry per step ({n}), got {len(seq)}")
    drv.reset()
    out = np.empty_like(ll)
    best = np.zeros(n, dtype=np.int64)
    prob = np.zeros(n)
    wts, hws = arrays["weights"], arrays["heading_weights"]
    for t in range(n):
        s = drv.step(
            ll[t],
            inc[t - 1] if t > 0 else None,
            weight=None if wts is None else float(wts[t]),
            heading_weight=None if hws is None else float(hws[t]),
            headings=None if hds is None else hds[t],
            points=None if points is None else points[t],
            scan_map=None if scan_maps is None else scan_maps[t],
        )
        out[t], best[t], prob[t] = s.log_posterior, s.best, s.probability
    return FilterResult(out, best, prob, entropy_bits(out) if n else np.zeros(0))
