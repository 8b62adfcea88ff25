"""Fit each log's fingerprint front end once; cache scores AND implied headings (per place) for the
held-out mapping rows (fold models, as the calibration) and the queries. Writes /tmp/heading/LOG.pkl.

usage: cache.py [LOG ...]
"""
import math, pickle, sys, time
from types import SimpleNamespace
import numpy as np
RAW = None
from fingerloc.experiments import markov
from fingerloc.experiments.carmen import FingerprintMethod, best_fingerprint_params
from fingerloc.experiments.protocol import load_log_scans, make_split
from fingerloc.pipeline.tracker import held_out_rows
from fingerloc.pipeline.places import visit_folds

LOGS = ["aces", "csail", "freiburg-101", "intel"]
def path(l): return f"/work/shared/data/carmen/{l}-corrected.log.gz"


def implied_headings(method, obs, scores, view_poses, top=None):
    """(n, P) implied absolute headings theta_ref + h (rad; NaN none) and (n, P, 2) the reference views' positions."""
    model = method.model_
    n, P = scores.shape
    H = np.full((n, P), np.nan)
    global RAW
    RAW = (np.full((n, P), np.nan), np.full((n, P), np.nan))
    XY = np.full((n, P, 2), np.nan)
    labels = list(model.classes_)
    col = {str(c): k for k, c in enumerate(labels)}
    order = np.argsort(-np.where(np.isfinite(scores), scores, -1e300), axis=1)
    K = P if top is None else min(top, P)
    for k in range(K):
        places = []
        ok = []
        for i in range(n):
            j = int(order[i, k])
            ok.append(np.isfinite(scores[i, j]))
            places.append(str(j) if str(j) in col else labels[0])
        h, v = model.headings_with_reference(obs, places)
        for i in range(n):
            j = int(order[i, k])
            if not ok[i] or v[i] < 0 or not np.isfinite(h[i]):
                continue
            ref = view_poses[j][v[i]]
            H[i, j] = math.remainder(ref[2] - math.radians(h[i]), 2 * math.pi)  # measured: b_view = b_query - h
            XY[i, j] = ref[:2]
            if RAW is not None:
                RAW[0][i, j], RAW[1][i, j] = math.radians(h[i]), ref[2]
    return H, XY


def build(log, top):
    t0 = time.time()
    scans, _ = load_log_scans(path(log))
    pos = markov._positions(scans)
    poses = markov._full_poses(scans)
    split = make_split(pos)
    m = markov.FilteredMethod("fingerprint")
    m.set_context(scans, split)
    tr_scans = [scans[i] for i in split.train_idx.tolist()]
    y = split.train_labels.copy()
    m.fit(tr_scans, y)
    held = m.held_out_
    P = split.n_places
    # query pass: a model on every training scan
    fm = FingerprintMethod(**best_fingerprint_params()).fit(tr_scans, y)
    q_scans = [scans[i] for i in split.query_idx.tolist()]
    qs = np.asarray(fm.score(q_scans), dtype=np.float64)
    tr_poses = poses[split.train_idx]
    view_poses = [tr_poses[y == j] for j in range(P)]
    qobs = fm._observations(q_scans)
    qH, qXY = implied_headings(fm, qobs, qs, view_poses, top)
    qraw = RAW
    # held-out mapping rows: fold models as held_out_calibration (visits; fallback alternate)
    fold = visit_folds(split.train_idx, y)
    if not np.array_equal(held_out_rows(fold), held.index):
        fold = np.arange(y.size) % 2
    assert np.array_equal(held_out_rows(fold), held.index), "fold mismatch"
    hH = np.full((held.index.size, P), np.nan)
    hXY = np.full((held.index.size, P, 2), np.nan)
    off = 0
    hraw = (np.full((held.index.size, P), np.nan), np.full((held.index.size, P), np.nan))
    for f in (0, 1):
        trn, te = np.flatnonzero(fold != f), np.flatnonzero(fold == f)
        present = np.unique(y[trn])
        remap = np.full(P, -1, dtype=np.int64)
        remap[present] = np.arange(present.size)
        mf = FingerprintMethod(**best_fingerprint_params()).fit([tr_scans[i] for i in trn], remap[y[trn]])
        s = np.asarray(mf.score([tr_scans[i] for i in te]), dtype=np.float64)
        vp = [tr_poses[trn][remap[y[trn]] == k] for k in range(present.size)]
        Hf, XYf = implied_headings(mf, mf._observations([tr_scans[i] for i in te]), s, vp, top)
        hH[off:off + te.size][:, present] = Hf
        hXY[off:off + te.size][:, present] = XYf
        hraw[0][off:off + te.size][:, present] = RAW[0]
        hraw[1][off:off + te.size][:, present] = RAW[1]
        off += te.size
    lite = [SimpleNamespace(pose=s.pose, fov=s.fov) for s in scans]
    d = dict(scans=lite, split=split, graph=m.graph_, transition=m.transition_, scale=m.scale_,
             rows=m.calibration_rows_, held=held, qs=qs, n_train=len(split.train_idx),
             qH=qH, qXY=qXY, hH=hH, hXY=hXY, top=top, qraw=qraw, hraw=hraw)
    with open(f"/tmp/heading/{log}.pkl", "wb") as fh:
        pickle.dump(d, fh)
    print(log, f"{time.time()-t0:.0f}s", "P", P, "queries", len(q_scans), "held", held.index.size, flush=True)


if __name__ == "__main__":
    top = None
    args = [a for a in sys.argv[1:] if not a.startswith("--top=")]
    for a in sys.argv[1:]:
        if a.startswith("--top="):
            top = int(a[6:])
    for log in (args or LOGS):
        build(log, top)
