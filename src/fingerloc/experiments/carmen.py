"""The real-log benchmark: place recognition on CARMEN logs (``fingerloc bench carmen``).

Protocol (other tools compare against its counts, so it is fixed):

1. The front-laser scans of a log, in file order (timestamps in these logs are
   unreliable). Scans ``0 .. n//2 - 1`` are the *mapping pass*, the rest the
   *query pass*.
2. Places: walk the mapping pass in order; a scan whose position is strictly
   farther than ``D = 2.0 m`` from every existing place centre creates a place
   centred at its position. Then every mapping scan within ``R = 1.0 m``
   (inclusive) of some centre is a training scan of the nearest centre.
3. Queries: every query-pass scan within ``R`` of some centre; its true place
   is the nearest centre. (Ties in distance go to the lower place index.)
4. Every method learns from the training scans of a log and scores every query
   against every place of that log; the true place's rank counts ties against
   the method (``rank = #{places scoring >= the true one}``). Per log and pooled
   over the logs' queries: top-1 (rank 1), mean rank, recall@5, milliseconds
   per query (scoring, including descriptor / feature extraction), seconds to
   learn.

A *method* (:class:`Method`) is anything with ``name``, ``fit(scans, labels)``
and ``score(scans) -> (n_queries, n_places)`` (higher = better; column ``j``
is place ``j``). Methods are created by name from :data:`METHODS`; register a
new one with :func:`register_method`. Names starting with ``fingerprint`` are
the Bayesian program, ``baseline-`` the scan-descriptor baselines.

Positions are the robot's (corrected) pose ``(x, y)`` in each ``FLASER`` line.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from .._types import FArray, IArray
from ..errors import EmptyInputError, InvalidParameterError
from ..metrics import max_per_place
from ..pipeline.presets import model_options
from ..sensors import Scan
from .protocol import (
    DEFAULT_METHODS,
    METHODS,
    PLACE_RADIUS_M,
    PLACE_SPACING_M,
    Method,
    Split,
    load_log_scans,
    load_methods,
    log_name,
    make_method,
    make_split,
    rank_metrics,
    register_method,
    true_place_ranks,
)
from .shared import shared_method, shared_results

__all__ = [
    "DEFAULT_METHODS",
    "METHODS",
    "PLACE_RADIUS_M",
    "PLACE_SPACING_M",
    "BenchmarkRun",
    "Hardening",
    "HistogramBaseline",
    "LogRun",
    "Method",
    "MethodRun",
    "ScanContextBaseline",
    "Split",
    "harden_scans",
    "load_log_scans",
    "load_methods",
    "log_name",
    "make_method",
    "make_split",
    "plot_benchmark",
    "rank_metrics",
    "register_method",
    "run_benchmark",
    "run_log",
    "true_place_ranks",
]



def _check_fit_input(scans: Sequence[Scan], labels: Any) -> IArray:
    y = np.asarray(labels, dtype=np.int64).reshape(-1)
    if len(scans) != y.size:
        raise InvalidParameterError(f"one label per scan is needed, got {y.size} for {len(scans)} scans")
    if y.size == 0:
        raise EmptyInputError("no training scans")
    if y.min() < 0 or set(np.unique(y).tolist()) != set(range(int(y.max()) + 1)):
        raise InvalidParameterError("labels must be place indices 0 .. n_places - 1, each used at least once")
    return y


class ScanContextBaseline:
    """A Scan-Context-like polar grid for 2D scans, with a union-normalised score.

    After Kim and Kim, "Scan Context" (IROS 2018), adapted to a planar laser
    that sees only part of the circle: the robot-frame plane around the
    sensor is cut into ``n_rings`` rings (``max_radius`` metres) by
    ``n_sectors`` sectors covering 360 deg; a cell holds the fraction of the
    scan's end points that fall in it (square-rooted, so near walls do not
    swamp far ones). Two grids are compared column by column (one column = one
    sector) with the cosine similarity, at every sector shift (unknown
    heading). The original score averages over all ``n_sectors`` columns; a
    180 deg scan leaves half of them empty, so that average is dominated by
    columns neither scan could fill; the original code instead divides by the
    columns non-empty in *both*, so two scans that overlap in one column can
    score 1. Here (``normalise="union"``) the sum of cosines is divided by the
    number of columns non-empty in *either* grid: columns seen by one scan but
    not the other count as mismatches; columns seen by neither do not count.
    A place scores its best training scan.

    Parameters
    ----------
    n_rings : int, default 20
    n_sectors : int, default 60
    max_radius : float, default 12.0
        Metres; end points beyond are ignored.
    normalise : {"union", "intersection"}, default "union"
        Columns the sum of cosines is divided by; ``"intersection"`` is the
        original Scan Context score.
    """

    name = "baseline-scancontext"

    def __init__(
        self, n_rings: int = 20, n_sectors: int = 60, max_radius: float = 12.0, normalise: str = "union"
    ) -> None:
        self.n_rings = n_rings
        self.n_sectors = n_sectors
        self.max_radius = max_radius
        self.normalise = normalise

    def descriptor(self, scan: Scan) -> FArray:
        """The polar grid of one scan, shape (n_sectors, n_rings), columns L2-normalised (zero when empty)."""
        pts = scan.points()
        r = np.hypot(pts[:, 0], pts[:, 1])
        a = np.mod(np.arctan2(pts[:, 1], pts[:, 0]), 2 * math.pi)
        ok = r < self.max_radius
        ring = np.minimum((r[ok] / self.max_radius * self.n_rings).astype(np.int64), self.n_rings - 1)
        sec = np.minimum((a[ok] / (2 * math.pi) * self.n_sectors).astype(np.int64), self.n_sectors - 1)
        g = np.zeros((self.n_sectors, self.n_rings))
        np.add.at(g, (sec, ring), 1.0)
        g = np.sqrt(g / max(1, pts.shape[0]))
        norm = np.linalg.norm(g, axis=1, keepdims=True)
        return np.divide(g, norm, out=np.zeros_like(g), where=norm > 0)

    def fit(self, scans: Sequence[Scan], labels: Any) -> ScanContextBaseline:
        """Store the training grids."""
        if self.n_rings < 1 or self.n_sectors < 2 or not (self.max_radius > 0):
            raise InvalidParameterError(
                f"scan context needs n_rings >= 1, n_sectors >= 2, max_radius > 0, got "
                f"{self.n_rings}, {self.n_sectors}, {self.max_radius!r}"
            )
        if self.normalise not in ("union", "intersection"):
            raise InvalidParameterError(f"normalise must be 'union' or 'intersection', got {self.normalise!r}")
        y = _check_fit_input(scans, labels)
        grids = np.stack([self.descriptor(s) for s in scans])  # (T, S, R)
        self.grids_ = grids.reshape(len(scans), -1)
        self.occupied_ = (np.linalg.norm(grids, axis=2) > 0).astype(np.float64)  # (T, S)
        self.labels_ = y
        self.n_places_ = int(y.max()) + 1
        return self

    def score(self, scans: Sequence[Scan]) -> FArray:
        """Best union-normalised similarity to each place, shape (n_queries, n_places), in [0, 1]."""
        sn = self.n_sectors
        shifts = (np.arange(sn)[:, None] + np.arange(sn)[None, :]) % sn  # row k: grid rolled by -k
        n_occ_c = self.occupied_.sum(axis=1)  # (T,)
        n_t = self.grids_.shape[0]
        sims = np.empty((len(scans), n_t))
        # queries in blocks, one matrix product per block (many small products spin BLAS threads; each
        # entry is the same dot product as with one product per query)
        block = max(1, 2048 // sn)
        for i0 in range(0, len(scans), block):
            q = np.stack([self.descriptor(s) for s in scans[i0 : i0 + block]])  # (B, S, R)
            b = q.shape[0]
            qs = q[:, shifts]  # (B, S_shift, S, R)
            occ = (np.linalg.norm(q, axis=2) > 0).astype(np.float64)[:, shifts]  # (B, S_shift, S)
            num = (qs.reshape(b * sn, -1) @ self.grids_.T).reshape(b, sn, n_t)  # sums of column cosines
            both = (occ.reshape(b * sn, sn) @ self.occupied_.T).reshape(b, sn, n_t)
            if self.normalise == "union":
                den = occ.sum(axis=2)[:, :, None] + n_occ_c[None, None, :] - both
            else:
                den = both
            sim = np.divide(num, den, out=np.zeros_like(num), where=den > 0)
            sims[i0 : i0 + b] = sim.max(axis=1)
        return max_per_place(sims, self.labels_, self.n_places_)


class HistogramBaseline:
    """A range histogram: the distribution of a scan's ranges, heading-free.

    Ranges up to ``max_range`` metres fall into ``n_bins`` equal bins; beams
    with no return or beyond go to one more bin; the histogram is divided by
    the number of beams. Two histograms are compared by the L1 distance of
    their cumulative sums (the 1D earth mover's distance in bins, so a range
    shifted by one bin costs little); a place scores minus its nearest
    training scan's distance.

    Parameters
    ----------
    n_bins : int, default 40
    max_range : float, default 10.0
        Metres.
    """

    name = "baseline-histogram"

    def __init__(self, n_bins: int = 40, max_range: float = 10.0) -> None:
        self.n_bins = n_bins
        self.max_range = max_range

    def descriptor(self, scan: Scan) -> FArray:
        """Cumulative range histogram, shape (n_bins + 1,), last value 1."""
        from ..terms.range import cumulative_range_histogram

        edges = np.linspace(0.0, self.max_range, self.n_bins + 1)[1:]  # np.histogram's uniform edges
        return cumulative_range_histogram(scan.ranges, edges)

    def fit(self, scans: Sequence[Scan], labels: Any) -> HistogramBaseline:
        """Store the training histograms."""
        if self.n_bins < 1 or not (self.max_range > 0):
            raise InvalidParameterError(
                f"histogram needs n_bins >= 1 and max_range > 0, got {self.n_bins}, {self.max_range!r}"
            )
        y = _check_fit_input(scans, labels)
        self.hists_ = np.stack([self.descriptor(s) for s in scans])
        self.labels_ = y
        self.n_places_ = int(y.max()) + 1
        return self

    def score(self, scans: Sequence[Scan]) -> FArray:
        """Minus the least cumulative-histogram L1 distance to each place's scans, shape (n_queries, n_places)."""
        q = np.stack([self.descriptor(s) for s in scans]) if len(scans) else np.zeros((0, self.n_bins + 1))
        d = np.abs(q[:, None, :] - self.hists_[None, :, :]).sum(axis=2)
        return max_per_place(-d, self.labels_, self.n_places_)


