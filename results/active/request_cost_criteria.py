"""CPU time of one request for one task by each criterion, against one transfer of that task.

Usage: OMP_NUM_THREADS=1 python results/active/request_cost_criteria.py WORLD SEED [N_TASKS]

``bench active``'s model and test tasks (WORLD: grid or objectworld-per-task-quick); for each of the
first N_TASKS test tasks alone (one demonstration): ``transfer``, then its posterior (built when first
read), then ``request_starts`` ranking every state by each criterion (``time.process_time``, median of
3 repeats). Prints JSON: per criterion the ratio of the summed request CPU (posterior + ranking)
to the summed transfer CPU, and the median and largest per-task ratios.
"""

import json
import statistics
import sys
import time

import numpy as np

from factirl_opt.lab.benchmarks.active import DEFAULTS, world
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.learners.active import CRITERIA, request_starts
from factirl_opt.learners.factirl import FactIRL


def main(name, seed, n_tasks=10):
    s = dict(DEFAULTS)
    preset, gt, train_mdps, train_feats, mdps, feats = world(name, s, seed)
    model = FactIRL(rng=seed, features=train_feats,
                    **factorial_options(preset, preset.solvers, "policy-matching", features=train_feats is not None))
    model.fit(train_mdps, gt.train_demos)
    times = {"transfer": np.zeros(n_tasks), "posterior": np.zeros(n_tasks), **{c: np.zeros(n_tasks) for c in CRITERIA}}
    for i in range(n_tasks):
        m1 = [mdps[i]] if isinstance(mdps, list) else mdps
        f1 = None if feats is None else [feats[i]]
        runs: dict = {k: [] for k in times}
        for _ in range(3):
            demos = [np.asarray(gt.test_demos[i])]
            t = time.process_time()
            model.transfer(m1, demos, features=f1)
            runs["transfer"].append(time.process_time() - t)
            t = time.process_time()
            model.transfer_posterior_
            runs["posterior"].append(time.process_time() - t)
            for c in CRITERIA:
                t = time.process_time()
                request_starts(model, m1, demos, 1, features=f1, criterion=c)
                runs[c].append(time.process_time() - t)
        for k in times:
            times[k][i] = statistics.median(runs[k])
    out = {"world": name, "seed": seed, "n_tasks": n_tasks}
    for c in CRITERIA:
        ratio = (times["posterior"] + times[c]) / times["transfer"]
        out[c] = {"request_over_transfer": float((times["posterior"] + times[c]).sum() / times["transfer"].sum()),
                  "median_task_ratio": float(np.median(ratio)), "max_task_ratio": float(ratio.max()),
                  "ranking_cpu_s": float(times[c].sum())}
    out["transfer_cpu_s"], out["posterior_cpu_s"] = float(times["transfer"].sum()), float(times["posterior"].sum())
    return out


if __name__ == "__main__":
    print(json.dumps(main(sys.argv[1], int(sys.argv[2]), *(int(a) for a in sys.argv[3:])), indent=2))
