"""Single-shot answers in chunks: the posterior, ranks and headings of a chunk of observations, as plain data.

A *chunk* is a run of consecutive observations (:data:`LOCALIZE_CHUNK` of
them). :func:`answer_chunk` computes its answers (the terms once, then the
posterior, ranks and headings) and returns plain data: the JSON records of
``fingerloc localize --json`` already encoded as text, the table rows, the
ranks of the true places. :meth:`fingerloc.pipeline.placemap.PlaceMap.localize`,
the command (serially) and its Dask tasks all call it, so their answers are
the same.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["LOCALIZE_CHUNK", "ChunkAnswers", "answer_chunk", "shows_heading"]

#: Observations answered at once: ``localize``'s memory does not grow with the file's length.
LOCALIZE_CHUNK = 256


def shows_heading(model: Any) -> bool:
    """Whether ``localize`` gives a heading: a cyclic model, or one with the column-profile term ``AP`` or the
    keypoint term ``K``."""
    return bool(model.cyclic or "AP" in model.terms_ or "K" in model.terms_)


def _finite(v: float, where: str, nulls: dict[str, str]) -> float | None:
    """``v``, or None (noted in ``nulls`` as a strict JSON encoder notes it) when it is not finite."""
    if math.isfinite(v):
        return v
    nulls[where] = f"not a finite number: {v!r}"
    return None


def _float_map(keys: list[str], values: list[float], finite: bool, where: str, nulls: dict[str, str]) -> dict[str, Any]:
    """``dict(zip(keys, values))`` with non-finite values as None, as a strict JSON encoder writes it; ``finite``: all are."""
    if finite:
        return dict(zip(keys, values, strict=True))
    return {k: _finite(v, f"{where}/{k}", nulls) for k, v in zip(keys, values, strict=True)}


@dataclass(slots=True)
class ChunkAnswers:
    """``localize``'s answers for one chunk, as plain data (what a Dask task returns).

    Attributes
    ----------
    n : int
        Observations answered.
    records : list of str
        Each observation's JSON record, encoded (empty unless asked for).
    nulls : list of dict
        Per record: path inside it -> why a number was written as ``null``.
    rows : list of list of str
        The table's rows (empty unless asked for).
    rank_of_true : list of int
        Rank of the labelled place per observation, 0 when it has none.
    pairs : list of (str, str)
        (true place, best place) of each labelled observation.
    logp, ranks : ndarray or None
        The log posterior and every place's rank, kept only for ``--report``.
    """

    n: int
    records: list[str] = field(default_factory=list)
    nulls: list[dict[str, str]] = field(default_factory=list)
    rows: list[list[str]] = field(default_factory=list)
    rank_of_true: list[int] = field(default_factory=list)
    pairs: list[tuple[str, str]] = field(default_factory=list)
    logp: Any = None
    ranks: Any = None


def answer_chunk(
    model: Any, obs: list[Any], names: list[str], start: int, top: int, *, table: bool, records: bool, keep: bool = False
) -> ChunkAnswers:
    """Posterior, ranks and headings of one chunk (the terms computed once); its records and table rows.

    ``start`` is the index of the chunk's first observation among all the
    answered ones; ``keep`` keeps the log posterior and rank matrix (for the report).
    """
    from ..metrics import rank_scores
    from ..model import normalise_log

    if not records and not keep and not model.unknown_prior > 0:
        from ..retrieval import index_for

        index = index_for(model)
        if index is not None:  # a large map: the best places without scoring every place, same answers
            return _answer_indexed(index, model, obs, start, top, table=table)
    classes = [str(c) for c in model.classes_]
    n = len(obs)
    terms = model.term_log_likelihoods(obs)  # once: the posterior, ranks and headings follow from them
    logp = normalise_log(model.combine(terms))
    best_cols = np.argmax(logp, axis=1) if n else np.zeros(0, dtype=np.int64)
    col = {c: j for j, c in enumerate(classes)}
    truth = np.array([col.get(str(o.label), -1) if o.label is not None else -1 for o in obs], dtype=np.int64)
    rows_n = np.arange(n)
    ranks = rank_scores(logp) if keep else None
    # rank of the true place: how many places score at least as high (ties count against), as rank_scores
    at_truth = logp[rows_n, np.maximum(truth, 0)] if n else np.zeros(0)
    rank_all = (logp >= at_truth[:, None]).sum(axis=1) if n else np.zeros(0, dtype=np.int64)
    rank_of_true = np.where(truth >= 0, rank_all, 0)
    headings = np.full(n, np.nan)
    refs = np.full(n, -1, dtype=np.int64)
    sources: list[str | None] = [None] * n
    with_heading = shows_heading(model)
    if with_heading and n:
        # heading_deg: a feature at bearing b in the query is at b + heading_deg in the reference view
        h, refs, sources = model.heading_sources(obs, [model.classes_[j] for j in best_cols])
        headings = np.mod(-h, 360.0)
    unknown = model.predict_unknown_proba(obs) if model.unknown_prior > 0 else None
    out = ChunkAnswers(n, rank_of_true=[int(r) for r in rank_of_true])
    out.pairs = [(str(o.label), classes[int(best_cols[i])]) for i, o in enumerate(obs) if rank_of_true[i] > 0]
    if keep:
        out.logp, out.ranks = logp, ranks
    post = np.exp(logp) if (table or records) else None
    if records:
        assert post is not None
        places = list(model.places_.values())
        term_rows = {t: (ll.tolist(), np.isfinite(ll).all(axis=1).tolist()) for t, ll in terms.items()}
        post_rows: list[list[float]] = post.tolist()
        post_finite = np.asarray(np.isfinite(post).all(axis=1), dtype=bool).tolist()
        for i, o in enumerate(obs):
            best = classes[int(best_cols[i])]
            ref = places[int(best_cols[i])].observations[int(refs[i])] if refs[i] >= 0 else None
            nulls: dict[str, str] = {}
            rec: dict[str, Any] = {
                "index": start + i,
                "name": names[i],
                "place": o.label,
                "best": best,
                "posterior": _float_map(classes, post_rows[i], bool(post_finite[i]), "/posterior", nulls),
                "rank_of_true": int(rank_of_true[i]) if rank_of_true[i] > 0 else None,
                "terms": {t: _float_map(classes, ll[i], bool(ok[i]), f"/terms/{t}", nulls) for t, (ll, ok) in term_rows.items()},
                "heading_deg": None if np.isnan(headings[i]) else _finite(float(headings[i]), "/heading_deg", nulls),
                "heading_ref": None if ref is None else (ref.source or f"{best}#{int(refs[i])}"),
            }
            if with_heading:  # where heading_deg comes from (keypoints, profile, fingerprint)
                rec["heading_from"] = sources[i]
            if unknown is not None:
                rec["unknown"] = _finite(float(unknown[i]), "/unknown", nulls)
            # what encode_record gives for this record (tests/test_localize_stream.py), without walking every number
            out.records.append(json.dumps(rec, allow_nan=False))
            out.nulls.append(nulls)
    if table:
        assert post is not None
        for i, o in enumerate(obs):
            order = np.argsort(-logp[i], kind="stable")[:top]
            topk = ", ".join(f"{classes[j]} {post[i, j]:.3f}" for j in order)
            out.rows.append(_table_row(start + i, o, classes[int(best_cols[i])], topk, int(rank_of_true[i]),
                                       headings[i] if with_heading else None))  # fmt: skip
    return out


def _table_row(n: int, o: Any, best: str, topk: str, rank: int, heading: float | None) -> list[str]:
    """A row of ``localize``'s table: number, label, best place, the top places with their probabilities, the
    true place's rank (``-`` when unlabelled) and, with ``heading`` (degrees; None: no column), the heading."""
    row = [str(n), o.label or "-", best, topk, "-" if rank <= 0 else str(rank)]
    if heading is not None:
        row.append("-" if np.isnan(heading) else f"{heading:.1f}")
    return row


