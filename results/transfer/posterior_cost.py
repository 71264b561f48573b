"""The posterior and the requests of the README's ``"auto"`` model against one transfer, side by side in one process.

``python results/transfer/posterior_cost.py OUT.json [REPEATS]``: the README's grid
(:func:`factirl_opt.lab.benchmarks.auto_cost.readme_grid`, seed 0: 30 training tasks x 10
demonstrations, 10 new tasks from one demonstration each), ``FactIRL(n_primitives="auto",
residual_penalty="auto")`` fitted on it (its choice: k and lambda in the record), then, REPEATS
times (default 2), in this order, CPU time (time.process_time) of: ``transfer`` (today's,
``transfer_stol=0``), ``transfer`` with the saturation rule (``transfer_stol=TRANSFER_STOL``),
``transfer_posterior_`` after the first (the low-rank posterior, the default), the dense posterior
(``laplace_posteriors(..., lowrank=False)``, as before), ``request_starts(n_requests=3)`` (the
posterior cached), and ``information_gains`` of every task over its parameters' determinants (as
before) for the ratio. The low-rank and dense posteriors, and the two gains, are compared (largest
absolute differences in the record).
"""
import json
import sys
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.benchmarks.auto_cost import readme_grid
from factirl_opt.learners.active import information_gains, start_occupancy, state_information
from factirl_opt.learners.posterior import coefficient_prior, laplace_posteriors, transfer_problem
from factirl_opt.learners.transfer import TRANSFER_STOL


def cpu(fn):
    t0 = time.process_time()
    out = fn()
    return out, time.process_time() - t0


def dense_gains(post, beta, length):
    """``log det(Lambda + H_s) - log det(Lambda)`` of every start over the posterior's parameters (before)."""
    pl, info, pi = state_information(post, "policy-matching", beta)
    occ = start_occupancy(pl, pi, np.arange(post.mdp.n_states), length)
    Lam = np.linalg.inv(post.covariance)
    H = np.einsum("cy,yde->cde", occ, info)
    return np.linalg.slogdet(Lam[None] + H)[1] - np.linalg.slogdet(Lam)[1]


def main(out_path, repeats=2):
    g = readme_grid(0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        flat = fo.GradIRL(beta=5.0).fit(g.mdp, g.train_demos)
        model, fit_s = cpu(lambda: fo.FactIRL(n_primitives="auto", residual_penalty="auto", init="pca").fit(
            g.mdp, g.train_demos, flat_rewards=flat.rewards_))
    record = {"k": int(model.n_primitives_), "lambda": float(model.residual_penalty_), "fit_cpu": fit_s, "runs": []}
    for _ in range(repeats):
        run = {}
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.set_params(transfer_stol=TRANSFER_STOL)
            _, run["transfer_saturation"] = cpu(lambda: model.transfer(g.mdp, g.test_demos))
            run["saturation_status"] = model.transfer_status_
            run["saturation_deviation"] = float(fo.deviation(g.mdp, g.test_rewards, model.transfer_rewards_).mean())
            model.set_params(transfer_stol=0.0)
            _, run["transfer"] = cpu(lambda: model.transfer(g.mdp, g.test_demos))
        run["transfer_status"] = model.transfer_status_
        run["transfer_deviation"] = float(fo.deviation(g.mdp, g.test_rewards, model.transfer_rewards_).mean())
        run["warnings"] = sorted({type(w.message).__name__ for w in caught})
        posts, run["posterior"] = cpu(lambda: model.transfer_posterior_)
        problem = transfer_problem(model, g.mdp, g.test_demos)
        start = np.concatenate([model.transfer_coefficients_, model.transfer_residuals_], axis=1)
        dense, run["posterior_dense"] = cpu(lambda: laplace_posteriors(problem, coefficient_prior(model.coefficients_),
                                                                      start, lowrank=False))
        run["posterior_mean_max_diff"] = float(max(np.abs(a.mean - b.mean).max() for a, b in zip(posts, dense)))
        run["posterior_covariance_max_diff"] = float(max(np.abs(a.covariance - b.covariance).max()
                                                         for a, b in zip(posts, dense)))
        run["covariance_max"] = float(max(np.abs(a.covariance).max() for a in dense))
        _, run["request_starts"] = cpu(lambda: model.request_starts(g.mdp, g.test_demos, 3))
        gains, run["gains"] = cpu(lambda: [information_gains(p, "policy-matching", model.beta, np.arange(g.mdp.n_states), 10)
                                           for p in posts])
        before, run["gains_dense"] = cpu(lambda: [dense_gains(p, model.beta, 10) for p in posts])
        run["gains_max_diff"] = float(max(np.abs(a - b).max() for a, b in zip(gains, before)))
        run["same_ranking"] = all(np.array_equal(np.argsort(-a, kind="stable"), np.argsort(-b, kind="stable"))
                                  for a, b in zip(gains, before))
        for key in ("posterior", "posterior_dense", "request_starts"):
            run[f"{key}_over_transfer"] = run[key] / run["transfer"]
            run[f"{key}_over_saturation_transfer"] = run[key] / run["transfer_saturation"]
        print(json.dumps(run), flush=True)
        record["runs"].append(run)
        model.transfer(g.mdp, g.test_demos[::-1])  # another task list: the next repeat builds its posterior again
    with open(out_path, "w") as f:
        json.dump(record, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 2)
