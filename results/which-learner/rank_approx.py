"""Approximate leave-one-task-out scores (``learners.approximate_cv``) on one which-learner point, ranked against
the exact K-fold scores and the candidates' test deviations:
python rank_approx.py PRESET N SEED OUT.json [EXACT_ROUTES.json]
python rank_approx.py --rank OUT.json EXACT_ROUTES.json   (the correlations again, of a record already made)
python rank_approx.py --refits PRESET N SEED OUT.json K TASKS   (e.g. ``2 0,5,10``: exact refits without each task)

For the point's adaptive learner (``_point.setup``) and each of its candidates ``(k, lambda)`` (the search's grid,
before any bisection): the candidate is fitted once on all the training tasks from the flat start; its test
deviation is measured with that fit (``_point.test_deviation``'s protocol: the test tasks transferred from one
demonstration); each training task t is transferred from its first demonstration with (a) the one-step
leave-task-out dictionary ``D_(-t)`` of each of ``VARIANTS`` and (b) the full fit's dictionary (``naive``: no
correction, the in-sample baseline),
and scored on its other demonstrations by the search's held-out score (the tempered likelihood,
``adaptive.held_out_nll``). Records per candidate the mean scores, the per-task scores, the test deviation and the CPU time of
the fit, of the step (Jacobians and Newton systems) and of the transfers (``time.process_time``). Spearman
correlations over the candidates: each score against the test deviations, and against the exact K-fold scores of
``EXACT_ROUTES.json`` (a ``routes.py`` record, its first route's table) where given.
"""
import copy
import json
import os
import sys
import time

import numpy as np
from scipy.stats import spearmanr

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import factirl_opt as fo  # noqa: E402
from factirl_opt.learners import adaptive  # noqa: E402
from factirl_opt.learners.approximate_cv import check_approximate_cv, leave_task_out_dictionaries  # noqa: E402
from factirl_opt.learners.fitting import task_objective  # noqa: E402
from factirl_opt.tasks.task_set import task_set  # noqa: E402
from _point import setup  # noqa: E402


#: the steps compared (``leave_task_out_dictionaries``' options): the Newton step with the other tasks' curvature
#: from the inexact fit (the library's default), the same assuming an exact optimum (the step is task t's own
#: gradient only), and the infinitesimal jackknife (every task's curvature, the step task t's gradient); "-damped":
#: with a larger Levenberg-Marquardt damping (relative to the mean curvature)
VARIANTS = {"ns-inexact": dict(curvature="leave-out", inexact=True, damping=1e-3),
            "ns": dict(curvature="leave-out", inexact=False, damping=1e-3),
            "ns-damped": dict(curvature="leave-out", inexact=False, damping=1.0),
            "ij": dict(curvature="full", inexact=False, damping=1e-3),
            "ij-damped": dict(curvature="full", inexact=False, damping=0.1)}  # the library's default


def score(tasks, model, idx):
    """The search's held-out score of tasks ``idx`` (one MDP): transferred from their first demonstration, the
    tempered likelihood of the others (``adaptive.held_out_nll``, as the search's default score)."""
    demos = tasks.demos_per_task
    model.transfer(tasks.mdp, [demos[i][:1] for i in idx])
    return np.array([adaptive.held_out_nll(tasks.mdp, demos[i][1:], model.transfer_rewards_[j], model)
                     for j, i in enumerate(idx)])


def spearman(a, b):
    return float(spearmanr(a, b)[0]) if len(a) > 2 else None


def measure(P):
    """Every candidate's fit, approximate and naive scores and test deviation, recorded as they come."""
    tasks = task_set(P.mdp, P.demos, P.learner.features, P.learner.reward)
    check_approximate_cv(P.learner, tasks)
    n = tasks.n_tasks
    out = {"preset": P.preset.name, "n_tasks": n, "seed": int(sys.argv[3]), "candidates": {}, "spearman": {}}
    for k, lam in P.cands:
        row = {}
        model = adaptive.fixed_learner(P.learner, k, lam)
        t0 = time.process_time()
        model.fit(P.mdp, P.demos, flat_rewards=P.flat.rewards_)
        row["fit_cpu_s"] = time.process_time() - t0
        t0 = time.process_time()
        naive = score(tasks, model, np.arange(n))  # the full fit's dictionary (exact for lambda = 0: no dictionary)
        row["naive_cpu_s"] = time.process_time() - t0
        for name, options in VARIANTS.items():
            if lam == 0.0:
                approx, row[f"{name}_step_cpu_s"], row[f"{name}_transfer_cpu_s"] = naive, 0.0, row["naive_cpu_s"]
            else:
                t0 = time.process_time()
                Ds = leave_task_out_dictionaries(task_objective(tasks, model.beta, model.objective, model.planner),
                                                 tasks.basis, model.dictionary_, model.coefficients_,
                                                 None if np.isinf(lam) else model.residuals_, lam, **options)
                row[f"{name}_step_cpu_s"] = time.process_time() - t0
                row[f"{name}_step_norm_rel"] = [float(np.linalg.norm(D - model.dictionary_)
                                                      / np.linalg.norm(model.dictionary_)) for D in Ds]
                t0 = time.process_time()
                approx = np.empty(n)
                for t in range(n):
                    one = copy.copy(model)
                    one.dictionary_ = Ds[t]
                    approx[t] = score(tasks, one, np.array([t]))[0]
                row[f"{name}_transfer_cpu_s"] = time.process_time() - t0
            row[name], row[f"{name}_tasks"] = float(np.mean(approx)), approx.tolist()
        model.transfer(P.gt.mdps("test"), P.test_demos, features=P.Fte)
        row["test_deviation"] = float(np.mean(fo.deviation(P.gt.mdps("test"), P.gt.rewards("test"),
                                                           model.transfer_rewards_, planner=P.preset.planner)))
        row.update(naive=float(np.mean(naive)), naive_tasks=naive.tolist())
        out["candidates"][f"{k},{lam}"] = row
        print(k, lam, {key: v for key, v in row.items() if not key.endswith(("tasks", "step_norm_rel"))}, flush=True)
        with open(P.out_path, "w") as f:
            json.dump(out, f, indent=1)
    return out


