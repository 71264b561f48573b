"""What the Laplace approximation misses on the paper's grid: calibration with the learnt dictionary
and with the true one (no dictionary error), side by side, on the same 100 test tasks.

Usage: OMP_NUM_THREADS=1 python results/active/calibration_oracle.py SEED [N_SAMPLES]

Prints JSON: for the learnt model (FactIRL on 100 training tasks x 10 demonstrations, the
``fast`` preset's solvers, as ``bench active`` fits it) and for an oracle model whose
``dictionary_`` and ``coefficients_`` are the true dictionary and the training tasks' true
coefficients: the coverage of the 90% regret bound and Spearman(expected regret, deviation of
the posterior mean), each test task transferred from its one demonstration.
"""

import json
import sys

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from factirl_opt.datasets.synthetic import random_coefficients, random_dictionary
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.presets import PRESETS
from factirl_opt.lab.experiments.worlds import N_STREAMS, make_ground_truth


def calibration(model, gt, n_samples, seed):
    model.transfer(gt.mdp, gt.test_demos)
    posts = model.transfer_posterior_
    reg = np.array([p.sample_regrets(n_samples, np.random.default_rng([seed, i])) for i, p in enumerate(posts)])
    dev = np.asarray(fo.deviation(gt.mdp, gt.test_rewards, np.stack([p.mean_rewards() for p in posts])))
    dev_t = np.asarray(fo.deviation(gt.mdp, gt.test_rewards, model.transfer_rewards_))
    return {"coverage_90": float(np.mean(dev <= np.quantile(reg, 0.9, axis=1))),
            "spearman": float(spearmanr(reg.mean(axis=1), dev).correlation),
            "mean_expected_regret": float(reg.mean()), "mean_deviation_map": float(dev.mean()),
            "mean_deviation_transferred": float(dev_t.mean()),
            "mean_posterior_sd": float(np.mean([np.sqrt(np.diag(p.covariance)).mean() for p in posts]))}


def main(seed, n_samples=200):
    preset = PRESETS["fast"]
    gt = make_ground_truth(preset, 100, 10, seed)
    model = fo.FactIRL(rng=seed, **factorial_options(preset, preset.solvers, "policy-matching"))
    model.fit(gt.mdp, gt.train_demos)
    out = {"seed": seed, "learnt": calibration(model, gt, n_samples, seed)}
    # the true dictionary and training coefficients, drawn from the same streams as make_ground_truth
    s_dict, s_train = np.random.SeedSequence(seed).spawn(N_STREAMS)[:2]
    D = random_dictionary(gt.mdp.n_params, preset.n_primitives, rng=np.random.default_rng(s_dict))
    H = random_coefficients(100, preset.n_primitives, kind=preset.coefficient_kind, rng=np.random.default_rng(s_train))
    assert np.allclose(fo.task_rewards(D, H, gt.mdp.n_states, gt.mdp.n_actions), gt.train_rewards)
    model.dictionary_, model.coefficients_ = D, H
    out["true_dictionary"] = calibration(model, gt, n_samples, seed)
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), *(int(a) for a in sys.argv[2:])), indent=2))
