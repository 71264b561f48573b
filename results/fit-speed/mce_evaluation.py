"""CPU per MCE evaluation on per-task Objectworld maps with walls, along L-BFGS paths, on any code.

The setting of ``per_task_maps.py`` (16 tasks, each on its own 24x24 map with 30 blocked cells,
24 demonstrations of 16 steps, the ``objectworld-per-task`` preset's colours, density, dynamics,
discount and beta), without the learner: each task's ``MCEObjective`` (one task, its own MDP, as
a map-per-task fit plans it) minimised over the map's feature weights ``w`` (``R = F w``) by
scipy's L-BFGS-B for ``--max-iter`` iterations from ``w = 0``, every loss-and-gradient call
timed (``time.process_time``). Both objectives (``--objectives``), so that the ratio is the
per-evaluation cost of MCE against policy matching. The path depends only on the losses and
gradients, so codes that compute them bit for bit alike take the same path: the record
(``final_losses``, a digest of them) shows it.

    PYTHONPATH=/path/to/code OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 \\
        python results/fit-speed/mce_evaluation.py --label NAME > out.json

Prints one JSON record: per objective the CPU seconds of all evaluations, their number, the
CPU per evaluation in milliseconds, the summed final losses and a digest of every task's final
loss (hex of the float64 values), and ``cpu_per_evaluation_ratio_mce_over_pm``.
"""

import argparse
import hashlib
import json
import time

import numpy as np
from scipy.optimize import minimize

import factirl_opt as fo
from factirl_opt.objectives import get_objective

from walled_maps import add_arguments, draw

parser = argparse.ArgumentParser()
add_arguments(parser)
parser.add_argument("--max-iter", type=int, default=60, help="L-BFGS-B iterations per task")
parser.add_argument("--objectives", nargs="+", default=["policy-matching", "mce"])
parser.add_argument("--repeats", type=int, default=1, help="each objective's paths this many times, alternating; fastest kept")
args = parser.parse_args()

preset, maps, mdps, R_true, demos = draw(args)


def features(i):
    """Task i's features as an (S*A, p) array (state features repeated over the actions)."""
    F = np.asarray(maps.features[i], dtype=np.float64)
    S, A = mdps[i].n_states, mdps[i].n_actions
    return np.repeat(F, A, axis=0) if F.shape[0] == S else F.reshape(S * A, -1)


def run(objective):
    """Every task's L-BFGS-B path: CPU of the loss-and-gradient calls, their number, final losses."""
    cls = get_objective(objective)
    cpu, calls, finals = 0.0, 0, []
    for i, mdp in enumerate(mdps):
        mu, pi_hat = fo.empirical_statistics(mdp, [demos[i]])
        obj = cls(mdp, mu, pi_hat, preset.beta, planner=preset.planner)
        F = features(i)
        S, A = mdp.n_states, mdp.n_actions

        def fun(w):
            nonlocal cpu, calls
            c0 = time.process_time()
            loss, grad = obj.loss_and_grad((F @ w).reshape(1, S, A))
            cpu += time.process_time() - c0
            calls += 1
            return float(loss[0]), F.T @ grad.reshape(-1)

        res = minimize(fun, np.zeros(F.shape[1]), jac=True, method="L-BFGS-B",
                       options=dict(maxiter=args.max_iter, gtol=0.0, ftol=0.0))
        finals.append(float(res.fun))
    finals = np.array(finals)
    return dict(cpu_s=cpu, n_evaluations=calls, cpu_per_evaluation_ms=1e3 * cpu / calls,
                final_loss=float(finals.sum()), final_losses_digest=hashlib.sha256(finals.tobytes()).hexdigest()[:12])


out = {}
for _ in range(args.repeats):
    for objective in args.objectives:
        entry = run(objective)
        best = out.setdefault(objective, dict(cpus_s=[]))
        best["cpus_s"].append(round(entry["cpu_s"], 3))
        if entry["cpu_s"] <= best.get("cpu_s", np.inf):
            best.update(entry)
ratio = (out["mce"]["cpu_per_evaluation_ms"] / out["policy-matching"]["cpu_per_evaluation_ms"]
         if {"mce", "policy-matching"} <= set(out) else None)
print(json.dumps(dict(label=args.label, code=fo.__file__, settings=vars(args), fits=out,
                      cpu_per_evaluation_ratio_mce_over_pm=ratio), indent=1))
