"""Rerun only the pose filter on cached per-log fits (issue 15, branch h-kid).

usage: run.py VARIANT SEEDS [--kidnap] [--null] [--log=NAME ...]

VARIANT names a PoseFilteredMethod option set (VARIANTS below); the cache is
written by cache.py (the benchmark's FilteredMethod.fit per log, and the
query scores). Prints and writes /tmp/kid/res-VARIANT-SEEDS.json:
  top1      the query steps' top-1 of the first filter run (what `bench carmen` reports)
  kidnap    kidnap_experiment's summary (the trials of `bench kidnap --filter pose --seed K`)
  null      two never-kidnapped runs of the filter: per-step disagreement, and for each
            hold margin (held_best) the disagreement between queries and the accuracy against
            the true Voronoi cell between queries; the kidnap floor on every eligible B start.
"""
import json, math, pickle, sys, time
import numpy as np
from fingerloc.experiments import markov
from fingerloc.experiments.markov import FilteredMethod, PoseFilteredMethod, TrackingData, kidnap_experiment, nearest_cells
from fingerloc.map.relocalize import Augmented, held_best

LOGS = ["aces", "csail", "freiburg-101", "intel"]
MARGINS = [0.0, 0.05, 0.1, 0.2, 0.3, math.inf]
VARIANTS = {
    "base": {},  # the defaults before this session (argmax between observations)
    "new": {"hold_margin": 0.05, "tie_break": 0.02},  # the defaults after it
    "amcl": {"augmented": Augmented()},                      # slow 0.05, fast 0.5, cap 0.5
    "amcl-f1": {"augmented": Augmented(fast=1.0)},
    "amcl-s01": {"augmented": Augmented(slow=0.01, fast=0.3)},
    "amcl-c2": {"augmented": Augmented(cap=0.2)},
    "amcl-c9": {"augmented": Augmented(cap=0.9)},
    "fixed05": {"augmented": Augmented(floor=0.05, slow=0.0, fast=0.0, cap=0.05)},
    "fixed20": {"augmented": Augmented(floor=0.2, slow=0.0, fast=0.0, cap=0.2)},
    "amcl-s01f1": {"augmented": Augmented(slow=0.01, fast=0.1)},
    "amcl-t5": {"augmented": Augmented(slow=0.01, fast=0.2, threshold=0.5)},
    "amcl-rel": {"augmented": Augmented(relative=True)},
    "amcl-rel-t5": {"augmented": Augmented(slow=0.01, fast=0.2, threshold=0.5, relative=True)},
    "amcl-rel-s01f1": {"augmented": Augmented(slow=0.01, fast=0.1, relative=True)},
    "res1000": {"augmented": Augmented(reserve=1000, adaptive=False)},
    "res300": {"augmented": Augmented(reserve=300, adaptive=False)},
    "res1000-e02": {"augmented": Augmented(reserve=1000, adaptive=False, floor=0.02, cap=0.02)},
    "res1000-e05": {"augmented": Augmented(reserve=1000, adaptive=False, floor=0.05, cap=0.05)},
    "res1000-amcl-c1": {"augmented": Augmented(reserve=1000, cap=0.1)},
    "res1000-rel-c1": {"augmented": Augmented(reserve=1000, cap=0.1, relative=True)},
    "kid01": {"kidnap": 0.01},
    "kid03": {"kidnap": 0.03},
    "res1000-pp": {"augmented": Augmented(reserve=1000, adaptive=False), "_place_poses": True},
    "res1000-e02-pp": {"augmented": Augmented(reserve=1000, adaptive=False, floor=0.02, cap=0.02), "_place_poses": True},
    "amcl-pp": {"augmented": Augmented(), "_place_poses": True},
    "op03": {"off_place": 0.03},
    "op01": {"off_place": 0.01},
    "op003": {"off_place": 0.003},
    "tb01": {"tie_break": 0.01},
    "tb02": {"tie_break": 0.02},
    "tb03": {"tie_break": 0.03},
    "tb05": {"tie_break": 0.05},
    "hold05-tb02": {"hold_margin": 0.05, "tie_break": 0.02},
    "hold05": {"hold_margin": 0.05},
    "hold10": {"hold_margin": 0.1},
    "hold20": {"hold_margin": 0.2},
}
_cache = {}


def _restore(self, scans, labels):
    d = _cache["d"]
    self.graph_, self.transition_, self.scale_ = d["graph"], d["transition"], d["scale"]
    self.calibration_rows_, self.held_out_ = d["rows"], d["held"]
    return self