class FingerprintMethod:
    """The fingerprint Bayesian program (:class:`fingerloc.model.PlaceModel`) on laser-only observations.

    Each scan becomes an :class:`~fingerloc.observation.Observation` with
    :func:`fingerloc.features.laser.observation_from_scan` (corners,
    extremities, beacons; the scan's own field of view); ``score`` is the
    model's log-posterior over places.

    With ``verify`` (and a pose on every training scan) the answer is
    verified against the mapping run's laser end points
    (:mod:`fingerloc.map.scan_verify`): each query scan is fitted into the
    scan map at every place, and the program's log-posterior and the fits
    are combined with weights fitted on held-out training scans
    (:func:`fingerloc.experiments.verify.fit_verified`). The scan map is made
    of the mapping run of the enclosing
    :func:`~fingerloc.experiments.verify.mapping_context` (the benchmark's
    runner opens one per log: every mapping-pass scan but the training scans
    this fit does not hold), else of the training scans themselves.

    Parameters
    ----------
    feature_params : dict, optional
        Keyword arguments of the laser feature extractor.
    world_frame : bool, default False
        Turn every observation by the robot's heading (``pose[2]``) so that
        bearings are in the map frame: the heading is then *given* to the
        method (the baselines do not get it). False keeps robot-frame
        bearings (heading unknown).
    verify : bool, default False
        Verify the answers against the scan map (above).
    search : VerifySearch, optional
        The verifier's search (:class:`~fingerloc.map.scan_verify.VerifySearch`).
    **model_params
        Arguments of :class:`~fingerloc.model.PlaceModel`.

    Attributes
    ----------
    model_ : PlaceModel
    verification_ : Verification or None
        The fitted weights (``verify``).
    verifier_ : ScanVerifier or None
    """

    name = "fingerprint"

    def __init__(
        self,
        feature_params: dict[str, Any] | None = None,
        *,
        world_frame: bool = False,
        verify: bool = False,
        search: Any = None,
        **model_params: Any,
    ) -> None:
        self.feature_params = dict(feature_params or {})
        self.world_frame = world_frame
        self.verify = verify
        self.search = search
        self.model_params = model_params

    def _observations(self, scans: Sequence[Scan]) -> list[Any]:
        from ..features.laser import observation_from_scan
        from .shared import observations

        params = self.feature_params
        key = "observation_from_scan" + repr(sorted(params.items()))
        obs = observations(scans, key, lambda s: observation_from_scan(s, **params))
        if self.world_frame:
            obs = [o.rotated(s.pose[2]) if s.pose is not None else o for o, s in zip(obs, scans, strict=True)]
        return obs

    def _program(self, scans: Sequence[Scan], y: IArray) -> Any:
        from ..model import PlaceModel
        from ..pipeline.places import place_label

        return PlaceModel(**self.model_params).fit(self._observations(scans), [place_label(v) for v in y.tolist()])

    def fit(self, scans: Sequence[Scan], labels: Any) -> FingerprintMethod:
        """Extract features of the training scans and fit the place model (labels as strings ``"0"``, ``"1"``...);
        with ``verify``, build the scan map and fit the verification's weights."""
        y = _check_fit_input(scans, labels)
        self.n_places_ = int(y.max()) + 1
        self.model_ = self._program(scans, y)
        self.verification_ = None
        self.verifier_ = None
        if self.verify and all(s.pose is not None for s in scans):
            from .verify import fit_verified

            self.verifier_, self.verification_ = fit_verified(self, scans, y, self.search)
        return self

    def program_scores(self, scans: Sequence[Scan]) -> FArray:
        """The program's log-posterior of each place, shape (n_queries, n_places) (before any verification)."""
        from ..pipeline.calibration import posterior_columns

        return posterior_columns(self.model_, self._observations(scans) if scans else [], self.n_places_)

    def score(self, scans: Sequence[Scan]) -> FArray:
        """Log-posterior of each place, shape (n_queries, n_places) (verified with ``verify``)."""
        lp = self.program_scores(scans)
        if self.verifier_ is None or self.verification_ is None or not len(scans):
            return lp
        from ..map.scan_map import end_points
        from ..map.scan_verify import verify_candidates

        return verify_candidates(lp, [end_points(s) for s in scans], self.verifier_, verification=self.verification_)


