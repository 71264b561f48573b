"""Calibration of the transfer posterior with each distinct demonstrated pair counted once (not adopted).

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/calibration_once.py SEED [N_TRAIN N_TEST N_SAMPLES]

Prints JSON: calibration.py's draw, model and scores, for posteriors whose likelihood counts each
distinct demonstrated (state, action) pair once (a greedy expert repeats its action in a state it
revisits, so the repeat tells nothing new; ``N`` the number of distinct pairs), built with
``laplace_posteriors`` on the task's distinct pairs as one-step episodes, started from the
transfer's values: ``once`` (multinomial noise level), ``once+noise`` (with the misfit noise
reference of ``PosteriorSettings(noise="misfit")``), and ``bootstrap8+once+noise`` (the same, with
the 8 bootstrap dictionaries as members). The posterior mean differs from calibration.py's
(another likelihood), so each row's deviation is its own mean's.
"""

import json
import sys

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from calibration import draw  # this folder's shared draw
from factirl_opt.learners.dictionary_ensemble import dictionary_ensemble
from factirl_opt.learners.noise_levels import noise_reference
from factirl_opt.learners.posterior import member_posteriors, laplace_posteriors
from factirl_opt.learners.transfer import coefficient_prior
from factirl_opt.learners.transfer_likelihood import transfer_problem


def distinct_pairs(demos_per_task):
    """Each task's distinct (state, action) pairs as one-step episodes (m_i, 1, 2)."""
    return [np.unique(np.asarray(d).reshape(-1, 2), axis=0)[:, None, :] for d in demos_per_task]


def scores(gt, true, posts, n_samples, seed):
    dev = np.asarray(fo.deviation(gt.mdp, true, np.stack([p.mean_rewards() for p in posts])))
    reg = np.array([p.sample_regrets(n_samples, np.random.default_rng([seed, i])) for i, p in enumerate(posts)])
    expected, upper = reg.mean(axis=1), np.quantile(reg, 0.9, axis=1)
    return {"coverage_90": float(np.mean(dev <= upper)), "spearman": float(spearmanr(expected, dev).correlation),
            "mean_expected_regret": float(expected.mean()), "mean_deviation": float(dev.mean())}


def main(seed, n_train=60, n_test=30, n_samples=200):
    gt, test, true, model = draw(seed, n_train, n_test)
    model.fit(gt.mdp, gt.train_demos)
    model.transfer(gt.mdp, test)
    start = np.asarray(model.transfer_coefficients_)
    problem = transfer_problem(model, gt.mdp, distinct_pairs(test))
    prior = coefficient_prior(model.coefficients_)
    out = {"seed": seed, "n_train": n_train, "n_test": n_test, "n_samples": n_samples, "rows": {}}
    out["rows"]["once"] = scores(gt, true, laplace_posteriors(problem, prior, start), n_samples, seed)
    ref = noise_reference(model.set_params(posterior__noise="misfit"))
    out["rows"]["once+noise"] = scores(gt, true, laplace_posteriors(problem, prior, start, noise_reference=ref), n_samples, seed)
    model.dictionary_ensemble_, model.ensemble_prior_means_, model.ensemble_prior_precisions_ = dictionary_ensemble(
        model, gt.mdp, gt.train_demos, 8, "bootstrap", rng=model.rng)
    posts = member_posteriors(model, problem, laplace_posteriors(problem, prior, start, noise_reference=ref), ref)
    out["rows"]["bootstrap8+once+noise"] = scores(gt, true, posts, n_samples, seed)
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), *(int(a) for a in sys.argv[2:])), indent=2))
