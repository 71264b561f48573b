"""Where the CPU time of one ``bench mce`` FactIRL fit goes: flat start, H-steps, D-steps, the rest.

Runs the benchmark's fit (:func:`factirl_opt.lab.benchmarks.mce.fit_once`: the preset's budgets and
solvers, ELIRL's protocol) for one objective and flat-start solver, with every step-solver run
timed by category (:func:`solvers.observe_runs`, the CPU time of the thread running it): the flat start (the separable run of the flat learner), H-step runs (one
row per task) and D-step runs (one row, the dictionary). For each: runs, CPU time, planning
evaluations, iterations (an evaluation beyond one per iteration is a line-search or
rejected trial). The rest of the fit (outer-loop evaluations of the loss and gradient, PCA
start and its shrinking) is the difference to the total.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/profile_fit.py --n-tasks 10 \\
        --objective mce --flat-solver lbfgs [--h-solver newton]
"""

import argparse
import json
import warnings

import solvers
from factirl_opt.lab.benchmarks import mce as bench
from factirl_opt.lab.experiments.worlds import objectworld_per_task

parser = argparse.ArgumentParser()
parser.add_argument("--n-tasks", type=int, default=10)
parser.add_argument("--objective", default="mce")
parser.add_argument("--flat-solver", default="default")
parser.add_argument("--h-solver", default="default")
parser.add_argument("--seed", type=int, default=0)
args = parser.parse_args()

settings = dict(bench.DEFAULTS, n_tasks=args.n_tasks)
preset = bench.benchmark_preset(settings)
gt = objectworld_per_task(preset, args.n_tasks, settings["n_demos"], args.seed)

parts = {k: dict(runs=0, cpu_s=0.0, n_evaluations=0, iterations=0, solvers=set()) for k in ("flat start", "H-steps", "D-steps")}


def record(solver, problem, result, *, separable, cpu_seconds):
    kind = "flat start" if separable else "D-steps" if problem.n_rows == 1 else "H-steps"
    part = parts[kind]
    part["runs"] += 1
    part["cpu_s"] += cpu_seconds
    part["n_evaluations"] += int(result.n_evaluations)
    part["iterations"] += int(result.iterations)
    part["solvers"].add(solver.name)


with bench.limit_blas_threads(1), warnings.catch_warnings(), solvers.observe_runs(record):
    warnings.simplefilter("ignore")
    model, wall, cpu, planner = bench.fit_once(preset, gt, args.objective, args.seed + 1, args.flat_solver,
                                               args.h_solver)
for part in parts.values():
    part["solvers"] = sorted(part["solvers"])
rest = cpu - sum(p["cpu_s"] for p in parts.values())
out = dict(objective=args.objective, flat_solver=args.flat_solver, h_solver=args.h_solver, n_tasks=args.n_tasks, cpu_s=cpu,
           n_evaluations=int(model.n_evaluations_), n_iter=int(model.n_iter_), status=model.status_,
           parts=parts, rest_cpu_s=rest, counts=planner.counts(),
           loss_history=[float(v) for v in model.loss_history_],
           train_deviation=bench.fit_entry(model, wall, planner, gt, preset)["mean_train_deviation"])
print(json.dumps(out, indent=1))