@register_method("baseline-scancontext")
def _scancontext() -> Method:
    return ScanContextBaseline()


@register_method("baseline-scancontext-original", default=False)
def _scancontext_original() -> Method:
    return ScanContextBaseline(normalise="intersection")


@register_method("baseline-histogram")
def _histogram() -> Method:
    return HistogramBaseline()


def best_fingerprint_params() -> dict[str, Any]:
    """The fingerprint program's configuration for 2D laser logs: the library's ``laser2d`` preset.

    Every :class:`~fingerloc.model.PlaceModel` argument of
    :func:`fingerloc.pipeline.presets.model_options` ``("laser2d")``:

    * ``terms=("Fp", "R")``: the fingerprint string and the range term. The
      mixtures' terms (Ex, and VE/CP/B which a 2D laser without remissions
      does not give) model bearings in the robot frame; with the heading
      unknown between visits they mislead (docs/RESULTS.md).
    * ``laser_letters=True``: extremities and wall segments (length and range
      class) become letters, so a laser-only string says more than its few
      corners.
    * ``costs=CostModel.feature_aware()``: neighbouring wall classes, ``f``
      against ``c``/``v`` and extra ``n`` cost less than other edits.
    * ``cyclic=True``: the heading is unknown.
    * ``fp_likelihood="exp"``: ``exp(-lambda cost)`` with ``lambda`` fit on
      the training scans, so the string and the range term are weighed by how
      well each separates the training places.
    """
    return model_options("laser2d")


