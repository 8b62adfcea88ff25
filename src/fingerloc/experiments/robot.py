"""The paper's robot experiment (Tables II-IV) in simulation (docs/METHOD.md §5).

Protocol (Tapus et al. 2004, section V-B, as restated in docs/METHOD.md §5), with the
robot replaced by :mod:`fingerloc.sim`:

* ten offices alike (:func:`fingerloc.sim.make_offices`), each with a
  measurement point (the office's ``anchor``). The default world, ``"paper"``,
  is calibrated so that the extractors find about as many features per
  measurement as the paper's Table II (see :data:`WORLD_PROFILES`: office
  chairs, fewer posters, more beacons, a softer camera image, an edge extractor
  that keeps only long edges, offices of one corridor at similarity 0.8), and
  its test measurements are taken at a later visit of the offices
  (:func:`fingerloc.sim.make_office_sessions`: chairs moved, doors closed,
  people in the room, other daylight); ``"paper-static"`` is the same world
  with nothing changed between the visits; ``"alike"`` is the original
  generator, far richer in edges;
* per office, eight **training** measurements on a circle around that point,
  radius drawn in ``train_radius_m`` (40-70 cm), at eight evenly spaced angles
  (the whole ring turned by a random angle), and two **test** measurements
  inside the circle (radius below ``test_radius_m``, 40 cm);
* the same heading throughout (the world's x axis), up to a small Gaussian
  error ``heading_jitter_deg`` as a real robot would have; a pose closer than
  ``min_clearance_m`` to an obstacle is redrawn;
* at every pose the simulator produces the **raw** sensor data: a 360 deg scan
  of two 180 deg heads (ranges, intensities) and the donut image of the
  omnidirectional camera (equiangular mirror, lighting changes, sun patches,
  pixel noise, JPEG). The feature extractors of :mod:`fingerloc.features` run
  on these alone: laser corners ``c``, extremities ``Ex`` and beacons ``B``;
  the donut is unwarped with :func:`~fingerloc.features.vision.unwarp_omni`
  from its mirror geometry, then vertical edges ``VE`` and colour patches
  ``CP``. The simulator's ground truth is never used.

What is measured, per trial (new offices, poses and noise each trial):

* **Table II**: mean number of features of each type per measurement.
* **Table III**: string matching alone. Each test fingerprint is compared
  with the 80 training fingerprints; a place scores the least cost over its
  eight; the place of least cost wins. Minimum energy
  (:func:`~fingerloc.align.minimum_energy_costs`, Lamon et al. 2001) against
  global alignment (:func:`~fingerloc.align.alignment_costs`).
* **Table IV**: the Bayesian program (:class:`~fingerloc.model.PlaceModel`,
  ``fp_likelihood="paper"``) with the terms VE, Ex, VE & Ex and VE & Ex & Fp,
  for k = 3, 4, 5 mixture components. One model with every term is fit per
  k; a term set's posterior is the sum of its terms' log-likelihoods (each
  term's mixtures do not depend on the other terms, so this equals fitting
  one model per term set).
* **Random heading** (beyond the paper, docs/METHOD.md §6): the two test
  measurements of each office are taken again at the same positions with a
  uniformly random heading. String matching uses the cyclic alignment (every
  rotation); the full program first estimates, for each place, the heading
  from the best cyclic alignment against that place's training fingerprints
  (:meth:`~fingerloc.model.PlaceModel.headings`), turns the observation back
  by it, then scores the mixture terms; ``Fp`` is the cyclic cost.

Right classification is the share of test measurements whose true place
ranks first; the rank of the true place counts ties against (two places tied
for first both get rank 2). Each figure is the mean over trials; the spread is
the standard deviation over trials, and every cell has a 95 % confidence
interval: Student t over the trials' figures with two trials or more, or, for
one trial (the demo), a Wilson interval of the share over its test queries and
a Student t interval of the mean rank over them.
"""

from __future__ import annotations

import multiprocessing as mp
import os
from collections.abc import Callable, Iterator
from concurrent.futures import Executor, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from typing import Any

from ..errors import InvalidParameterError
from ..metrics import true_place_ranks as rank_of_truth
from .robot_eval import CI_LEVEL, TrialEvaluation, evaluate_trial, t_interval, wilson_interval
from .robot_result import RobotResult
from .robot_sim import (
    PAPER_K,
    PAPER_TABLE2,
    PAPER_TABLE3,
    PAPER_TABLE4,
    TABLE2_TYPES,
    TABLE4_EXP,
    TABLE4_FITTED,
    TABLE4_NAMES,
    TABLE4_TERMS,
    WORLD_PROFILES,
    Measurement,
    RobotProtocol,
    TrialData,
    measurement_poses,
    simulate_office,
    simulate_trial,
)

