"""The photos behind panorama answers: the query and the answered view with their verified matches.

For each answered query that carries keypoints and whose photo (its
``source``) can be read, :func:`write_photo_answers` draws the query's band
above the reference view the heading was measured against (``heading_ref``
of ``localize``), joins the keypoint matches that the relative pose explains
(green; the rejected ones faint red), states the heading and where it comes
from, and explains the answer by the terms that carry weight: for each term
of non-zero weight, its weighted log-likelihood of the answer minus that of
the runner-up place (nats; positive: the term speaks for the answer).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from .._types import FArray
from ..errors import FingerlocError
from .html import Page, esc
from .staging import staged_report

__all__ = ["draw_photo_match", "term_evidence", "write_photo_answers"]


def term_evidence(model: Any, term_ll: dict[str, FArray], row: int, answer: int) -> list[tuple[str, float, float]]:
    """``(term, weight, weighted evidence)`` per term of non-zero weight for one query, largest evidence first.

    Evidence: ``weight * (ll[answer] - max over the other places of ll)`` in nats
    (the runner-up of each term; 0 with a single place).
    """
    out = []
    for name, ll in term_ll.items():
        w = float(model._weight(name))
        if w <= 0:
            continue
        r = np.asarray(ll[row], dtype=np.float64)
        other = np.delete(r, answer)
        ev = float(w * (r[answer] - other.max())) if other.size else 0.0
        out.append((name, w, ev))
    return sorted(out, key=lambda x: -x[2])


def _pixels(pano: Any, bearing: FArray, elevation: FArray) -> tuple[FArray, FArray]:
    from ..features.keypoints import band_elevations

    top, bottom = band_elevations(pano)
    h = np.asarray(pano.image).shape[0]
    return np.asarray(pano.bearing_column(bearing)), (top - np.asarray(elevation)) / (top - bottom) * h


def draw_photo_match(
    path: str | Path,
    query: Any,
    reference: Any,
    q_kps: Any,
    r_kps: Any,
    pairs: Any,
    inliers: Any,
    *,
    title: str = "",
    max_lines: int = 150,
) -> Path:
    """Draw the query's band above the reference's, joined by matched keypoints (PNG at ``path``).

    ``query``, ``reference``: :class:`fingerloc.sensors.Panorama` bands;
    ``q_kps``, ``r_kps``: their :class:`~fingerloc.features.keypoints.Keypoints`;
    ``pairs``: ``(m, 2)`` indices of the matches; ``inliers``: ``(m,)`` bool.
    At most ``max_lines`` of each kind are drawn (evenly thinned).
    """
    from . import figures

    plt = figures.plt
    qi, ri = np.asarray(query.image), np.asarray(reference.image)
    w = max(qi.shape[1], ri.shape[1])
    fig, ax = plt.subplots(figsize=(12, 12 * (qi.shape[0] + ri.shape[0]) / w + 0.6))
    ax.imshow(qi, extent=(0, qi.shape[1] * w / qi.shape[1], qi.shape[0], 0))
    gap = qi.shape[0]
    ax.imshow(ri, extent=(0, ri.shape[1] * w / ri.shape[1], gap + ri.shape[0], gap))
    pr = np.asarray(pairs, dtype=np.int64).reshape(-1, 2)
    inl = np.asarray(inliers, dtype=bool).reshape(-1)
    if pr.size:
        qx, qy = _pixels(query, q_kps.bearing[pr[:, 0]], q_kps.elevation[pr[:, 0]])
        rx, ry = _pixels(reference, r_kps.bearing[pr[:, 1]], r_kps.elevation[pr[:, 1]])
        qx, rx = qx * w / qi.shape[1], rx * w / ri.shape[1]
        for sel, colour, alpha in ((~inl, "#ff5050", 0.25), (inl, "#30ff60", 0.9)):
            k = np.flatnonzero(sel)
            if k.size > max_lines:
                k = k[np.linspace(0, k.size - 1, max_lines).round().astype(int)]
            for j in k:
                ax.plot([qx[j], rx[j]], [qy[j], gap + ry[j]], color=colour, alpha=alpha, lw=0.8)
            ax.scatter(qx[k], qy[k], s=6, color=colour, alpha=alpha)
            ax.scatter(rx[k], gap + ry[k], s=6, color=colour, alpha=alpha)
    ax.set_xlim(0, w)
    ax.set_ylim(gap + ri.shape[0], 0)
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=10)
    return figures._save(fig, path)


@staged_report
def write_photo_answers(
    out_dir: str | Path,
    *,
    model: Any,
    observations: Sequence[Any],
    names: Sequence[str] | None = None,
    max_answers: int = 20,
    title: str = "fingerloc: the photos behind the answers",
) -> Path | None:
    """Write the photo page of a panorama model's answers (module docstring); None when no query has keypoints.

    Parameters
    ----------
    out_dir : str or Path
        The folder (created); ``index.html`` and one PNG per drawn answer.
    model : PlaceModel
        Fitted, with the keypoint term ``K``.
    observations : sequence of Observation
        The queries (their ``source``: the photo files).
    names : sequence of str, optional
    max_answers : int
        At most this many queries (the first ones with keypoints).
    """
    from ..features.keypoints import match_keypoints
    from ..features.sphere import ransac_pose
    from ..pipeline.files import FeatureOptions, panorama_from_file

    obs = [o for o in observations]
    pick = [i for i, o in enumerate(obs) if o.keypoints is not None and len(o.keypoints)][:max_answers]
    kt = model.terms_.get("K")
    if not pick or kt is None:
        return None
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    qs = [obs[i] for i in pick]
    term_ll = model.term_log_likelihoods(qs)
    from ..model import normalise_log

    logp = normalise_log(model.combine(term_ll))
    best = np.argmax(logp, axis=1)
    heads, refs, sources = model.heading_sources(qs, [model.classes_[j] for j in best])
    places = list(model.places_.values())
    page = Page(title)
    page.paragraph(
        "Each query's photo (top) and the stored view its heading was measured against (bottom). Green lines join "
        "the keypoint matches that one relative pose of the two cameras explains; faint red ones were rejected. "
        "Evidence: each weighted term's log-likelihood of the answer minus that of its runner-up (nats)."
    )
    opts = FeatureOptions()
    for k, (i, o) in enumerate(zip(pick, qs, strict=True)):
        name = names[i] if names is not None else f"query {i + 1}"
        place = str(model.classes_[best[k]])
        p = float(np.exp(logp[k, best[k]]))
        head = None if not math.isfinite(heads[k]) else float(np.mod(-heads[k], 360.0))
        page.heading(f"{name}: {place} ({p:.3f})", 3)
        ev = term_evidence(model, term_ll, k, int(best[k]))
        facts = [
            f"true place: {o.label}" if o.label else "true place: not given",
            "heading: -" if head is None else f"heading: {head:.1f} deg (from the {sources[k]})",
        ]
        page.items(facts)
        page.table(["term", "weight", "evidence (nats)"], [(t, f"{w:g}", f"{e:+.2f}") for t, w, e in ev],
                   numeric=[False, True, True])  # fmt: skip
        ref_obs = places[int(best[k])].observations[int(refs[k])] if refs[k] >= 0 else None
        if ref_obs is None or ref_obs.keypoints is None or not o.source or not ref_obs.source:
            page.paragraph("(no reference view with keypoints and a photo file to draw)")
            continue
        try:
            qp = panorama_from_file(Path(o.source), opts)
            rp = panorama_from_file(Path(ref_obs.source), opts)
        except FingerlocError as err:  # a photo moved or unreadable: the page says so, the report goes on
            page.paragraph(f"(photos not drawn: {esc(str(err))})")
            continue
        pairs = match_keypoints(o.keypoints, ref_obs.keypoints)
        inl = np.zeros(len(pairs), dtype=bool)
        if len(pairs) >= 10:
            fit = ransac_pose(o.keypoints.vectors()[pairs[:, 0]], ref_obs.keypoints.vectors()[pairs[:, 1]],
                              model=kt.model_, threshold=math.radians(kt.threshold_deg))  # fmt: skip
            if fit is not None:
                inl = fit.inliers
        fig = f"answer{k + 1}.png"
        draw_photo_match(
            out / fig, qp, rp, o.keypoints, ref_obs.keypoints, pairs, inl,
            title=f"{Path(o.source).name} (top) and {Path(ref_obs.source).name} (bottom): "
            f"{int(inl.sum())} of {len(pairs)} matches verified"
            + ("" if head is None else f", heading {head:.1f} deg"),
        )  # fmt: skip
        page.figure(fig, f"the query photo above the reference view with {int(inl.sum())} verified matches")
    return page.write(out)