@register_method("fingerprint")
def _fingerprint() -> Method:
    # Our best configuration for 2D laser logs (see best_fingerprint_params), verified against the scan map.
    return FingerprintMethod(**best_fingerprint_params(), verify=True)


@register_method("fingerprint-program", default=False)
def _fingerprint_program() -> Method:
    # The program alone (no scan verification): the single shot before the verification.
    return FingerprintMethod(**best_fingerprint_params())


@register_method("fingerprint-weighted", default=False)
def _fingerprint_weighted() -> Method:
    # The best configuration with the terms' weights fit on held-out training scans (weights="fit").
    return FingerprintMethod(**{**best_fingerprint_params(), "weights": "fit"})


@register_method("fingerprint-string")
def _fingerprint_string() -> Method:
    # The same without the range term: what the fingerprint string alone does.
    params = best_fingerprint_params()
    params["terms"] = ("Fp",)
    return FingerprintMethod(**params)


@register_method("fingerprint-paper")
def _fingerprint_paper() -> Method:
    # The paper's program as it stands on a 2D laser: Ex mixtures and the paper's string, unit costs.
    return FingerprintMethod(terms=("Ex", "Fp"))


# ---------------------------------------------------------------------------------------------------
# Runner
# ---------------------------------------------------------------------------------------------------


@dataclass(slots=True)
class MethodRun:
    """One method's results on one log.

    Attributes
    ----------
    ranks : ndarray of int, shape (n_queries,)
        True-place rank of each query (ties against).
    predicted : ndarray of int, shape (n_queries,)
        Best-scoring place of each query (lowest index among ties).
    learn_s, score_s : float
        Wall seconds of ``fit`` and of ``score`` over all queries.
    """

    ranks: IArray
    predicted: IArray
    learn_s: float
    score_s: float

    def figures(self) -> dict[str, float]:
        """``top1``, ``mean_rank``, ``recall5``, ``ms_per_query``, ``learn_s``."""
        n = self.ranks.size
        return {
            **rank_metrics(self.ranks),
            "ms_per_query": 1000.0 * self.score_s / n if n else float("nan"),
            "learn_s": self.learn_s,
        }


