"""Two changes of the posterior's likelihood measured for calibration on the paper's grid (not adopted).

Usage: OMP_NUM_THREADS=1 python results/active/calibration_variants.py SEED [N_SAMPLES]

Prints JSON. The model is ``bench active``'s (FactIRL on 100 training tasks x 10 demonstrations,
the ``fast`` preset's solvers); each of the 100 test tasks is transferred from its one
demonstration, and for each posterior below: the coverage of the 90% regret bound
(``sample_regrets``) and Spearman(expected regret, deviation of the posterior mean).

- ``count``: ``transfer_posterior_`` as the library builds it (every demonstrated pair counts);
- ``once``: each distinct demonstrated (state, action) pair counted once, ``N`` the number of
  distinct pairs (a deterministic expert repeats its action in a state it revisits, so the
  repeat tells nothing new): the posterior of the task's demonstrations reduced to one
  one-step episode per distinct pair;
- ``once+fit``: ``once`` with a per-task noise level estimated from the fit, as ``s^2 = RSS/(n - d)``
  in regression: ``sigma_i^2 = sigma0_i^2 * shat_i^2 / shat_train^2``, ``shat_i^2 = RSS_i / (n_i (A - 1) - d)``
  (``RSS_i`` eq. (5)'s sum of squares over the task's ``n_i`` distinct states at the MAP),
  ``shat_train^2`` the same pooled over the training tasks at their learnt coefficients, and
  ``sigma0_i^2`` the library's multinomial level; so a demonstration the dictionary explains worse
  than it explains its training tasks widens its posterior.
"""

import json
import sys

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from factirl_opt.learners.posterior import (LaplacePosterior, coefficient_prior, demonstration_curvature,
                                            laplace_posteriors, transfer_problem)
from calibration_diagnostics import transferred_model  # this directory is on sys.path when run as a script


def distinct_pairs(demos_per_task):
    """Each task's distinct (state, action) pairs as one-step episodes (m_i, 1, 2)."""
    return [np.unique(np.asarray(d).reshape(-1, 2), axis=0)[:, None, :] for d in demos_per_task]


def scores(gt, posts, n_samples, seed):
    reg = np.array([p.sample_regrets(n_samples, np.random.default_rng([seed, i])) for i, p in enumerate(posts)])
    dev = np.asarray(fo.deviation(gt.mdp, gt.test_rewards, np.stack([p.mean_rewards() for p in posts])))
    return {"coverage_90": float(np.mean(dev <= np.quantile(reg, 0.9, axis=1))),
            "spearman": float(spearmanr(reg.mean(axis=1), dev).correlation),
            "mean_expected_regret": float(reg.mean()), "mean_deviation_map": float(dev.mean())}


def noise_level(problem, x, n_distinct, n_actions):
    """``RSS / (n (A - 1) - d)`` per task at ``x`` (eq. (5) on the distinct pairs: ``J = RSS / n``)."""
    loss, _, _ = demonstration_curvature(problem, x)
    d = x.shape[1]
    return loss * n_distinct, np.maximum(n_distinct * (n_actions - 1) - d, 1)


def main(seed, n_samples=200):
    gt, model = transferred_model(seed)
    out = {"seed": seed, "n_samples": n_samples, "count": scores(gt, model.transfer_posterior_, n_samples, seed)}
    prior = coefficient_prior(model.coefficients_)
    once = distinct_pairs(gt.test_demos)
    problem = transfer_problem(model, gt.mdp, once)
    posts = laplace_posteriors(problem, prior, np.asarray(model.transfer_coefficients_))
    out["once"] = scores(gt, posts, n_samples, seed)
    X = np.stack([p.mean for p in posts])
    n = problem.n_pairs
    rss, dof = noise_level(problem, X, n, gt.mdp.n_actions)
    train = distinct_pairs(gt.train_demos)
    tp = transfer_problem(model, gt.mdp, train)
    rss_t, dof_t = noise_level(tp, np.asarray(model.coefficients_), tp.n_pairs, gt.mdp.n_actions)
    pooled = rss_t.sum() / dof_t.sum()
    _, _, G = demonstration_curvature(problem, X)
    fitted = []
    for i, p in enumerate(posts):
        sigma0 = n[i] / (2.0 * p.scaling)
        s = n[i] / (2.0 * sigma0 * (rss[i] / dof[i]) / pooled)
        C = np.linalg.inv(s * G[i] + prior[1])
        fitted.append(LaplacePosterior(p.mean, 0.5 * (C + C.T), p.dictionary, p.features, p.mdp, float(s), float(n[i])))
    out["once+fit"] = scores(gt, fitted, n_samples, seed)
    out["once+fit"]["median_noise_ratio"] = float(np.median(rss / dof / pooled))
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), *(int(a) for a in sys.argv[2:])), indent=2))
