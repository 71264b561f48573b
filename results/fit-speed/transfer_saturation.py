"""Policy matching's one-demonstration transfer with and without the flat learner's saturation rule.

On one draw of the ``objectworld-per-task`` preset (``--n-tasks`` training tasks, a 32x32 map
each, 32 demonstrations; 100 test tasks on new maps, one demonstration each), in one process:
the flat row (GradIRL with the preset's stopping rules, ``flat_stol = 1e-5``) on the training
tasks and on the test tasks (the line-up's ``flat, features`` test row), the factorial row from
the flat row's rewards (``FactIRL.fit(..., flat_rewards=...)``) with the preset's scheme and,
for comparison, the alternation; then each factorial model's transfer to the test tasks with
``transfer_stol`` 0 (the transfer as before) and with the flat learner's ``stol`` (1e-5). Prints
per transfer the mean deviation (eq. 13), CPU time, evaluations, how the tasks stopped, and the
per-task deviations' paired difference with the flat learner's test row.

    git worktree add /work/wl/ts46 7ed48a3     # FactIRL(transfer_stol=...), reverted since (no effect here)
    PYTHONPATH=/work/wl/ts46 OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/transfer_saturation.py --n-tasks 20 --seed 0

Runs on commit 7ed48a3 only (the parameter ``transfer_stol`` it sets was reverted in ed0911c: the
transfers stop by the gradient rule before their loss saturates, so it changed nothing).
"""

import argparse
import dataclasses
import json
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.experiments.learner_solvers import factorial_options, flat_features_solver
from factirl_opt.lab.experiments.presets import get_preset
from factirl_opt.lab.experiments.worlds import objectworld_per_task

parser = argparse.ArgumentParser()
parser.add_argument("--n-tasks", type=int, default=20)
parser.add_argument("--n-demos", type=int, default=32)
parser.add_argument("--seed", type=int, default=0)
parser.add_argument("--objective", default="policy-matching")
parser.add_argument("--schemes", nargs="+", default=["joint", "alternating"])
parser.add_argument("--stols", nargs="+", type=float, default=[0.0, 1e-5])
args = parser.parse_args()

preset = get_preset("objectworld-per-task")
gt = objectworld_per_task(preset, args.n_tasks, args.n_demos, args.seed)
mdps, features = gt.mdps("train"), list(gt.task_maps["train"].features)
test_mdps, test_features = gt.mdps("test"), list(gt.task_maps["test"].features)
objective = args.objective
out = {}


def flat_fit(mdp_list, feats, demos):
    model = fo.GradIRL(beta=preset.beta, features=feats, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol,
                       stol=preset.flat_stol, solver=flat_features_solver(preset, objective), objective=objective,
                       planner=preset.planner)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        model.fit(mdp_list, demos)
        return model, time.process_time() - c0


flat_train, _ = flat_fit(mdps, features, gt.train_demos)
flat_test, cpu = flat_fit(test_mdps, test_features, gt.test_demos)
flat_dev = fo.deviation(test_mdps, gt.test_rewards, np.asarray(flat_test.rewards_), planner=preset.planner)
out["flat, features (test)"] = dict(mean_deviation=float(np.mean(flat_dev)), cpu_s=round(cpu, 2),
                                    n_evaluations=int(flat_test.n_evaluations_), reason=flat_test.stop_reason_)
print(json.dumps(out), flush=True)
for scheme in args.schemes:
    p = dataclasses.replace(preset, fact_scheme=scheme)
    model = fo.FactIRL(rng=np.random.default_rng(args.seed + 1), features=features,
                       **factorial_options(p, p.solvers, objective))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        model.fit(mdps, gt.train_demos, flat_rewards=flat_train.rewards_)
        fit_cpu = time.process_time() - c0
    for stol in args.stols:
        model.set_params(transfer_stol=stol)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c0 = time.process_time()
            model.transfer(test_mdps, gt.test_demos, features=test_features)
            cpu = time.process_time() - c0
        dev = fo.deviation(test_mdps, gt.test_rewards, np.asarray(model.transfer_rewards_), planner=preset.planner)
        diff = dev - flat_dev
        name = f"factorial, {model.scheme}, transfer_stol {stol:g}"
        out[name] = dict(fit_cpu_s=round(fit_cpu, 2), fit_loss=float(np.sum(model.loss_)),
                         mean_deviation=float(np.mean(dev)), cpu_s=round(cpu, 2),
                         n_evaluations=int(model.transfer_n_evaluations_), reason=model.transfer_stop_reason_,
                         minus_flat_mean=float(np.mean(diff)),
                         minus_flat_se=float(np.std(diff, ddof=1) / np.sqrt(diff.size)))
        print(json.dumps({name: out[name]}), flush=True)
print(json.dumps(dict(settings=vars(args), results=out), indent=1))