@dataclass(slots=True)
class LogRun:
    """One log: its scans, split, and every method's results."""

    name: str
    path: str
    scans: list[Scan]
    split: Split
    skipped: int
    methods: dict[str, MethodRun] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        """``{"places", "train", "queries", "scans", "skipped_lines", "methods": {name: figures}}``."""
        return {
            "places": self.split.n_places,
            "train": self.split.n_train,
            "queries": self.split.n_queries,
            "scans": self.split.n_scans,
            "skipped_lines": self.skipped,
            "methods": {k: v.figures() for k, v in self.methods.items()},
        }


@dataclass(frozen=True, slots=True)
class Hardening:
    """A benchmark run made harder than the fixed protocol (``bench carmen`` options); the defaults are the protocol.

    Attributes
    ----------
    seed : int, default 0
        Seeds every method that draws random numbers (the pose filter's
        particles and simulated odometry: a method's ``seed`` attribute).
    odometry_error : float, default 1.0
        Factor on the simulated odometry errors of every method that
        simulates them (times the method's own factor; 0 = exact odometry).
    mapping_part : float, default 0.5
        Fraction of the scans that maps (``floor(mapping_part * n)``): a
        shorter mapping part gives fewer places, fewer training scans and a
        longer query pass.
    query_start : float, default 0.0
        Fraction of the query pass left out at its start: the robot starts
        somewhere else along its route (global localization from there).
    query_cut : (float, float) or None
        ``(start, length)``, fractions of the query pass: that block is left
        out (a gap in the log; the odometry sees the jump).
    reverse : bool, default False
        The query pass in reverse order: the route driven backwards (the
        scans are the recorded ones, so the robot moves in reverse).
    """

    seed: int = 0
    odometry_error: float = 1.0
    mapping_part: float = 0.5
    query_start: float = 0.0
    query_cut: tuple[float, float] | None = None
    reverse: bool = False

    def __post_init__(self) -> None:
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0:
            raise InvalidParameterError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not (math.isfinite(self.odometry_error) and self.odometry_error >= 0):
            raise InvalidParameterError(f"odometry_error must be a finite factor >= 0, got {self.odometry_error!r}")
        if not (isinstance(self.mapping_part, (int, float)) and 0 < self.mapping_part < 1):
            raise InvalidParameterError(f"mapping_part must be a fraction in (0, 1), got {self.mapping_part!r}")
        if not (isinstance(self.query_start, (int, float)) and 0 <= self.query_start < 1):
            raise InvalidParameterError(f"query_start must be a fraction in [0, 1), got {self.query_start!r}")
        if self.query_cut is not None:
            a, b = (float(v) for v in self.query_cut)
            if not (0 <= a < 1 and 0 < b < 1 and a + b <= 1):
                raise InvalidParameterError(
                    f"query_cut must be (start, length) fractions with start + length <= 1, got {self.query_cut!r}"
                )
            object.__setattr__(self, "query_cut", (a, b))

    def is_protocol(self) -> bool:
        """True when the run is the fixed protocol (every field at its default)."""
        return self == Hardening()

    def apply(self, method: Method) -> Method:
        """``method`` with this run's seed and odometry-error factor, when it has those attributes (the pose filters)."""
        if self.is_protocol():
            return method
        if hasattr(method, "seed"):
            method.seed = int(self.seed)
        if hasattr(method, "odometry_error"):
            method.odometry_error = float(method.odometry_error) * self.odometry_error
        return method

    def to_json(self) -> dict[str, Any]:
        """Every field (``query_cut`` as a list or None)."""
        return {
            "seed": int(self.seed),
            "odometry_error": float(self.odometry_error),
            "mapping_part": float(self.mapping_part),
            "query_start": float(self.query_start),
            "query_cut": None if self.query_cut is None else list(self.query_cut),
            "reverse": bool(self.reverse),
        }


