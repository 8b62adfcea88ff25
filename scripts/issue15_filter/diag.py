import sys, numpy as np
chs = dict(a.split("=") for a in sys.argv[1:])
sys.argv=[sys.argv[0]]
exec(open("/tmp/filter/run.py").read().split('if __name__')[0])
if chs:
    trk.challenger_of = lambda c: None if not c.challenger else Challenger(**{"switch_nats": c.challenger_switch_nats, **{k: parse(v) for k,v in chs.items()}})
    markov.challenger_of = trk.challenger_of
log = "aces"
data = prep(log, "fingerprint", 0, {"challenger": True})
f = data.method.filter_
full = data.run()
q = data.truth >= 0
print("top1", np.mean(full.best[q] == data.truth[q]))
print("full trace", [(t,e,round(x,1)) for t,e,x in f.challenger_trace_ if e!="compare"][:60])
import fingerloc.experiments.markov as mk
orig = TrackingData.run
def run(self, idx=None):
    r = orig(self, idx)
    if idx is not None:
        print("trial", [(t,e,round(x,1)) for t,e,x in f.challenger_trace_ if t>=38])
    return r
TrackingData.run = run
k = kidnap_experiment(data, name=log, random_state=0, n_trials=6)
for t in k.trials: print(t["recover_steps"], t["recover_observed_steps"], t["first_right_steps"])
