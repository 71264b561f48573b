"""The ``objectworld-per-task`` line-up's training rows as the harness builds them, before and after the preset's switch.

The experiments fit ``flat, features`` (GradIRL, the preset's ``flat_features_solver`` and
stopping rules) and start ``factorial, features`` from its rewards (``FactIRL.fit(...,
flat_rewards=...)``: FactIRL's own flat start, and so ``FactIRL(flat_tol=...)``, does not run);
``factorial, features, random init`` starts from a random dictionary. For each objective, on
one draw of ``--n-tasks`` training tasks (a 32x32 map each, 32 demonstrations of 16 steps) in
one process, this fits:

- the flat row with ``flat_stol = 0`` (the protocol before the switch) and with the preset's;
- the PCA-start factorial row from each, with the alternation and with the preset's scheme;
- the random-init factorial row with each scheme.

Prints per fit its CPU time, evaluations, final loss, the mean train deviation (eq. 13), the
mean deviation on fresh maps of the training tasks (``new_maps_deviation``) and, for the
factorial fits, the mean deviation of their transfer to ``--n-test`` test tasks on new maps
(one demonstration each); for the flat fits how their tasks stopped.

    PYTHONPATH=. OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/harness_rows.py --n-tasks 30
"""

import argparse
import dataclasses
import json
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.benchmarks.mce import new_maps_deviation, transfer_entry
from factirl_opt.lab.experiments.learner_solvers import factorial_options, flat_features_solver
from factirl_opt.lab.experiments.presets import get_preset
from factirl_opt.lab.experiments.worlds import objectworld_per_task

parser = argparse.ArgumentParser()
parser.add_argument("--n-tasks", type=int, default=30)
parser.add_argument("--n-demos", type=int, default=32)
parser.add_argument("--n-test", type=int, default=100)
parser.add_argument("--objectives", nargs="+", default=["policy-matching", "mce"])
parser.add_argument("--seed", type=int, default=0)
parser.add_argument("--preset", default="objectworld-per-task", help="a preset with a map per task")
args = parser.parse_args()

preset = get_preset(args.preset)
before = dataclasses.replace(preset, flat_stol=0.0, fact_scheme="alternating")
gt = objectworld_per_task(dataclasses.replace(preset, n_test_tasks=max(1, args.n_test)), args.n_tasks, args.n_demos,
                          args.seed)
mdps, features = gt.mdps("train"), list(gt.task_maps["train"].features)
out = {}


class Weights:
    """What new_maps_deviation reads of a model: the learnt weights as D h_i (+ residuals)."""

    def __init__(self, W):
        self.coefficients_, self.dictionary_, self.residuals_ = W, np.eye(W.shape[1]), 0.0


def record(name, model, cpu, transfer):
    dev = fo.deviation(mdps, gt.train_rewards, np.asarray(model.rewards_), planner=preset.planner)
    weights = model.weights_ if hasattr(model, "weights_") else None
    entry = dict(cpu_s=round(cpu, 2), n_evaluations=int(model.n_evaluations_), final_loss=float(np.sum(model.loss_)),
                 mean_train_deviation=float(np.mean(dev)), status=model.status_,
                 mean_new_maps_deviation=new_maps_deviation(Weights(np.asarray(weights)) if weights is not None else model,
                                                            gt, preset))
    if transfer:
        entry.update(transfer_entry(model, gt, preset, args.n_test))
    else:
        entry["reason"] = model.stop_reason_
    out[name] = entry
    print(json.dumps({name: entry}), flush=True)


def timed_fit(model, *fit_args, **fit_kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        c0 = time.process_time()
        model.fit(*fit_args, **fit_kw)
        return time.process_time() - c0


for objective in args.objectives:
    flat_rewards = {}
    for label, p in (("flat_stol 0", before), ("flat_stol preset", preset)):
        flat = fo.GradIRL(beta=p.beta, features=features, max_iter=p.flat_max_iter, gtol=p.flat_gtol, stol=p.flat_stol,
                          solver=flat_features_solver(p, objective), objective=objective, planner=p.planner)
        cpu = timed_fit(flat, mdps, gt.train_demos)
        record(f"{objective}: flat, features ({label})", flat, cpu, transfer=False)
        flat_rewards[label] = flat.rewards_
    for start, p in (("flat_stol 0", before), ("flat_stol 0", preset), ("flat_stol preset", preset)):
        model = fo.FactIRL(rng=np.random.default_rng(args.seed + 1), features=features,
                           **factorial_options(p, p.solvers, objective))
        cpu = timed_fit(model, mdps, gt.train_demos, flat_rewards=flat_rewards[start])
        record(f"{objective}: factorial, features, {model.scheme} (from {start})", model, cpu, transfer=True)
    for p in (before, preset):
        model = fo.FactIRL(rng=np.random.default_rng(args.seed + 2), features=features,
                           **factorial_options(p, p.solvers, objective, init="random"))
        cpu = timed_fit(model, mdps, gt.train_demos)
        record(f"{objective}: factorial, features, random init, {model.scheme}", model, cpu, transfer=True)
print(json.dumps(dict(preset=preset.name, settings=vars(args), fits=out), indent=1))