def rank(out, exact_path):
    """The Spearman correlations over the candidates (and the summed CPU times) of a record."""
    keys = list(out["candidates"])
    dev = [out["candidates"][c]["test_deviation"] for c in keys]
    out["spearman"] = {f"{which}/test_deviation": spearman([out["candidates"][c][which] for c in keys], dev)
                       for which in (*VARIANTS, "naive")}
    if exact_path:
        route, record = next(iter(json.load(open(exact_path))["routes"].items()))
        table = record["table"]
        exact = {f"{r['n_primitives']},{float(r['residual_penalty'])}": r["score"] for r in table}
        common = [c for c in keys if c in exact]
        out["exact_route"] = route
        out["spearman"]["exact/test_deviation"] = spearman([exact[c] for c in common],
                                                           [out["candidates"][c]["test_deviation"] for c in common])
        for which in (*VARIANTS, "naive"):
            out["spearman"][f"{which}/exact"] = spearman([out["candidates"][c][which] for c in common],
                                                         [exact[c] for c in common])
        out["spearman"]["n_common"] = len(common)
    out["spearman"]["n"] = len(keys)
    out["cpu_s"] = {key: float(sum(out["candidates"][c][key] for c in keys))
                    for key in ("fit_cpu_s", "naive_cpu_s", *(f"{v}_{part}_cpu_s" for v in VARIANTS
                                                             for part in ("step", "transfer")))}
    return out


def refits(P, k, left):
    """For the candidate ``(k, inf)`` and each task t of ``left``: the exact refit without t from the others' flat
    start (as K-fold refits), the refit without t started from the full fit (the local leave-one-out that a step
    approximates), the full fit (naive) and the default step; the gauge-invariant distance of each dictionary from
    the full fit's (``min_M ||D' - D M|| / ||D'||``) and task t's held-out score with it."""
    tasks = task_set(P.mdp, P.demos, P.learner.features, P.learner.reward)
    n = tasks.n_tasks

    def distance(D, other):
        M = np.linalg.lstsq(D, other, rcond=None)[0]
        return float(np.linalg.norm(other - D @ M) / np.linalg.norm(other))

    model = adaptive.fixed_learner(P.learner, k, np.inf)
    model.fit(P.mdp, P.demos, flat_rewards=P.flat.rewards_)
    D = model.dictionary_
    steps = leave_task_out_dictionaries(task_objective(tasks, model.beta, model.objective, model.planner), tasks.basis,
                                        D, model.coefficients_, tasks=left)
    out = {"preset": P.preset.name, "n_tasks": n, "seed": int(sys.argv[4]), "n_primitives": k, "tasks": {}}
    for j, t in enumerate(left):
        keep = np.setdiff1d(np.arange(n), [t])
        cold = adaptive.fixed_learner(P.learner, k, np.inf)
        cold.fit(P.mdp, adaptive.take_tasks(P.demos, keep), flat_rewards=adaptive.take_tasks(P.flat.rewards_, keep))
        warm = adaptive.fixed_learner(P.learner, k, np.inf, init=(D, model.coefficients_[keep]))
        warm.fit(P.mdp, adaptive.take_tasks(P.demos, keep))
        one = copy.copy(model)
        one.dictionary_ = steps[j]
        row = {name: {"distance": distance(D, m.dictionary_), "score": float(score(tasks, m, np.array([t]))[0])}
               for name, m in (("cold_refit", cold), ("warm_refit", warm), ("naive", model), ("step", one))}
        row["warm_refit"]["status"] = warm.status_
        row["step"]["distance_to_warm"] = distance(steps[j], warm.dictionary_)
        out["tasks"][str(t)] = row
        print(t, row, flush=True)
    return out


if sys.argv[1] == "--refits":
    P = setup(sys.argv[2:6])
    path = P.out_path
    out = refits(P, int(sys.argv[6]), [int(t) for t in sys.argv[7].split(",")])
    with open(path, "w") as f:
        json.dump(out, f, indent=1)
    sys.exit(0)
if sys.argv[1] == "--rank":
    path, exact_path = sys.argv[2], sys.argv[3]
    out = rank(json.load(open(path)), exact_path)
else:
    P = setup(sys.argv[1:5])
    path, exact_path = P.out_path, sys.argv[5] if len(sys.argv) > 5 else None
    out = rank(measure(P), exact_path)
print(out["spearman"], out["cpu_s"], flush=True)
with open(path, "w") as f:
    json.dump(out, f, indent=1)
