"""The ``objectworld`` presets' flat learner on features, test split, under stopping rules side by side.

GradIRL as the harness builds it for ``flat, features`` on the test tasks (the preset's beta,
flat_max_iter, base features, flat_features_solver, planner, and its pinned ``flat_gtol`` and
``flat_stol``), on the preset's one-demonstration test tasks (100), once per variant named on
the command line, in one process, alternating over ``--repeats``. A variant is ``preset`` (the
committed protocol) or comma-separated GradIRL overrides such as ``stol=1e-5`` or
``stol=1e-5,gtol=1e-4``. Prints, per variant: CPU time (fastest repeat), planning evaluations,
the summed loss, the mean deviation (eq. 13), the fit's status and stop reason, and each task's
iterations and status (a histogram, from ``solvers.observe_runs``).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/flat_stopping_rules.py preset stol=1e-5

``--preset objectworld-per-task``: every test task on its own map (the features and the
deviation of each task on its map, as ``flat, features`` of that line-up).

The test split does not depend on the training tasks, so the ground truth is drawn with one
training task. Run with ``PYTHONPATH`` on a checkout of older code (before the harness moved
to ``factirl_opt.lab``) for the ``preset`` variant there: without the per-task records.
"""

import argparse
import collections
import json
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.evaluation import deviation

try:
    from factirl_opt.lab.experiments.presets import get_preset
    from factirl_opt.lab.experiments.worlds import make_ground_truth
except ImportError:  # older code: the harness in factirl_opt.experiments
    from factirl_opt.experiments.presets import get_preset
    from factirl_opt.experiments.worlds import make_ground_truth

try:
    from solvers import observe_runs
except ImportError:  # older code: no per-task records
    observe_runs = None

parser = argparse.ArgumentParser()
parser.add_argument("variants", nargs="+", help="'preset' or GradIRL overrides, e.g. stol=1e-5,gtol=1e-4")
parser.add_argument("--n-test", type=int, default=None, help="test tasks (default: the preset's)")
parser.add_argument("--repeats", type=int, default=1)
parser.add_argument("--seed", type=int, default=0)
parser.add_argument("--out", default=None, help="write the JSON here")
parser.add_argument("--preset", default="objectworld", choices=["objectworld", "objectworld-per-task"])
args = parser.parse_args()
preset = get_preset(args.preset)
gt = make_ground_truth(preset, 1, 1, args.seed)
demos = gt.test_demos if args.n_test is None else gt.test_demos[: args.n_test]
R_true = gt.test_rewards[: len(demos)]
if args.preset == "objectworld":
    mdp, features = gt.mdp, gt.features
else:  # a map per task: its own features
    maps = gt.task_maps["test"]
    mdp, features = list(maps.mdps)[: len(demos)], list(maps.features)[: len(demos)]


def mean_deviation(rewards):
    if args.preset == "objectworld":
        return float(np.mean(deviation(mdp, R_true, np.asarray(rewards), planner=preset.planner)))
    return float(np.mean([deviation(mdp[i], R_true[i:i + 1], np.asarray(rewards[i])[None], planner=preset.planner)[0]
                          for i in range(len(demos))]))

pinned = {f: getattr(preset, "flat_" + f) for f in ("gtol", "stol") if hasattr(preset, "flat_" + f)}


def options(variant):
    kw = dict(beta=preset.beta, features=features, max_iter=preset.flat_max_iter, solver=preset.flat_features_solver,
              objective="policy-matching", planner=preset.planner, **pinned)
    if variant != "preset":
        kw.update({k: float(v) for k, v in (part.split("=") for part in variant.split(","))})
    return kw


out = {}
for _ in range(args.repeats):
    for variant in args.variants:
        runs = []
        model = fo.GradIRL(**options(variant))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c0 = time.process_time()
            if observe_runs is None:
                model.fit(mdp, demos)
            else:
                with observe_runs(lambda solver, problem, result, **info: runs.append(result)):
                    model.fit(mdp, demos)
            cpu = time.process_time() - c0
        entry = out.setdefault(variant, dict(cpus_s=[]))
        entry["cpus_s"].append(round(cpu, 2))
        entry.update(options={k: v for k, v in options(variant).items() if k in ("gtol", "stol", "tol")},
                     cpu_s=min(entry["cpus_s"]), n_evaluations=int(model.n_evaluations_), n_iter=int(model.n_iter_),
                     loss=float(np.sum(model.loss_)), mean_deviation=mean_deviation(model.rewards_), status=model.status_,
                     reason=model.stop_reason_)
        if runs and getattr(runs[-1], "row_iterations", None) is not None:
            it = runs[-1].row_iterations
            entry.update(task_iterations_mean=float(np.mean(it)), task_iterations_max=int(np.max(it)),
                         task_iterations_by_ten=dict(sorted(collections.Counter((it // 10 * 10).tolist()).items())),
                         task_status=dict(collections.Counter(runs[-1].row_status.tolist())))
        print(variant, json.dumps(entry), flush=True)
report = json.dumps(dict(preset=args.preset, split="test", n_tasks=len(demos), seed=args.seed, fits=out), indent=1)
print(report)
if args.out:
    with open(args.out + ".tmp", "w") as f:
        f.write(report + "\n")
    import os

    os.replace(args.out + ".tmp", args.out)
