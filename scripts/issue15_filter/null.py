"""Noise floor of the kidnap metric: a second never-kidnapped run against the reference, on the trials' B stretches."""
import sys, numpy as np
logs = sys.argv[1].split(",")
opts = dict(a.split("=") for a in sys.argv[2:])
sys.argv=[sys.argv[0]]
exec(open("/tmp/filter/run.py").read().split('if __name__')[0])
opts = {k: parse(v) for k, v in opts.items()}
for log in logs:
    data = prep(log, "fingerprint", 0, opts)
    full = data.run()
    k = kidnap_experiment(data, name=log, random_state=0, n_trials=20, stretch=2)  # only to get pairs? no
    second = data.run()
    has_q = data.truth >= 0
    # B starts as kidnap_experiment would choose: every observed step with a 40-step stretch
    n = data.truth.size; S = 40
    bs = [b for b in range(1, n - S + 1) if has_q[b] and has_q[b:b+S].sum() >= 5]
    rec, rec_obs = [], []
    for b in bs:
        agree = full.best[b:b+S] == second.best[b:b+S]
        seen = has_q[b:b+S]
        rec.append(next((j for j in range(S) if np.all(agree[j:])), None))
        rec_obs.append(next((j for j in range(S) if np.all(agree[j:][seen[j:]])), None))
    w10 = np.mean([r is not None and r <= 10 for r in rec]); w10o = np.mean([r is not None and r <= 10 for r in rec_obs])
    print(log, opts, "null-trial within10 all steps %.2f, observed %.2f; per-step disagreement %.3f (n=%d)" % (w10, w10o, np.mean(full.best != second.best), len(bs)), flush=True)
