"""Rerun only the pose filter on cached per-log fits (scripts/issue15_heading/cache.py), with or without headings.

usage: run.py NAME SEEDS BASE [k=v ...] [--kidnap] [--log=LOG ...]
BASE: fingerprint (cached) or baseline-histogram (needs /tmp/filter/LOG-baseline-histogram.pkl from
scripts/issue15_filter/cache.py). Options are PoseFilteredMethod keywords (heading=True ...).
Writes /tmp/heading/res-NAME.json. Same protocol as scripts/issue15_filter/run.py.
"""
import json, pickle, sys, time
import numpy as np
from fingerloc.experiments import markov
from fingerloc.experiments.markov import FilteredMethod, PoseFilteredMethod, TrackingData, kidnap_experiment

LOGS = ["aces", "csail", "freiburg-101", "intel"]
_cache = {}


def _restore(self, scans, labels):
    d = _cache["d"]
    self.graph_, self.transition_, self.scale_ = d["graph"], d["transition"], d["scale"]
    self.calibration_rows_, self.held_out_ = d["rows"], d["held"]
    if not self.calibrate:
        self.scale_ = 1.0
    return self


FilteredMethod.fit = _restore
PoseFilteredMethod._held_out_headings = lambda self, scans, labels: _cache["d"].get("hH")


def load(log, base):
    f = f"/tmp/heading/{log}.pkl" if base == "fingerprint" else f"/tmp/filter/{log}-{base}.pkl"
    return pickle.load(open(f, "rb"))


def prep(log, base, seed, opts):
    d = load(log, base)
    _cache["d"] = d
    split = d["split"]
    m = PoseFilteredMethod(base, seed=seed, **opts)
    m.set_context(d["scans"], split)
    m.fit([None] * d["n_train"], split.train_labels.copy())
    ll, dist = m.step_log_likelihoods(d["qs"])
    truth = np.full(split.n_scans - split.n_mapping, -1, dtype=np.int64)
    truth[split.query_idx - split.n_mapping] = split.query_labels
    pos = markov._positions(d["scans"])
    hd = None
    if m.heading_model_ is not None and "qH" in d:
        hd = np.full(ll.shape, np.nan)
        hd[split.query_idx - split.n_mapping] = d["qH"]
    return TrackingData(m, ll, dist, truth, pos[split.n_mapping:], np.vstack([np.zeros((1, 3)), m.increments_]), hd)


def parse(v):
    for f in (int, float):
        try:
            return f(v)
        except ValueError:
            pass
    return {"True": True, "False": False, "None": None}.get(v, v)


def kidnap_into(r, data, log, seed):
    """Run the kidnap trials of one log into its result row ``r``."""
    k = kidnap_experiment(data, name=log, random_state=seed)
    r["kidnap"] = k.summary()
    r["trials"] = k.trials


def pool(name, seed, per, kid):
    """Add and print the pooled line of one seed's per-log rows (``per[log]["n"]``, ``["top1"]``)."""
    n = sum(p["n"] for p in per.values())
    line = {"pooled": sum(p["top1"] * p["n"] for p in per.values()) / n}
    if kid:
        tr = [t for p in per.values() for t in p["trials"]]
        line["kidnap"] = markov.KidnapResult("pooled", tr).summary()
    per["pooled"] = line
    print(name, seed, "POOLED", json.dumps(line), flush=True)
    return per


if __name__ == "__main__":
    name, seeds, base = sys.argv[1], [int(x) for x in sys.argv[2].split(",")], sys.argv[3]
    args = [a for a in sys.argv[4:] if "=" in a and not a.startswith("--")]
    kid = "--kidnap" in sys.argv
    logs = [a[6:] for a in sys.argv if a.startswith("--log=")] or LOGS
    opts = {k: parse(v) for k, v in (a.split("=", 1) for a in args)}
    res = {"name": name, "base": base, "opts": args, "seeds": {}}
    for seed in seeds:
        per = {}
        for log in logs:
            t0 = time.time()
            data = prep(log, base, seed, opts)
            full = data.run()
            q = data.truth >= 0
            top1 = float(np.mean(full.best[q] == data.truth[q]))
            hm = data.method.heading_model_
            tun = data.method.tuning_
            r = {"n": int(q.sum()), "top1": top1, "mapping_top1": max((t["top1"] for t in tun), default=None), "outlier": data.method.outlier_, "temper": data.method.temper_metres_,
                 "heading": None if hm is None else [round(hm.kappa, 2), round(hm.intercept, 2), round(hm.slope, 2), round(hm.reverse, 3), round(float(hm.peak_share(0.0)), 3), round(float(hm.peak_share(-3.0)), 3)]}
            if kid:
                kidnap_into(r, data, log, seed)
            r["sec"] = time.time() - t0
            per[log] = r
            print(name, seed, log, json.dumps({k: v for k, v in r.items() if k != "trials"}), flush=True)
        res["seeds"][seed] = pool(name, seed, per, kid)
    json.dump(res, open(f"/tmp/heading/res-{name}.json", "w"), indent=1)
