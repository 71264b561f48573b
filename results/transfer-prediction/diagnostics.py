"""What the one-demonstration deviations on the grid follow (one seed): observable and unobservable predictors.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/diagnostics.py SEED

Prints JSON: on calibration.py's draw (60 training tasks, 30 test tasks from one demonstration,
``transfer_stol=1e-3``), Spearman of the deviation of the posterior mean with: the true reward's
norm and its part off the span of the learnt dictionary (not observable: a greedy demonstration
does not reveal the reward's scale), and observable quantities: the task's misfit noise level at
its MAP, minus the number of distinct states its demonstration visits, the MAP reward's norm, the
trace of the conditional covariance, and the spread of the 8 bootstrap dictionaries' MAP rewards
around the conditional one (mean distance, and the mean deviation between them).
"""

import json
import sys

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from calibration import draw  # this folder's shared draw
from factirl_opt.learners.dictionary_ensemble import dictionary_ensemble
from factirl_opt.learners.noise_levels import misfit_noise_levels
from factirl_opt.learners.transfer_likelihood import demonstration_curvature, transfer_problem


def main(seed, n_train=60, n_test=30):
    gt, test, true, model = draw(seed, n_train, n_test)
    model.fit(gt.mdp, gt.train_demos)
    model.transfer(gt.mdp, test)
    posts = model.transfer_posterior_
    M = np.stack([p.mean_rewards() for p in posts])
    dev = np.asarray(fo.deviation(gt.mdp, true, M))
    problem = transfer_problem(model, gt.mdp, test)
    J = demonstration_curvature(problem, np.stack([p.mean for p in posts]))[0]
    visited = np.array([np.unique(np.asarray(d).reshape(-1, 2)[:, 0]).size for d in test])
    k = model.n_primitives_
    level = misfit_noise_levels(J, problem.n_pairs, visited, gt.mdp.n_actions, k)
    D, Rt = model.dictionary_, true.reshape(len(test), -1)
    off = Rt - (D @ np.linalg.lstsq(D, Rt.T, rcond=None)[0]).T
    out = {"seed": seed}

    def rho(name, v):
        out[name] = float(spearmanr(v, dev).correlation)

    rho("true_norm", np.linalg.norm(Rt, axis=1))
    rho("true_off_span_norm", np.linalg.norm(off, axis=1))
    rho("misfit_level", level)
    rho("minus_distinct_states", -visited)
    rho("map_norm", np.linalg.norm(M.reshape(len(test), -1), axis=1))
    rho("trace_covariance", [np.trace(p.covariance) for p in posts])
    model.dictionary_ensemble_, model.ensemble_prior_means_, model.ensemble_prior_precisions_ = dictionary_ensemble(
        model, gt.mdp, gt.train_demos, 8, "bootstrap", rng=model.rng)
    model.transfer(gt.mdp, test)
    posts = model.transfer_posterior_
    rho("ensemble_map_spread", [np.mean([np.linalg.norm(q.mean_rewards() - p.mean_rewards()) for q in p.members]) for p in posts])
    rho("ensemble_map_regret", [np.mean(fo.deviation(gt.mdp, np.stack([q.mean_rewards() for q in p.members]),
                                                     np.repeat(p.mean_rewards()[None], len(p.members), axis=0)))
                                for p in posts])
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1])), indent=2))
