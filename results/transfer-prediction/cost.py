"""Cost of ``transfer_posterior_`` and of one request with a dictionary ensemble, side by side with ``transfer``.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/cost.py SEED [REPEATS]

Prints JSON. The draw of ``calibration.py`` (the paper's grid, fast preset, 60 training tasks x
10 demonstrations, 30 one-demonstration test tasks, ``transfer_stol=1e-3``), one fitted model
and, as ``fit`` computes them, 8 bootstrap and 5 fold dictionaries; ``bootstrap4`` is the
first 4 of the 8 (the members are drawn independently). For each of ``B0`` (the conditional
posterior), ``bootstrap4``, ``bootstrap8`` and ``folds5``, CPU seconds (``time.process_time``,
median of REPEATS), in one process:

- ``transfer`` of the 30 tasks and ``transfer_posterior_`` after it, their ratio (transfers);
- ``each_member``: the same posterior with the members one at a time
  (``member_posteriors(..., batched=False)``, the route before the batched one), its ratio, and the
  largest relative differences of the members' means and covariances between the two routes;
- ``solves``: the task systems the planner solved (a ``CountingPlanner`` as the model's
  planner, ``n_forward``) during ``transfer`` and during ``transfer_posterior_``;
- ``request``: per test task (the first 10), ``transfer`` of that task alone, then
  ``transfer_posterior_`` + ``request_starts(..., 1)`` with ``marginal=False`` and, after the same
  transfer again, with ``marginal=True``; the ratio of the sums over the tasks; and the one-task
  posterior alone by either route (``posterior_over_transfer``, ``each_member_posterior_over_transfer``).

And ``batching``: the conditional posterior of the 30 tasks computed 9 times one after the
other against once on the 30 tasks repeated 9 times (``repeated_problem``, 270 rows, one planner
call per Newton step for all).
"""

import json
import statistics
import sys
import time

import numpy as np

import factirl_opt as fo
from factirl_opt.learners.dictionary_ensemble import dictionary_ensemble
from factirl_opt.learners.noise_levels import noise_reference
from factirl_opt.learners.posterior import laplace_posteriors, member_posteriors
from factirl_opt.learners.transfer import coefficient_prior
from factirl_opt.learners.transfer_likelihood import repeated_problem, transfer_problem
from factirl_opt.planning import CountingPlanner, get_planner

from calibration import ENSEMBLES, draw

CONFIGS = {"B0": (0, None), "bootstrap4": (4, "bootstrap8"), "bootstrap8": (8, "bootstrap8"), "folds5": (5, "folds5")}


def _set_ensemble(model, ensembles, B, kind):
    if B == 0:
        model.dictionary_ensemble_ = None
        return
    Ds, ms, Ps = ensembles[kind]
    model.dictionary_ensemble_, model.ensemble_prior_means_, model.ensemble_prior_precisions_ = Ds[:B], ms[:B], Ps[:B]


def _each_member(model, problem):
    """The posterior with the members one at a time (the route before the batched one)."""
    start = np.asarray(model.transfer_coefficients_, dtype=np.float64)
    reference = noise_reference(model)
    posts = laplace_posteriors(problem, coefficient_prior(model.coefficients_), start, noise_reference=reference)
    return member_posteriors(model, problem, posts, reference, batched=False)


def _max_differences(a, b):
    dm = dc = 0.0
    for p, q in zip(a, b):
        for x, y in zip((p, *p.members), (q, *q.members)):
            dm = max(dm, float(np.max(np.abs(x.mean - y.mean)) / np.max(np.abs(y.mean))))
            dc = max(dc, float(np.max(np.abs(x.covariance - y.covariance)) / np.max(np.abs(y.covariance))))
    return dm, dc


def _solves(model, gt, test):
    """Task systems solved during one transfer and during its posterior (a counting planner as the model's)."""
    counting = CountingPlanner(get_planner(gt.mdp))
    execution = model.execution
    model.set_params(execution=fo.Execution(planner=counting))
    try:
        model.transfer(gt.mdp, test)
        transfer = counting.n_forward
        model.transfer_posterior_
        posterior = counting.n_forward - transfer
    finally:
        model.set_params(execution=execution)
    return {"transfer": int(transfer), "posterior": int(posterior)}


