"""Speed section ``align`` of ``fingerloc bench speed``.

One run on the same random fingerprints (letters drawn uniformly from the
paper's 21 letters with a fixed seed; 20 queries and 10,000 references of 40 letters;
``--quick``: 5 queries, 1,000 references):

(a) unit-cost plain alignment, ms per query, and its ratio to
    ``rapidfuzz.process.cdist`` with all workers (target <= 2);
(b) weighted plain alignment (``CostModel.feature_aware()``) in DP cells per
    second (target >= 1e9 on 2 cores);
(c) exact cyclic alignment (unit costs), ms per query against all references
    (target <= 10 ms), and its ratio to the brute force that runs the plain
    compiled DP for every rotation (timed on the first 1,000 references and
    scaled, as it is slow), after checking that both agree exactly.

(d) exact cyclic alignment with ``CostModel.feature_aware()`` (the laser
    configuration), ms per query against all references, and its ratio to
    (c) (target <= 2); beside it the float64 kernel it replaced (on the
    first 1,000 references, scaled).

Also timed: the minimum-energy matcher (on the first 1,000 references,
scaled to 10,000). Every figure comes as wall
time and as process CPU time (``*_cpu_*``, summed over threads), which a
shared, loaded machine disturbs much less; the 1-minute load average at the
end of the run is reported too.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable
from typing import Any

import numba
import numpy as np
from rapidfuzz import process as rf_process
from rapidfuzz.distance import Levenshtein

from .._numba_guard import parallel_region
from ..align import CostModel, alignment_costs, minimum_energy_costs
from ..align._cyclic import cyclic_batch_brute
from ..align._encode import encode_many
from ..align._kernels import nw_batch_cyclic, pack_lanes
from ..fingerprint import PAPER_ALPHABET
from .speed import section

__all__ = ["align_figures", "random_fingerprints", "speed_align"]


def random_fingerprints(n: int, length: int, rng: np.random.Generator) -> list[str]:
    """``n`` strings of ``length`` letters drawn uniformly from the paper's 21 letters."""
    letters = np.array(list(PAPER_ALPHABET))
    return ["".join(row) for row in letters[rng.integers(0, len(PAPER_ALPHABET), size=(n, length))]]


def _wall_cpu(fn: Callable[[], object], repeat: int) -> tuple[float, float]:
    """Best wall time and best process CPU time (all threads) of ``fn``, in seconds.

    CPU time counts only the time this process ran, so it is far less
    disturbed by other processes on a shared machine than wall time.
    """
    best_w = best_c = math.inf
    for _ in range(repeat):
        w0, c0 = time.perf_counter(), time.process_time()
        fn()
        best_w = min(best_w, time.perf_counter() - w0)
        best_c = min(best_c, time.process_time() - c0)
    return best_w, best_c


@section("align")
def speed_align(quick: bool) -> dict[str, Any]:
    """Time the alignment kernels; return JSON-ready figures."""
    if quick:
        return align_figures(n_queries=5, n_references=1_000, repeat=2)
    return align_figures(repeat=5)


