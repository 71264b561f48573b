"""FactIRL with policy matching and MCE on Objectworld maps with walls, a map per task, on any code.

The issue's "per-task maps of that size": ``--n-tasks`` tasks (16), each on its own
``--size`` x ``--size`` map (24) with ``--n-blocked`` blocked cells (walls, 30), ``--n-demos``
demonstrations (24) of ``--length`` steps (16), k = 5 (the ``objectworld-per-task`` preset's
colours, density, dynamics and discount). For each objective, one ``FactIRL.fit`` from scratch
(``init="pca"``: its own flat start) with the ``objectworld-per-task`` preset's budgets and
solvers as the code at hand builds them (``factorial_options``), and where the code has them the
preset's flat-start solver and scheme as ``bench mce`` takes them (``--config preset``) or
FactIRL's own Armijo start and the alternation (``--config armijo-alternating``, the fit before
the preset took the joint scheme). Written to run unchanged on older code (commit cf6a37f: the
harness in ``factirl_opt.experiments``, FactIRL's flat start Armijo, the alternation only):

    git worktree add /work/wl/cf6 cf6a37f
    PYTHONPATH=/work/wl/cf6 OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/per_task_maps.py --label cf6a37f
    PYTHONPATH=. OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/per_task_maps.py --label HEAD \
        --configs preset armijo-alternating

Prints one JSON line per fit as it ends, then the whole record: per objective and
configuration the CPU time of the fit (fastest of ``--repeats``, alternating), evaluations, outer
iterations, status, final loss and the mean train deviation (eq. 13, each task on its own map),
plus a digest of the demonstrations (the same draw on every code), and ``cpu_ratio_mce_over_pm``
per configuration.
"""

import argparse
import hashlib
import json
import time
import warnings

import numpy as np

import factirl_opt as fo

from walled_maps import add_arguments, draw

try:
    from factirl_opt.lab.experiments.learner_solvers import factorial_options
except ImportError:  # older code: the harness in factirl_opt.experiments
    from factirl_opt.experiments.learner_solvers import factorial_options
try:
    from factirl_opt.lab.benchmarks.mce import resolved_run
except ImportError:  # older code: FactIRL's own flat start, the alternation
    resolved_run = None

parser = argparse.ArgumentParser()
add_arguments(parser)
parser.add_argument("--objectives", nargs="+", default=["policy-matching", "mce"])
parser.add_argument("--configs", nargs="+", default=["preset"], choices=["preset", "armijo-alternating"],
                    help="on code with bench mce's resolved_run; older code runs its own FactIRL")
parser.add_argument("--repeats", type=int, default=1)
args = parser.parse_args()

preset, maps, mdps, R, demos = draw(args)
digest = hashlib.sha256(np.ascontiguousarray(np.stack(demos)).tobytes()).hexdigest()[:12]
configs = args.configs if resolved_run is not None else ["own"]


def options(objective, config):
    kw = factorial_options(preset, preset.solvers, objective)
    if config == "preset":
        kw["flat_solver"], kw["scheme"] = resolved_run(preset, objective)
    elif config == "armijo-alternating":
        kw["flat_solver"], kw["scheme"] = "armijo", "alternating"
    return kw


fits = {}
for _ in range(args.repeats):
    for config in configs:
        for objective in args.objectives:
            kw = options(objective, config)
            model = fo.FactIRL(rng=np.random.default_rng(args.seed + 1), features=list(maps.features), **kw)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                c0 = time.process_time()
                model.fit(mdps, demos)
                cpu = time.process_time() - c0
            dev = fo.deviation(mdps, R, np.asarray(model.rewards_), planner=preset.planner)
            entry = fits.setdefault(f"{objective}, {config}", dict(cpus_s=[]))
            entry["cpus_s"].append(round(cpu, 2))
            entry.update(cpu_s=min(entry["cpus_s"]), n_evaluations=int(model.n_evaluations_), n_iter=int(model.n_iter_),
                         status=model.status_, final_loss=float(np.sum(model.loss_)),
                         mean_train_deviation=float(np.mean(dev)),
                         flat_solver=str(kw.get("flat_solver", "armijo")), scheme=kw.get("scheme", "alternating"))
            print(json.dumps({f"{objective}, {config}": entry}), flush=True)
ratios = {config: fits[f"mce, {config}"]["cpu_s"] / fits[f"policy-matching, {config}"]["cpu_s"] for config in configs
          if f"mce, {config}" in fits and f"policy-matching, {config}" in fits}
print(json.dumps(dict(label=args.label, code=fo.__file__, settings=vars(args), demos_digest=digest, fits=fits,
                      cpu_ratio_mce_over_pm=ratios), indent=1))
