"""The alignment kernels from several Python threads at once.

numba's "workqueue" threading layer aborts the process when two threads enter
parallel regions at once; every parallel kernel takes one lock
(``fingerloc._numba_guard``). The check runs in a subprocess pinned to the
workqueue layer, so that a missing guard kills that process, not the test run.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

import pytest

SCRIPT = textwrap.dedent(
    """
    import sys
    import threading
    import numpy as np
    from fingerloc.align import CostModel, alignment_costs, minimum_energy_costs
    from fingerloc.mog import fit_mixtures

    rng = np.random.default_rng(0)
    letters = np.array(list("vcbfnABCh"))
    refs = ["".join(rng.choice(letters, int(n))) for n in rng.integers(5, 30, 120)]
    queries = refs[:3]
    feature = CostModel.feature_aware()
    samples = [rng.uniform(-3, 3, 40) for _ in range(40)]
    jobs = {
        "cyclic_unit": lambda: alignment_costs(queries, refs, cyclic=True),
        "cyclic_feature": lambda: alignment_costs(queries, refs, cyclic=True, costs=feature),
        "plain_feature": lambda: alignment_costs(queries, refs, costs=feature),
        "energy": lambda: minimum_energy_costs(queries, refs[:60]),
        "mog": lambda: fit_mixtures(samples, 3, random_state=1).means,
    }
    jobs = {name: jobs[name] for name in sys.argv[1].split(",")}
    serial = {name: job() for name, job in jobs.items()}
    errors = []

    def worker(t):
        try:
            for rep in range(2):
                for name in list(jobs)[:2] if t < 4 else jobs:
                    out = jobs[name]()
                    if not np.array_equal(out, serial[name]):
                        errors.append(f"thread {t}: {name} differs")
        except Exception as err:  # pragma: no cover - reported below
            errors.append(f"thread {t}: {err!r}")

    threads = [threading.Thread(target=worker, args=(t,)) for t in range(6)]
    for th in threads:
        th.start()
    for th in threads:
        th.join()
    import numba
    print(numba.threading_layer())
    print("\\n".join(errors) if errors else "ok")
    """
)


@pytest.mark.parametrize(
    "names",
    # three groups, each its own process: with a cold numba cache one process compiling every kernel took 9 s
    ["cyclic_unit,cyclic_feature,plain_feature", "energy,cyclic_unit", "mog,cyclic_unit"],
)
def test_alignment_costs_from_four_threads_workqueue(names):
    env = {**os.environ, "NUMBA_THREADING_LAYER": "workqueue", "NUMBA_NUM_THREADS": "2"}
    res = subprocess.run([sys.executable, "-c", SCRIPT, names], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0, res.stderr[-2000:]
    layer, verdict = res.stdout.strip().splitlines()[-2:]
    assert layer == "workqueue"
    assert verdict == "ok"