def harden_scans(scans: Sequence[Scan], hardening: Hardening) -> tuple[list[Scan], int]:
    """A log's scans as a hardened run sees them, and the number of mapping scans.

    The mapping pass (the first ``floor(mapping_part * n)`` scans, ``n // 2``
    at the default) is kept as recorded; the query pass loses its first
    ``query_start`` and the ``query_cut`` block (fractions of its scans) and
    is reversed with ``reverse``.
    """
    n = len(scans)
    n_map = n // 2 if hardening.mapping_part == 0.5 else math.floor(hardening.mapping_part * n)
    rest = list(scans[n_map:])
    nq = len(rest)
    keep = np.ones(nq, dtype=bool)
    keep[: math.floor(hardening.query_start * nq)] = False
    if hardening.query_cut is not None:
        a = math.floor(hardening.query_cut[0] * nq)
        keep[a : a + math.floor(hardening.query_cut[1] * nq)] = False
    rest = [s for s, k in zip(rest, keep.tolist(), strict=True) if k]
    if hardening.reverse:
        rest.reverse()
    return list(scans[:n_map]) + rest, n_map


@dataclass(slots=True)
class BenchmarkRun:
    """All logs of one run; :meth:`to_json` gives the benchmark's JSON layout (kept stable: other tools read it)."""

    logs: list[LogRun]
    method_names: list[str]
    hardening: Hardening = field(default_factory=lambda: Hardening())

    def pooled(self) -> dict[str, Any]:
        """Figures over every query of every log (each query weighs the same)."""
        out: dict[str, Any] = {
            "places": sum(lg.split.n_places for lg in self.logs),
            "train": sum(lg.split.n_train for lg in self.logs),
            "queries": sum(lg.split.n_queries for lg in self.logs),
            "methods": {},
        }
        for m in self.method_names:
            runs = [lg.methods[m] for lg in self.logs if m in lg.methods]
            ranks = np.concatenate([r.ranks for r in runs]) if runs else np.zeros(0, np.int64)
            score_s = sum(r.score_s for r in runs)
            out["methods"][m] = {
                **rank_metrics(ranks),
                "ms_per_query": 1000.0 * score_s / ranks.size if ranks.size else float("nan"),
                "learn_s": sum(r.learn_s for r in runs),
            }
        return out

    def to_json(self) -> dict[str, Any]:
        """``{"logs": {name: {...}}, "pooled": {...}, "protocol": {...}}``."""
        return {
            "logs": {lg.name: lg.to_json() for lg in self.logs},
            "pooled": self.pooled(),
            "protocol": {
                "place_spacing_m": PLACE_SPACING_M,
                "radius_m": PLACE_RADIUS_M,
                "mapping": "index < n // 2" if self.hardening.mapping_part == 0.5 else
                           f"index < floor({self.hardening.mapping_part:g} n)",
                "ties": "count against",
                **({} if self.hardening.is_protocol() else {"hardening": self.hardening.to_json()}),
            },
        }


def run_log(
    scans: Sequence[Scan],
    split: Split,
    methods: Sequence[Method],
    *,
    on_method: Callable[[str], None] | None = None,
) -> dict[str, MethodRun]:
    """Fit and score every method on one log's split."""
    from .verify import mapping_context

    train = [scans[i] for i in split.train_idx.tolist()]
    queries = [scans[i] for i in split.query_idx.tolist()]
    out: dict[str, MethodRun] = {}
    with mapping_context(scans, split):
        for m in methods:
            out[m.name] = _run_method(m, scans, split, train, queries, on_method)
    return out


def _run_method(
    m: Method,
    scans: Sequence[Scan],
    split: Split,
    train: list[Scan],
    queries: list[Scan],
    on_method: Callable[[str], None] | None,
) -> MethodRun:
    """One method of :func:`run_log`: fit, score, ranks."""
    if on_method is not None:
        on_method(m.name)
    fit_log = getattr(m, "fit_log", None)
    t0 = time.perf_counter()
    if fit_log is not None:  # methods that need the trajectory (the filters)
        fit_log(scans, split)
    else:
        m.fit(train, split.train_labels.copy())
    t1 = time.perf_counter()
    s = np.asarray(m.score(queries), dtype=np.float64) if queries else np.zeros((0, split.n_places))
    t2 = time.perf_counter()
    if s.shape != (split.n_queries, split.n_places):
        raise RuntimeError(f"method {m.name} returned scores of shape {s.shape}, expected "
                           f"({split.n_queries}, {split.n_places})")  # fmt: skip
    ranks = true_place_ranks(s, split.query_labels)
    pred = np.argmax(np.where(np.isnan(s), -np.inf, s), axis=1) if s.size else np.zeros(0, np.int64)
    return MethodRun(ranks=ranks, predicted=pred.astype(np.int64), learn_s=t1 - t0, score_s=t2 - t1)


