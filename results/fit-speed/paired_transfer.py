"""Today's FactIRL fit against the joint one with an L-BFGS flat start, scored task by task.

On the ``bench mce`` draw (ELIRL's protocol: a 32x32 Objectworld map per task, 32 demonstrations
of 16 steps, k = 5, the ``objectworld-per-task`` preset's budgets and solvers), in one process:
one ``FactIRL.fit`` per configuration (``bench mce``'s :func:`fit_once`: FactIRL's own flat start
and the alternation, then ``flat_solver="lbfgs"`` and ``scheme="joint"``), each transferred to the
same ``--n-test`` test tasks on new maps (one demonstration each). Prints each fit's CPU time,
mean transfer, train and new-maps deviations (eq. 13), and the paired difference of the transfer
deviations task by task (mean, its standard error, median, how many tasks the joint fit scores
lower on): the test-task transfer is the noisiest of the scores, and only a paired comparison
tells a difference from the draw's noise.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/paired_transfer.py 30 mce --n-test 100 --seed 1 \
        > results/fit-speed/paired_transfer_30_mce_seed1.json
"""

import argparse
import json
import sys

import numpy as np

from factirl_opt.evaluation import deviation
from factirl_opt.lab.benchmarks.mce import benchmark_preset, fit_once, new_maps_deviation
from factirl_opt.lab.experiments.worlds import objectworld_per_task
from factirl_opt.parallel import limit_blas_threads

parser = argparse.ArgumentParser()
parser.add_argument("n_tasks", type=int)
parser.add_argument("objective", choices=["policy-matching", "mce"])
parser.add_argument("--n-test", type=int, default=100)
parser.add_argument("--seed", type=int, default=1)
args = parser.parse_args()
settings = dict(preset="objectworld-per-task", size=32, n_tasks=args.n_tasks, n_demos=32, length=16, n_primitives=5,
                repeats=1, n_test_tasks=args.n_test, max_iter=None, flat_max_iter=None)
preset = benchmark_preset(settings)
out = {}
with limit_blas_threads(1):
    gt = objectworld_per_task(preset, args.n_tasks, 32, args.seed)
    mdps = gt.mdps("test")[:args.n_test]
    for flat, scheme in (("default", "default"), ("lbfgs", "joint")):
        model, _, cpu, _ = fit_once(preset, gt, args.objective, args.seed + 1, flat, "default", scheme)
        model.set_params(planner=preset.planner)  # the counting planner is bound to the training maps' MDP
        model.transfer(mdps, gt.test_demos[:args.n_test], features=list(gt.task_maps["test"].features)[:args.n_test])
        dev = deviation(mdps, gt.test_rewards[:args.n_test], np.asarray(model.transfer_rewards_), planner=preset.planner)
        train = deviation(gt.mdps("train"), gt.train_rewards, np.asarray(model.rewards_), planner=preset.planner)
        out[f"{flat} {scheme}"] = dict(cpu=cpu, transfer=dev.tolist(), train=float(train.mean()),
                                       new_maps=new_maps_deviation(model, gt, preset))
        print(flat, scheme, round(cpu, 1), float(dev.mean()), float(train.mean()), out[f"{flat} {scheme}"]["new_maps"],
              file=sys.stderr)
a, b = (np.array(out[key]["transfer"]) for key in out)
d = b - a
out["paired_transfer_difference"] = dict(mean=float(d.mean()), standard_error=float(d.std(ddof=1) / np.sqrt(len(d))),
                                         median=float(np.median(d)), joint_lower=int((d < 0).sum()), n=len(d))
out["settings"] = dict(vars(args))
json.dump(out, sys.stdout, indent=1)