def _answer_indexed(index: Any, model: Any, obs: list[Any], start: int, top: int, *, table: bool) -> ChunkAnswers:
    """:func:`answer_chunk` through an exact index (:mod:`fingerloc.retrieval`): no records, no kept matrices.

    The same best places, ranks and headings as the full scan, and every posterior shown within
    :data:`~fingerloc.retrieval.POSTERIOR_TOL` of it.
    """
    from ..retrieval import POSTERIOR_TOL

    classes = [str(c) for c in model.classes_]
    n = len(obs)
    res = index.search(obs, k=min(top, len(classes)), tol=POSTERIOR_TOL, truth=[o.label for o in obs])
    best_cols = res.places[:, 0] if n else np.zeros(0, dtype=np.int64)
    rank_of_true = res.rank_of_truth
    headings = np.full(n, np.nan)
    with_heading = shows_heading(model)
    if with_heading and n:
        h, _, _ = model.heading_sources(obs, [model.classes_[j] for j in best_cols])
        headings = np.mod(-h, 360.0)
    out = ChunkAnswers(n, rank_of_true=[int(r) for r in rank_of_true])
    out.pairs = [(str(o.label), classes[int(best_cols[i])]) for i, o in enumerate(obs) if rank_of_true[i] > 0]
    if table:
        post = np.exp(res.log_posterior)
        for i, o in enumerate(obs):
            topk = ", ".join(f"{classes[int(j)]} {post[i, c]:.3f}" for c, j in enumerate(res.places[i][:top]))
            out.rows.append(_table_row(start + i, o, classes[int(best_cols[i])], topk, int(rank_of_true[i]),
                                       headings[i] if with_heading else None))  # fmt: skip
    return out