def run_benchmark(
    paths: Sequence[str | Path],
    methods: Sequence[str] | None = None,
    *,
    skip_bad: bool = False,
    on_progress: Callable[[str], None] | None = None,
    workers: int | None = None,
    scheduler: str | None = None,
    hardening: Hardening | None = None,
) -> BenchmarkRun:
    """Run the benchmark's protocol on CARMEN logs.

    Parameters
    ----------
    paths : sequence of path
        CARMEN logs (plain or gzip).
    methods : sequence of str, optional
        Registered method names (default: :data:`DEFAULT_METHODS`).
    skip_bad : bool, default False
        Skip malformed log lines (counted per log in ``skipped_lines``).
    on_progress : callable, optional
        Called with a short text before each log and method (serial runs), or
        after each log (on Dask).
    workers, scheduler : optional
        Run one task per log on Dask (:func:`fingerloc.parallel.run_tasks`):
        a local cluster of ``workers`` processes, or an existing cluster at
        ``scheduler``. Every method is seeded by its own parameters, so the
        figures are those of the serial run.
    hardening : Hardening, optional
        A harder run than the protocol (seed, odometry errors, a shorter
        mapping part, the query pass cut, started later or reversed);
        default the protocol itself.

    Returns
    -------
    BenchmarkRun
    """
    if not paths:
        raise InvalidParameterError("at least one log is needed")
    load_methods()  # every module's registrations (the filtered methods of .markov)
    names = list(DEFAULT_METHODS) if not methods else list(dict.fromkeys(methods))
    for n in names:
        if n not in METHODS:
            raise InvalidParameterError(f"unknown method {n!r} (known: {', '.join(METHODS)})")
    hard = Hardening() if hardening is None else hardening
    tasks: list[tuple[str, str, list[str], bool, Hardening]] = []
    seen: dict[str, int] = {}
    for path in paths:
        name = log_name(path)
        seen[name] = seen.get(name, 0) + 1
        tasks.append((str(path), name if seen[name] == 1 else f"{name}#{seen[name]}", names, skip_bad, hard))
    if workers is None and scheduler is None:
        logs = [_bench_log(t, on_progress) for t in tasks]
    else:
        from ..parallel import run_tasks

        done = None if on_progress is None else (lambda k: on_progress(f"{k} of {len(tasks)} logs done"))
        logs = run_tasks(_bench_log, tasks, workers=workers, scheduler=scheduler, on_done=done)
    return BenchmarkRun(logs=logs, method_names=names, hardening=hard)


def _bench_log(
    task: tuple[str, str, list[str], bool, Hardening], on_progress: Callable[[str], None] | None = None
) -> LogRun:
    """One log of :func:`run_benchmark`: ``(path, name, method names, skip_bad, hardening)`` -> its :class:`LogRun`."""
    path, name, names, skip_bad, hard = task
    load_methods()  # in a fresh worker process too
    if on_progress is not None:
        on_progress(f"{name}: reading")
    scans, skipped = load_log_scans(path, skip_bad=skip_bad)
    n_map = None
    if not hard.is_protocol():
        scans, n_map = harden_scans(scans, hard)
    pos = np.array([s.pose[:2] for s in scans if s.pose is not None], dtype=np.float64)
    split = make_split(pos, n_mapping=n_map)
    lg = LogRun(name=name, path=str(path), scans=scans, split=split, skipped=skipped)
    if split.n_queries:
        with shared_results():  # one fit, one scoring, one feature extraction per scan, for every method
            lg.methods = run_log(
                scans,
                split,
                [_shareable(hard.apply(make_method(n))) for n in names],
                on_method=None if on_progress is None else (lambda m: on_progress(f"{name}: {m}")),
            )
    return lg


def _shareable(m: Method) -> Method:
    """``m`` as a :class:`~.shared.SharedMethod` when it is a registered single-shot method (no trajectory)."""
    if getattr(m, "fit_log", None) is not None or m.name not in METHODS:
        return m
    shared: Method = shared_method(m.name)
    return shared


# ---------------------------------------------------------------------------------------------------
# Plot
# ---------------------------------------------------------------------------------------------------


