"""What the grid's one-demonstration deviations follow, and the dictionary's error as reward noise (seed 0).

Usage: OMP_NUM_THREADS=1 python results/active/calibration_diagnostics.py SEED

Prints JSON, on ``bench active``'s grid model and its 100 test tasks (one demonstration each):
Spearman of the deviation of the posterior mean with the true reward's norm, with minus the number
of distinct states the demonstration visits, and with the posterior's expected regret when each
posterior sample's reward weights get the dictionary's error as Gaussian noise outside the
coefficients, ``e ~ N(0, rho^2 ||w_j||^2 / p I)`` (``||e||`` about ``rho`` times the sampled
weights' norm ``||w_j|| = ||D h_j||``: an error ``E h_j`` of the dictionary's columns), with
the coverage of the 90% bound.
"""

import json
import sys

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.presets import PRESETS
from factirl_opt.lab.experiments.worlds import make_ground_truth
from factirl_opt.planning import get_planner, plan


def regrets(post, R):
    """``sample_regrets`` of given rewards R (n, S, A)."""
    pl = get_planner(post.mdp)
    best = plan(pl, R).V.mean(axis=1)
    pols = np.repeat(plan(pl, post.mean_rewards()[None]).policy, len(R), axis=0)
    R_pi = np.take_along_axis(R, pols[:, :, None], axis=2)[:, :, 0]
    return np.maximum(best - pl.system(pols).solve(R_pi).mean(axis=1), 0.0)


def transferred_model(seed):
    """``bench active``'s model for ``seed``: FactIRL on the ``fast`` preset's 100 training tasks x 10
    demonstrations, each of its test tasks transferred from its one demonstration; and the ground truth."""
    preset = PRESETS["fast"]
    gt = make_ground_truth(preset, 100, 10, seed)
    model = fo.FactIRL(rng=seed, **factorial_options(preset, preset.solvers, "policy-matching"))
    model.fit(gt.mdp, gt.train_demos)
    model.transfer(gt.mdp, gt.test_demos)
    return gt, model


def main(seed, n_samples=200):
    gt, model = transferred_model(seed)
    posts = model.transfer_posterior_
    dev = np.asarray(fo.deviation(gt.mdp, gt.test_rewards, np.stack([p.mean_rewards() for p in posts])))
    norm = np.linalg.norm(np.asarray(gt.test_rewards).reshape(len(posts), -1), axis=1)
    distinct = np.array([len(np.unique(np.asarray(d)[..., 0])) for d in gt.test_demos])
    out = {"seed": seed, "spearman_true_norm": float(spearmanr(norm, dev).correlation),
           "spearman_minus_distinct_states": float(spearmanr(-distinct, dev).correlation), "reward_noise": {}}
    S, A = gt.mdp.n_states, gt.mdp.n_actions
    for rho in (0.0, 0.6, 1.5):
        reg = []
        for i, p in enumerate(posts):
            rng = np.random.default_rng([seed, i])
            W = p.weights(p.sample(n_samples, rng))
            W = W + rho * rng.standard_normal(W.shape) * np.linalg.norm(W, axis=1, keepdims=True) / np.sqrt(W.shape[1])
            reg.append(regrets(p, W.reshape(-1, S, A)))
        reg = np.array(reg)
        out["reward_noise"][str(rho)] = {"coverage_90": float(np.mean(dev <= np.quantile(reg, 0.9, axis=1))),
                                         "spearman": float(spearmanr(reg.mean(axis=1), dev).correlation),
                                         "mean_expected_regret": float(reg.mean())}
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1])), indent=2))