def align_figures(
    *,
    n_queries: int = 20,
    n_references: int = 10_000,
    length: int = 40,
    n_baseline: int = 1_000,
    repeat: int = 3,
    seed: int = 20040426,
) -> dict[str, Any]:
    """The figures of the ``align`` section for the given sizes (see the module docstring).

    ``n_baseline`` references (at most ``n_references``) time the slow
    baselines, whose figures are scaled to ``n_references``.
    """
    rng = np.random.default_rng(seed)
    n_q, n_r = n_queries, n_references
    n_sub = min(n_r, n_baseline)
    queries = random_fingerprints(n_q, length, rng)
    refs = random_fingerprints(n_r, length, rng)
    feature = CostModel.feature_aware()
    out: dict[str, Any] = {
        "queries": n_q,
        "references": n_r,
        "length": length,
        "threads": int(numba.get_num_threads()),
        "cpus": os.cpu_count() or 1,
    }

    # (a) unit costs, plain
    alignment_costs(queries[:1], refs[:8])
    t_ours, c_ours = _wall_cpu(lambda: alignment_costs(queries, refs), repeat)
    t_rf, c_rf = _wall_cpu(
        lambda: rf_process.cdist(queries, refs, scorer=Levenshtein.distance, workers=-1, dtype=np.int32), repeat
    )
    out["unit_plain_ms_per_query"] = 1e3 * t_ours / n_q
    out["rapidfuzz_cdist_ms_per_query"] = 1e3 * t_rf / n_q
    out["unit_plain_ratio_to_rapidfuzz"] = t_ours / t_rf
    out["unit_plain_cpu_ratio_to_rapidfuzz"] = c_ours / c_rf

    # (b) weighted costs, plain
    alignment_costs(queries[:1], refs[:8], costs=feature)
    t_w, c_w = _wall_cpu(lambda: alignment_costs(queries, refs, costs=feature), repeat)
    cells = n_q * n_r * length * length
    out["weighted_plain_ms_per_query"] = 1e3 * t_w / n_q
    out["weighted_plain_cells_per_s"] = cells / t_w
    out["weighted_plain_cells_per_cpu_s"] = cells / c_w

    # (c) exact cyclic, unit costs, against the brute force over rotations
    alignment_costs(queries[:1], refs[:8], cyclic=True)
    t_c, c_c = _wall_cpu(lambda: alignment_costs(queries, refs, cyclic=True), repeat)
    qc, qo = encode_many(queries)
    rc, ro = encode_many(refs[:n_sub])
    unit = CostModel()
    with parallel_region(int(numba.get_num_threads())):  # the one lock around numba parallel kernels
        cyclic_batch_brute(qc[:length], qo[:2], rc[:length], ro[:2], unit.substitution, unit.indel)  # compile
        t_b, c_b = _wall_cpu(lambda: cyclic_batch_brute(qc, qo, rc, ro, unit.substitution, unit.indel), 1)
        brute = cyclic_batch_brute(qc, qo, rc, ro, unit.substitution, unit.indel)
    fast = alignment_costs(queries, refs[:n_sub], cyclic=True)
    scale = n_r / n_sub
    out["cyclic_unit_ms_per_query"] = 1e3 * t_c / n_q
    out["cyclic_unit_cpu_ms_per_query"] = 1e3 * c_c / n_q
    out["cyclic_brute_ms_per_query"] = 1e3 * t_b / n_q * scale
    out["cyclic_brute_cpu_ms_per_query"] = 1e3 * c_b / n_q * scale
    out["cyclic_speedup_over_brute"] = t_b * scale / t_c
    out["cyclic_cpu_speedup_over_brute"] = c_b * scale / c_c
    out["cyclic_equals_brute"] = bool(np.array_equal(fast, brute))

    # (d) exact cyclic, feature-aware costs (the laser configuration), on every reference: target <= 2x (c);
    # and the float64 kernel it replaced (every rotation of the references), on n_sub references, scaled
    sub_refs = refs[:n_sub]
    alignment_costs(queries[:1], refs[:8], cyclic=True, costs=feature)
    t_wc, c_wc = _wall_cpu(lambda: alignment_costs(queries, refs, cyclic=True, costs=feature), repeat)
    out["cyclic_weighted_ms_per_query"] = 1e3 * t_wc / n_q
    out["cyclic_weighted_cpu_ms_per_query"] = 1e3 * c_wc / n_q
    out["cyclic_weighted_over_unit"] = t_wc / t_c
    out["cyclic_weighted_cpu_over_unit"] = c_wc / c_c
    rc_sub, ro_sub = encode_many(sub_refs)
    blocks, blens, block_len, _ = pack_lanes(rc_sub, ro_sub)
    with parallel_region(int(numba.get_num_threads())):
        nw_batch_cyclic(qc[:length], qo[:2], blocks[:1], blens[:1], block_len[:1], feature.substitution, feature.indel)
        t_f64, c_f64 = _wall_cpu(
            lambda: nw_batch_cyclic(qc, qo, blocks, blens, block_len, feature.substitution, feature.indel), 1
        )
    out["cyclic_weighted_float64_ms_per_query"] = 1e3 * t_f64 / n_q * scale
    out["cyclic_weighted_float64_cpu_ms_per_query"] = 1e3 * c_f64 / n_q * scale
    out["cyclic_weighted_speedup_over_float64"] = t_f64 * scale / t_wc
    minimum_energy_costs(queries[:1], refs[:8])
    t_me, c_me = _wall_cpu(lambda: minimum_energy_costs(queries, sub_refs), 1)
    out["minimum_energy_ms_per_query"] = 1e3 * t_me / n_q * scale
    out["minimum_energy_cpu_ms_per_query"] = 1e3 * c_me / n_q * scale
    out["load_average_1min"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    return out
