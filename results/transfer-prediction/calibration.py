"""Calibration of the transfer posterior with and without the dictionary's error and the per-task noise level.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/calibration.py SEED [N_TRAIN N_TEST N_SAMPLES]

Prints JSON. The issue's draw: the paper's 10x10 grid with the ``fast`` preset's solvers (as
``bench active``), a dictionary (k = 5, policy matching) learnt from N_TRAIN = 60 training
tasks x 10 demonstrations, and N_TEST = 30 test tasks transferred from one demonstration
each, with the converged transfer ``transfer_stol=1e-3`` passed explicitly. For each posterior
below, over the test tasks: the coverage of the 90% regret bound (the 0.9 quantile of
``sample_regrets``, N_SAMPLES = 200 draws, generator seeded by (SEED, task)) of the true deviation
of the posterior mean, and Spearman(expected regret, that deviation). The posterior mean (the
MAP under the conditional posterior) is the same in every row, so is the deviation.

Rows (the library's options, ``FactIRL(posterior=PosteriorSettings(noise=..., n_dictionaries=B,
resampling=...))``):

- ``conditional``: the default, conditional on the fitted dictionary;
- ``noise``: ``noise="misfit"``;
- ``bootstrap8`` / ``folds5``: the dictionary ensemble of 8 bootstrap refits / 5 fold refits;
- ``...+noise``: both terms.

The ensembles are computed once per kind (:func:`factirl_opt.learners.dictionary_ensemble.dictionary_ensemble`,
as ``fit`` does with those options, from the model's ``rng``) and set on the one fitted model.
"""

import json
import sys
import time

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.lab.experiments.presets import PRESETS
from factirl_opt.lab.experiments.worlds import make_ground_truth
from factirl_opt.learners.dictionary_ensemble import dictionary_ensemble

ENSEMBLES = {"bootstrap8": (8, "bootstrap"), "folds5": (5, "folds")}


def draw(seed, n_train=60, n_test=30):
    """The issue's draw (the paper's grid, ``n_train`` training tasks x 10 demonstrations, ``n_test``
    one-demonstration test tasks) and the fast preset's FactIRL with the converged transfer, unfitted:
    ``(gt, test, true, model)``. The scripts of this folder share it."""
    preset = PRESETS["fast"]
    gt = make_ground_truth(preset, n_train, 10, seed)
    test, true = gt.test_demos[:n_test], np.asarray(gt.test_rewards[:n_test])
    options = factorial_options(preset, preset.solvers, "policy-matching")
    return gt, test, true, fo.FactIRL(rng=seed, **{**options, "transfer_stol": 1e-3})


def calibration(model, gt, test, true, n_samples, seed):
    model.transfer(gt.mdp, test)
    t = time.process_time()
    posts = model.transfer_posterior_
    post_cpu = time.process_time() - t
    dev = np.asarray(fo.deviation(gt.mdp, true, np.stack([p.mean_rewards() for p in posts])))
    reg = np.array([p.sample_regrets(n_samples, np.random.default_rng([seed, i])) for i, p in enumerate(posts)])
    expected, upper = reg.mean(axis=1), np.quantile(reg, 0.9, axis=1)
    return {"coverage_90": float(np.mean(dev <= upper)), "spearman": float(spearmanr(expected, dev).correlation),
            "mean_expected_regret": float(expected.mean()), "mean_upper_90": float(upper.mean()),
            "mean_deviation": float(dev.mean()), "posterior_cpu_s": post_cpu}


def main(seed, n_train=60, n_test=30, n_samples=200):
    gt, test, true, model = draw(seed, n_train, n_test)
    t = time.process_time()
    model.fit(gt.mdp, gt.train_demos)
    out = {"seed": seed, "n_train": n_train, "n_test": n_test, "n_samples": n_samples, "fit_cpu_s": time.process_time() - t}
    t = time.process_time()
    model.transfer(gt.mdp, test)
    out["transfer_cpu_s"] = time.process_time() - t
    out["median_train_noise_level"] = float(np.median(model.noise_levels_))
    rows = {}
    for noise in ("multinomial", "misfit"):
        model.set_params(posterior__noise=noise)
        rows["conditional" if noise == "multinomial" else "noise"] = calibration(model, gt, test, true, n_samples, seed)
    for name, (B, how) in ENSEMBLES.items():
        t = time.process_time()
        ens = dictionary_ensemble(model, gt.mdp, gt.train_demos, B, how, rng=model.rng)
        out[f"{name}_fit_cpu_s"] = time.process_time() - t
        model.dictionary_ensemble_, model.ensemble_prior_means_, model.ensemble_prior_precisions_ = ens
        for noise in ("multinomial", "misfit"):
            model.set_params(posterior__noise=noise)
            rows[name + ("" if noise == "multinomial" else "+noise")] = calibration(model, gt, test, true, n_samples, seed)
    out["rows"] = rows
    return out


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), *(int(a) for a in sys.argv[2:])), indent=2))