def plot_benchmark(run: BenchmarkRun, path: str | Path, *, method: str | None = None, max_points: int = 60000) -> None:
    """Draw each log's map with place centres and queries coloured right / wrong; write a PNG.

    Parameters
    ----------
    run : BenchmarkRun
    path : path
        Output image (``.png``).
    method : str, optional
        Whose answers colour the queries (default: the run's first method).
    max_points : int, default 60000
        Scan end points drawn per log at most (evenly thinned).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    meth = method if method is not None else (run.method_names[0] if run.method_names else None)
    from ..reporting import scan_end_points

    if meth is not None and meth not in run.method_names:
        raise InvalidParameterError(f"method {meth!r} was not run (ran: {', '.join(run.method_names)})")
    n = len(run.logs)
    cols = min(n, 2)
    rows = math.ceil(n / cols)
    fig, axes = plt.subplots(rows, cols, figsize=(7.5 * cols, 7.0 * rows), squeeze=False)
    for ax in axes.flat[n:]:
        ax.set_visible(False)
    for ax, lg in zip(axes.flat, run.logs, strict=False):
        pts = scan_end_points(lg.scans, max_points=max_points)
        ax.scatter(pts[:, 0], pts[:, 1], s=0.2, c="0.65", linewidths=0, rasterized=True, label="scan points")
        traj = np.array([s.pose[:2] for s in lg.scans if s.pose is not None])
        ax.plot(traj[:, 0], traj[:, 1], lw=0.4, c="0.4", alpha=0.6)
        sp = lg.split
        if meth is not None and meth in lg.methods and sp.n_queries:
            right = lg.methods[meth].ranks == 1
            qpos = traj[sp.query_idx]
            ax.scatter(*qpos[right].T, s=10, c="tab:green", label=f"query right ({int(right.sum())})", zorder=3)
            ax.scatter(*qpos[~right].T, s=10, c="tab:red", label=f"query wrong ({int((~right).sum())})", zorder=3)
            top1 = float(np.mean(right))
            title = f"{lg.name}: {meth} top-1 {top1:.2f}"
        else:
            title = lg.name
        ax.scatter(sp.centres[:, 0], sp.centres[:, 1], s=28, marker="+", c="k", label=f"places ({sp.n_places})",
                   zorder=4)  # fmt: skip
        ax.set_title(title + f" ({sp.n_places} places, {sp.n_queries} queries)")
        ax.set_aspect("equal")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.legend(loc="best", fontsize=7, markerscale=1.5)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


# ---------------------------------------------------------------------------------------------------
# Speed section (``fingerloc bench speed --only carmen``)
# ---------------------------------------------------------------------------------------------------


def _synthetic_scans(n: int, beams: int, rng: np.random.Generator) -> list[Scan]:
    from ..io.carmen import flaser_bearings

    b = flaser_bearings(beams)
    out = []
    for k in range(n):
        w, h = rng.uniform(2.0, 12.0, size=2)
        px, py = rng.uniform(0.3, 0.7) * w, rng.uniform(0.3, 0.7) * h
        a = b + rng.uniform(-math.pi, math.pi)
        c, s = np.cos(a), np.sin(a)
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(c > 1e-12, (w - px) / c, np.where(c < -1e-12, -px / c, np.inf))
            ty = np.where(s > 1e-12, (h - py) / s, np.where(s < -1e-12, -py / s, np.inf))
        out.append(Scan(np.minimum(tx, ty), b, max_range=80.0, pose=(float(k), 0.0, 0.0)))
    return out


def _speed_section(quick: bool) -> dict[str, Any]:
    import gzip
    import tempfile

    from ..io.carmen import iter_scans
    from .speed import best_time

    rng = np.random.default_rng(0)
    n_lines = 300 if quick else 3000
    figs: dict[str, Any] = {}
    with tempfile.TemporaryDirectory() as tmp:
        p = Path(tmp) / "speed.log.gz"
        with gzip.open(p, "wt", encoding="utf-8", compresslevel=1) as fh:
            for k in range(n_lines):
                row = " ".join(f"{v:.2f}" for v in rng.uniform(0.5, 30.0, 361))
                fh.write(f"FLASER 361 {row} {k * 0.01:.2f} 0 0 0 0 0 {k} h {k}\n")
        t = best_time(lambda: sum(1 for _ in iter_scans(p)), repeat=2)
        figs["carmen_read_scans_per_s"] = n_lines / t
        figs["carmen_read_us_per_beam"] = 1e6 * t / (n_lines * 361)
    n_places, per_place, n_q = (10, 2, 10) if quick else (50, 4, 100)
    train = _synthetic_scans(n_places * per_place, 181, rng)
    labels = np.repeat(np.arange(n_places), per_place)
    queries = _synthetic_scans(n_q, 181, rng)
    for m in (ScanContextBaseline(), HistogramBaseline()):
        m.fit(train, labels)
        t = best_time(lambda m=m: m.score(queries), repeat=2)  # type: ignore[misc]
        figs[f"{m.name}_ms_per_query_{n_places * per_place}_train"] = 1000.0 * t / n_q
    return figs


def _register_speed() -> None:
    from .speed import section

    section("carmen")(_speed_section)


_register_speed()