FilteredMethod.fit = _restore


def prep(log, seed, opts, base="fingerprint"):
    d = pickle.load(open(f"/tmp/kid/{log}-{base}.pkl", "rb"))
    _cache["d"] = d
    split = d["split"]
    pp = opts.get("_place_poses", False)
    m = PoseFilteredMethod(base, seed=seed, **{k: v for k, v in opts.items() if not k.startswith("_")})
    m.set_context(d["scans"], split)
    m.fit([None] * d["n_train"], split.train_labels.copy())
    if pp:  # kidnapping / reserve particles at the mapping run's poses, both headings (PoseFilter(place_poses=))
        from fingerloc.map.pose_filter import PoseFilter, path_start_poses

        mp = np.array([s.pose for s in d["scans"][: split.n_mapping]], dtype=np.float64)
        f = m.filter_
        m.filter_ = PoseFilter(f.centres, f.radius, n_particles=f.n_particles, kidnap=f.kidnap, outlier=f.outlier,
                               off_place=f.off_place, place_poses=path_start_poses(mp, spacing=0.25), random_state=seed)
    ll, dist = m.step_log_likelihoods(d["qs"])
    truth = np.full(split.n_scans - split.n_mapping, -1, dtype=np.int64)
    truth[split.query_idx - split.n_mapping] = split.query_labels
    pos = markov._positions(d["scans"])[split.n_mapping:]
    return TrackingData(m, ll, dist, truth, pos, np.vstack([np.zeros((1, 3)), m.increments_]),
                        cells=nearest_cells(pos, split.centres))


def null(data, full, S=40):
    second = data.run()
    obs = data.truth >= 0
    out = {"disagree_all": float(np.mean(full.best != second.best))}
    n = obs.size
    bs = [b for b in range(1, n - S + 1) if obs[b] and obs[b:b + S].sum() >= 5]
    for m in MARGINS:
        a, b = held_best(full, obs, m), held_best(second, obs, m)
        dis = a.best != b.best
        rec = [markov._settles(~dis[s:s + S]) for s in bs]
        out[f"m{m:g}"] = {
            "disagree_between": float(np.mean(dis[~obs])),
            "cell_acc_between": float(np.mean(a.best[~obs] == data.cells[~obs])),
            "cell_acc_all": float(np.mean(a.best == data.cells)),
            "floor_within_10": float(np.mean([r is not None and r <= 10 for r in rec])) if rec else None,
        }
    return out


if __name__ == "__main__":
    name, seeds = sys.argv[1], [int(x) for x in sys.argv[2].split(",")]
    kid, do_null = "--kidnap" in sys.argv, "--null" in sys.argv
    logs = [a[6:] for a in sys.argv if a.startswith("--log=")] or LOGS
    # every variant with the former answers between observations unless it says otherwise
    opts = {"hold_margin": None, "tie_break": None, **VARIANTS[name]}
    res = {"name": name, "opts": repr(opts), "seeds": {}}
    for seed in seeds:
        per = {}
        for log in logs:
            t0 = time.time()
            data = prep(log, seed, opts)
            full = data.run()
            q = data.truth >= 0
            r = {"n": int(q.sum()), "top1": float(np.mean(full.best[q] == data.truth[q])),
                 "outlier": data.method.outlier_, "temper": data.method.temper_metres_,
                 "shares": len(getattr(data.method.filter_, "shares_", []))}
            if do_null:
                r["null"] = null(data, full)
            if kid:
                k = kidnap_experiment(data, name=log, random_state=seed)
                r["kidnap"] = k.summary()
                r["trials"] = k.trials
            r["sec"] = time.time() - t0
            per[log] = r
            print(name, seed, log, json.dumps({k: v for k, v in r.items() if k != "trials"}), flush=True)
        n = sum(p["n"] for p in per.values())
        line = {"pooled": sum(p["top1"] * p["n"] for p in per.values()) / n}
        if kid:
            line["kidnap"] = markov.KidnapResult("pooled", [t for p in per.values() for t in p["trials"]]).summary()
        per["pooled"] = line
        res["seeds"][seed] = per
        print(name, seed, "POOLED", json.dumps(line), flush=True)
    json.dump(res, open(f"/tmp/kid/res-{name}-{sys.argv[2].replace(',', '')}.json", "w"), indent=1)
