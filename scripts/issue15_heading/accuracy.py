"""How accurate is the implied heading at the TRUE place: held-out mapping rows and queries, both sign conventions."""
import math, pickle, sys
import numpy as np
from fingerloc.experiments import markov

def wrap(a): return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi

for log in sys.argv[1:]:
    d = pickle.load(open(f"/tmp/heading/{log}.pkl", "rb"))
    split, held = d["split"], d["held"]
    poses = np.array([s.pose for s in d["scans"]])
    th_tr = poses[split.train_idx][held.index, 2]
    rows = np.arange(held.labels.size)
    for name, H, th, lab in (("held", d["hH"], th_tr, held.labels),
                             ("query", d["qH"], poses[split.query_idx, 2], split.query_labels)):
        imp = H[np.arange(lab.size), lab]
        ok = np.isfinite(imp)
        e = np.abs(wrap(th[ok] - imp[ok]))
        # other sign: theta_ref - h instead of + h  -> recover h and ref from imp? not stored; report only +
        print(f"{log:13s} {name:6s} n={lab.size} with heading {ok.mean():.2f} |err| median {np.degrees(np.median(e)):.1f} deg,"
              f" <10deg {np.mean(e < math.radians(10)):.2f} <30deg {np.mean(e < math.radians(30)):.2f} >90deg {np.mean(e > math.pi/2):.2f}")
    for name, (h, r), th, lab in (("held", d["hraw"], th_tr, held.labels), ("query", d["qraw"], poses[split.query_idx, 2], split.query_labels)):
        i = np.arange(lab.size)
        hh, rr = h[i, lab], r[i, lab]
        ok = np.isfinite(hh)
        for sgn in (1, -1):
            e = np.abs(wrap(th[ok] - (rr[ok] + sgn * hh[ok])))
            print(f"   {name} sign {sgn:+d}: median {np.degrees(np.median(e)):.1f} <10 {np.mean(e<0.1745):.2f} <30 {np.mean(e<0.5236):.2f}; raw delta(true-ref) median {np.degrees(np.median(np.abs(wrap(th[ok]-rr[ok])))):.1f}")