def _request_cost(model, gt, n, repeats):
    transfer, plain, marginal, alone, each = (np.zeros(n) for _ in range(5))
    for i in range(n):
        demos = [np.asarray(gt.test_demos[i])]
        problem = transfer_problem(model, gt.mdp, demos)
        times = {key: [] for key in ("transfer", "plain", "marginal", "alone", "each")}
        for _ in range(repeats):
            t = time.process_time()
            model.transfer(gt.mdp, demos)
            times["transfer"].append(time.process_time() - t)
            t = time.process_time()
            model.transfer_posterior_
            model.request_starts(gt.mdp, demos, 1)
            times["plain"].append(time.process_time() - t)
            model.transfer(gt.mdp, demos)
            t = time.process_time()
            model.transfer_posterior_
            model.request_starts(gt.mdp, demos, 1, marginal=True)
            times["marginal"].append(time.process_time() - t)
            model.transfer(gt.mdp, demos)
            t = time.process_time()
            model.transfer_posterior_
            times["alone"].append(time.process_time() - t)
            t = time.process_time()
            _each_member(model, problem)
            times["each"].append(time.process_time() - t)
        for arr, key in zip((transfer, plain, marginal, alone, each), times):
            arr[i] = statistics.median(times[key])
    T = transfer.sum()
    return {"n_tasks": n, "transfer_cpu_s": float(T), "request_cpu_s": float(plain.sum()),
            "request_marginal_cpu_s": float(marginal.sum()), "request_over_transfer": float(plain.sum() / T),
            "request_marginal_over_transfer": float(marginal.sum() / T),
            "posterior_over_transfer": float(alone.sum() / T), "each_member_posterior_over_transfer": float(each.sum() / T)}


def _batching(model, gt, test, repeats, copies=9):
    model.transfer(gt.mdp, test)
    problem = transfer_problem(model, gt.mdp, test)
    prior = coefficient_prior(model.coefficients_)
    start = np.asarray(model.transfer_coefficients_, dtype=np.float64)
    seq, bat = [], []
    for _ in range(repeats):
        t = time.process_time()
        for _ in range(copies):
            laplace_posteriors(problem, prior, start)
        seq.append(time.process_time() - t)
        stacked = repeated_problem(model, problem, [problem.dictionary] * copies)
        t = time.process_time()
        laplace_posteriors(stacked, prior, np.tile(start, (copies, 1)))
        bat.append(time.process_time() - t)
    return {"copies": copies, "sequential_cpu_s": statistics.median(seq), "batched_cpu_s": statistics.median(bat),
            "batched_over_sequential": statistics.median(bat) / statistics.median(seq)}


def main(seed, repeats=3, n_request_tasks=10):
    gt, test, true, model = draw(seed)
    t = time.process_time()
    model.fit(gt.mdp, gt.train_demos)
    out = {"seed": seed, "repeats": repeats, "fit_cpu_s": time.process_time() - t}
    ensembles = {}
    for name, (B, how) in ENSEMBLES.items():
        t = time.process_time()
        ensembles[name] = dictionary_ensemble(model, gt.mdp, gt.train_demos, B, how, rng=model.rng)
        out[f"{name}_fit_cpu_s"] = time.process_time() - t
    rows = {}
    for name, (B, kind) in CONFIGS.items():
        _set_ensemble(model, ensembles, B, kind)
        model.transfer(gt.mdp, test)
        problem = transfer_problem(model, gt.mdp, test)
        tr, po, each = [], [], []
        for _ in range(repeats):
            t = time.process_time()
            model.transfer(gt.mdp, test)
            tr.append(time.process_time() - t)
            t = time.process_time()
            fast = model.transfer_posterior_
            po.append(time.process_time() - t)
            t = time.process_time()
            slow = _each_member(model, problem)
            each.append(time.process_time() - t)
        dm, dc = _max_differences(fast, slow)
        transfer = statistics.median(tr)
        rows[name] = {"transfer_cpu_s": transfer, "posterior_cpu_s": statistics.median(po),
                      "posterior_over_transfer": statistics.median(po) / transfer,
                      "each_member": {"posterior_cpu_s": statistics.median(each),
                                      "posterior_over_transfer": statistics.median(each) / transfer,
                                      "max_rel_diff_mean": dm, "max_rel_diff_covariance": dc},
                      "solves": _solves(model, gt, test),
                      "request": _request_cost(model, gt, n_request_tasks, repeats)}
    out["rows"] = rows
    _set_ensemble(model, ensembles, 0, None)
    out["batching"] = _batching(model, gt, test, repeats)
    return out


if __name__ == "__main__":
    print(json.dumps(main(*(int(a) for a in sys.argv[1:])), indent=2))
