"""The per-task flat learner on features of the ``objectworld`` preset's test split, side by side.

GradIRL (``flat, features``: the preset's beta, flat_max_iter, base features and planner) on the
preset's one-demonstration test tasks (100), fitted once per solver named on the command line
in one process, alternating over ``--repeats``; prints CPU time (fastest repeat), planning
evaluations, the summed loss, the mean deviation (eq. 13) and the tasks' statuses.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/flat_test_tasks.py lbfgs newton
"""

import argparse
import json
import time
import warnings

import numpy as np

from factirl_opt import GradIRL
from factirl_opt.evaluation import deviation
from factirl_opt.lab.experiments.presets import get_preset
from factirl_opt.lab.experiments.worlds import make_ground_truth

parser = argparse.ArgumentParser()
parser.add_argument("solvers", nargs="+", help="solver names; options as name:key=value;key=value")
parser.add_argument("--objective", default="policy-matching")
parser.add_argument("--n-test", type=int, default=None, help="test tasks (default: the preset's)")
parser.add_argument("--repeats", type=int, default=1)
parser.add_argument("--seed", type=int, default=0)
args = parser.parse_args()
preset = get_preset("objectworld")
gt = make_ground_truth(preset, 1, 1, args.seed)  # the test split does not depend on the training tasks
demos = gt.test_demos if args.n_test is None else gt.test_demos[: args.n_test]
R_true = gt.test_rewards[: len(demos)]
out = {}
for _ in range(args.repeats):
    for spec in args.solvers:
        name, _, opt = spec.partition(":")
        options = {k: float(v) if "." in v or "e" in v else int(v) for k, v in (kv.split("=") for kv in opt.split(";") if kv)}
        model = GradIRL(beta=preset.beta, features=gt.features, max_iter=preset.flat_max_iter, solver=name,
                        solver_options=options or None, objective=args.objective, planner=preset.planner)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            c0 = time.process_time()
            model.fit(gt.mdp, demos)
            cpu = time.process_time() - c0
        dev = deviation(gt.mdp, R_true, np.asarray(model.rewards_), planner=preset.planner)
        entry = out.setdefault(spec, dict(cpus_s=[]))
        entry["cpus_s"].append(cpu)
        entry.update(cpu_s=min(entry["cpus_s"]), n_evaluations=int(model.n_evaluations_), loss=float(np.sum(model.loss_)),
                     mean_deviation=float(np.mean(dev)), status=model.status_, reason=model.stop_reason_)
        print(spec, json.dumps(entry), flush=True)
print(json.dumps(dict(objective=args.objective, n_tasks=len(demos), fits=out), indent=1))