__all__ = [
    "CI_LEVEL",
    "PAPER_K",
    "PAPER_TABLE2",
    "PAPER_TABLE3",
    "PAPER_TABLE4",
    "TABLE2_TYPES",
    "TABLE4_EXP",
    "TABLE4_FITTED",
    "TABLE4_NAMES",
    "TABLE4_TERMS",
    "WORLD_PROFILES",
    "Measurement",
    "RobotProtocol",
    "RobotResult",
    "TrialData",
    "TrialEvaluation",
    "default_workers",
    "evaluate_trial",
    "measurement_poses",
    "rank_of_truth",
    "run_robot",
    "simulate_office",
    "simulate_trial",
    "simulation_pool",
    "small_protocol",
    "t_interval",
    "wilson_interval",
]


# ---------------------------------------------------------------------------- many trials


@contextmanager
def simulation_pool(workers: int) -> Iterator[Executor | None]:
    """A process pool of ``workers`` processes for :func:`simulate_trial` (None for one: run in place)."""
    if workers <= 1:
        yield None
        return
    with ProcessPoolExecutor(max_workers=workers, mp_context=mp.get_context("spawn")) as ex:
        yield ex


def default_workers() -> int:
    """Processes used to simulate: the usable cores, at most 4."""
    try:
        n = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not on Linux
        n = os.cpu_count() or 1
    return max(1, min(n, 4))


def run_robot(
    *,
    trials: int = 10,
    seed: int = 0,
    protocol: RobotProtocol | None = None,
    workers: int | None = None,
    on_trial: Callable[[int], None] | None = None,
    scheduler: str | None = None,
) -> RobotResult:
    """Run the simulated robot experiment ``trials`` times (new offices each) and collect the figures.

    Parameters
    ----------
    trials : int, default 10
    seed : int, default 0
        Trial ``t`` uses the seed sequence ``(seed, t)``: results do not depend on ``workers``.
    protocol : RobotProtocol, optional
    workers : int, optional
        Processes. Default (None): a local process pool of :func:`default_workers`
        processes, each running whole trials. Given (two or more, with two or more
        trials): a Dask ``LocalCluster`` of that many processes, one task per trial
        (:func:`fingerloc.parallel.run_tasks`). With one trial the offices are
        simulated in parallel on a process pool. 1: in this process. The figures do
        not depend on it.
    on_trial : callable(done), optional
        Called after each trial.
    scheduler : str, optional
        Address of an existing Dask cluster (``tcp://host:8786``): one task per
        trial on it (not with ``workers``). The figures are those of the serial run.
    """
    if isinstance(trials, bool) or not isinstance(trials, int) or trials < 1:
        raise InvalidParameterError(f"trials must be a positive integer, got {trials!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InvalidParameterError(f"seed must be an integer >= 0, got {seed!r}")
    p = protocol if protocol is not None else RobotProtocol()
    if scheduler is not None or (workers is not None and workers >= 2 and trials >= 2):
        from ..parallel import run_tasks

        # one Dask task per trial; each trial carries its seed sequence (seed, t)
        done = None if on_trial is None else on_trial
        results = run_tasks(_trial_job, [(p, seed, t) for t in range(trials)], workers=workers,
                            scheduler=scheduler, on_done=done)  # fmt: skip
        return RobotResult(protocol=p, seed=seed, trials=results)
    n_workers = default_workers() if workers is None else int(workers)
    results = []
    if n_workers >= 2 and trials >= 2:
        # Whole trials in parallel (simulate and evaluate in one process each): no process waits
        # for another, and each trial's figures are the same as when run alone.
        with simulation_pool(min(n_workers, trials)) as ex:
            assert ex is not None
            jobs = [(p, seed, t) for t in range(trials)]
            for t, ev in enumerate(ex.map(_trial_job, jobs)):
                results.append(ev)
                if on_trial is not None:
                    on_trial(t + 1)
        return RobotResult(protocol=p, seed=seed, trials=results)
    with simulation_pool(n_workers) as ex:
        for t in range(trials):
            results.append(_trial_job((p, seed, t), executor=ex))
            if on_trial is not None:
                on_trial(t + 1)
    return RobotResult(protocol=p, seed=seed, trials=results)


def _trial_job(args: tuple[RobotProtocol, int, int], executor: Executor | None = None) -> TrialEvaluation:
    """Simulate and evaluate trial ``t`` (seed sequence ``(seed, t)``); the model is dropped to keep results small."""
    p, seed, t = args
    data = simulate_trial(p, (seed, t), executor=executor)
    ev = evaluate_trial(data, p, random_state=seed * 1000 + t)
    ev.model = None
    ev.models = {}
    return ev


def small_protocol(**changes: Any) -> RobotProtocol:
    """A fast protocol for tests and smoke runs: fewer offices, small images."""
    base = RobotProtocol(n_offices=4, n_train=4, n_test=2, omni_size=(320, 240), panorama_width=360, ks=(3,))
    return replace(base, **changes)
