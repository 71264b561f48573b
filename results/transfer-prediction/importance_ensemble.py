"""The dictionary's error in the importance-sampled posterior: draws from the bootstrap dictionaries pooled with the model's own.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/importance_ensemble.py SEED [N_DRAWS B]

Prints JSON. On calibration.py's draw (60 training tasks, 30 test tasks from one demonstration,
``transfer_stol=1e-3``), the posterior of ``fo.learners.importance_posterior`` (docs/maths.md §10a) is
formed under each of ``1 + B`` dictionaries: the model's own with its prior, and ``B = 4``
bootstrap refits with theirs (``dictionary_ensemble``, as ``PosteriorSettings(n_dictionaries=B)``
fits them). Each dictionary ``b`` contributes ``N_DRAWS = 5000`` draws ``h ~ N(m_b, P_b^-1)``,
rewards ``R = D_b h`` (tabular), and every draw is weighted by the likelihood of the task's
demonstration under the Boltzmann policy of its ``Q*`` at the model's ``beta``: pooled over the
dictionaries, the weights of the mixture of their priors (equal prior mass, equal draws). Rows:

- ``own``: the model's dictionary only (checked against ``fo.learners.importance_posterior`` with the same
  draws: ``own_matches_library``, the largest weight difference);
- ``pooled``: the ``1 + B`` dictionaries (``mean_largest_dictionary_weight``: how much of a task's
  posterior mass its likeliest dictionary holds, averaged over the tasks);
- ``members``: the ``B`` bootstrap dictionaries only.

Spearman(expected regret, true deviation), the coverage of the 90% bound and the median effective
sample size; all posteriors act on the Laplace posterior's means (as in calibration.py).
"""

import json
import sys

import numpy as np
from scipy.stats import spearmanr

import factirl_opt as fo
from calibration import draw  # this folder's shared draw
from factirl_opt.learners.dictionary_ensemble import dictionary_ensemble
from factirl_opt.learners.transfer import coefficient_prior
from factirl_opt.planning import get_planner, plan


def member_draws(mdp, planner, D, m, P, n, rng, test, acted, beta):
    """Log-likelihoods (n_tasks, n) and regrets (n_tasks, n) of ``n`` draws of one dictionary's prior."""
    S, A = mdp.n_states, mdp.n_actions
    H = m + rng.standard_normal((n, m.shape[0])) @ np.linalg.cholesky(np.linalg.inv(P)).T
    unit = D.T.reshape(-1, S, A)
    R = np.tensordot(H, unit, axes=1)
    res = plan(planner, R)
    log_pi = np.log(fo.boltzmann_policy(res.Q, beta))
    best = res.V.mean(axis=1)
    ll, reg = [], []
    for demo, M in zip(test, acted):
        pairs = np.asarray(demo).reshape(-1, 2)
        ll.append(log_pi[:, pairs[:, 0], pairs[:, 1]].sum(axis=1))
        pi = plan(planner, M[None]).policy[0]
        c = np.array([fo.policy_evaluation(mdp, unit[j], pi).mean() for j in range(len(unit))])
        reg.append(np.maximum(best - H @ c, 0.0))
    return np.array(ll), np.array(reg), H


def summary(ll, reg, dev, n_per_member):
    w = np.exp(ll - ll.max(axis=1, keepdims=True))
    w /= w.sum(axis=1, keepdims=True)
    expected = (w * reg).sum(axis=1)
    upper = []
    for wi, ri in zip(w, reg):
        order = np.argsort(ri, kind="stable")
        cum = np.cumsum(wi[order])
        upper.append(ri[order][min(int(np.searchsorted(cum, 0.9 * cum[-1])), len(order) - 1)])
    mass = w.reshape(len(w), -1, n_per_member).sum(axis=2)
    return {"spearman": float(spearmanr(expected, dev).correlation), "coverage_90": float(np.mean(dev <= np.array(upper))),
            "median_ess": float(np.median(1.0 / (w ** 2).sum(axis=1))),
            "mean_largest_dictionary_weight": float(mass.max(axis=1).mean())}, w


def main(seed, n=5000, B=4):
    gt, test, true, model = draw(seed)
    mdp = gt.mdp
    model.fit(mdp, gt.train_demos)
    model.transfer(mdp, test)
    acted = np.stack([p.mean_rewards() for p in model.transfer_posterior_])
    dev = np.asarray(fo.deviation(mdp, true, acted))
    Ds, ms, Ps = dictionary_ensemble(model, mdp, gt.train_demos, B, "bootstrap", rng=np.random.default_rng(seed))
    m0, P0 = coefficient_prior(model.coefficients_)
    planner = get_planner(mdp, "auto")
    members = [(model.dictionary_, m0, P0), *zip(Ds, ms, Ps)]
    rng = np.random.default_rng([seed, 777])  # the own dictionary's draws first: those of fo.learners.importance_posterior
    out = [member_draws(mdp, planner, D, m, P, n, rng, test, acted, model.beta) for D, m, P in members]
    ll = [o[0] for o in out]
    reg = [o[1] for o in out]
    own, w_own = summary(ll[0], reg[0], dev, n)
    library = fo.learners.importance_posterior(model, n, rng=np.random.default_rng([seed, 777]), acted_rewards=acted)
    own["own_matches_library"] = float(max(np.abs(p.weights - w).max() for p, w in zip(library, w_own)))
    pooled, _ = summary(np.concatenate(ll, axis=1), np.concatenate(reg, axis=1), dev, n)
    only, _ = summary(np.concatenate(ll[1:], axis=1), np.concatenate(reg[1:], axis=1), dev, n)
    return {"seed": seed, "n_draws_per_dictionary": n, "n_dictionaries": B, "own": own, "pooled": pooled, "members": only}


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), *(int(a) for a in sys.argv[2:])), indent=2))
