"""The best ranking any posterior's expected regret can reach on the calibration draw: the exact Bayes posterior.

Usage: OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/transfer-prediction/bayes_ceiling.py SEED [N_TRAIN N_TEST N_DIRECTIONS]

Prints JSON. On calibration.py's draw (the paper's grid, a dictionary learnt from N_TRAIN = 60
training tasks x 10 demonstrations, N_TEST = 30 test tasks transferred from one demonstration,
``transfer_stol=1e-3``), the deviation of each test task's posterior mean (the reward the model
acts on) is predicted by the *exact* posterior of the world that generated the task, which knows
everything the learner has to estimate:

- the true dictionary ``D`` (S*A, k), the true prior of the coefficients ``w ~ N(0, I_k)`` and the
  true expert (greedy on ``Q*`` of ``D w``, ``sample_demonstrations``);
- so the posterior of ``w`` given the demonstration is the prior restricted to the ``w`` whose
  greedy policy takes the demonstrated action in every demonstrated state. A greedy policy does
  not change when ``w`` is scaled by ``c > 0``, so the restriction is on the direction
  ``u = w / |w|`` only: the direction is uniform on the sphere restricted to that set, and the
  norm ``r = |w|`` keeps its prior, chi with k degrees of freedom, independent of the direction.
- the posterior expected regret of the model's policy ``pi_i`` (greedy on the task's posterior
  mean) is then ``E[r] * mean_u dev(D u, pi_i)`` over the accepted directions, exactly (up to the
  Monte Carlo error of N_DIRECTIONS = 200,000 directions drawn once, shared by the tasks), with
  ``dev(R, pi) = mean_s V*_R(s) - mean_s V^pi_R(s)`` the library's ``deviation``
  (``V^pi_{D u} = sum_j u_j V^pi_{D e_j}``, linear in ``u``).

Reported: Spearman(that exact expected regret, true deviation), and the coverage of its exact
90% bound (``r`` drawn from chi_k, 2000 draws per direction set), beside the library's
conditional posterior in the same process (Spearman and coverage of 200 ``sample_regrets``, as
in calibration.py), and two oracles that know a part of the truth the demonstration does not
show: the direction (so only the norm ``r`` is unknown: ``E[r] dev(D u_true, pi_i)``) and the
norm (``r_true * mean_u dev(D u, pi_i)``). Each test task's own true direction must be accepted
(checked: ``own_direction_accepted``).
"""

import json
import sys
import time

import numpy as np
from scipy.special import gammaln
from scipy.stats import spearmanr

import factirl_opt as fo
from calibration import draw  # this folder's shared draw
from factirl_opt.planning import get_planner, plan

CHUNK = 10_000  # directions planned per batch
PARTICLES = (2_000, 10_000, 40_000)  # fo.learners.importance_posterior's draws


def chi_mean(k):
    """E|w| for w ~ N(0, I_k)."""
    return float(np.sqrt(2.0) * np.exp(gammaln((k + 1) / 2) - gammaln(k / 2)))


def direction_plans(planner, D3, U):
    """Greedy policy (n, S), mean optimal value (n,) and ``Q*`` (n, S, A; float32) of the rewards ``D u``
    for each row ``u`` of U."""
    policies, values, Q = [], [], []
    for lo in range(0, len(U), CHUNK):
        res = plan(planner, np.einsum("sak,mk->msa", D3, U[lo:lo + CHUNK]))
        policies.append(res.policy.astype(np.int8))
        values.append(res.V.mean(axis=1))
        Q.append(res.Q.astype(np.float32))
    return np.concatenate(policies), np.concatenate(values), np.concatenate(Q)


def log_softmax_pairs(Q, s, a, scale):
    """``sum_t log softmax(scale_j Q_j[s_t])[a_t]`` (n,) for each row ``j`` of Q (n, S, A)."""
    z = scale[:, None, None] * Q[:, s, :].astype(np.float64)  # (n, L, A)
    top = z.max(axis=2, keepdims=True)
    lse = top[:, :, 0] + np.log(np.exp(z - top).sum(axis=2))
    return (z[:, np.arange(len(s)), a] - lse).sum(axis=1)


def learnt_world_greedy(model, planner, test, dev, acted, seed, n_particles):
    """The draws of ``fo.learners.importance_posterior`` (learnt dictionary and prior) kept only when their greedy
    policy takes every demonstrated action (the true expert's likelihood): Spearman of the mean regret."""
    posts = fo.learners.importance_posterior(model, n_particles, rng=np.random.default_rng([seed, 777]), acted_rewards=acted)
    pol = plan(planner, posts[0].rewards(posts[0].coefficients)).policy  # one MDP: the draws' greedy policies
    expected, kept = [], []
    for p, demo in zip(posts, test):
        pairs = np.asarray(demo).reshape(-1, 2)
        acc = np.all(pol[:, pairs[:, 0]] == pairs[:, 1], axis=1)
        kept.append(int(acc.sum()))
        expected.append(float(p.regrets[acc].mean()) if acc.any() else np.nan)
    return {"n_particles": n_particles, "spearman": float(spearmanr(expected, dev, nan_policy="omit").correlation),
            "tasks_without_draw": int(np.isnan(expected).sum()), "median_kept": float(np.median(kept))}


def library_importance(model, mdp, dev, acted, seed, n_particles, transfer_cpu):
    """``fo.learners.importance_posterior`` (the learnt dictionary, the learnt prior, the model's own policy model)
    acting on the same rewards: Spearman, coverage of its 90% bound, effective sample sizes, cost."""
    t = time.process_time()
    posts = fo.learners.importance_posterior(model, n_particles, rng=np.random.default_rng([seed, 777]), acted_rewards=acted)
    cpu = time.process_time() - t
    expected = [p.expected_regret() for p in posts]
    ess = [p.effective_sample_size for p in posts]
    return {"n_particles": n_particles, "spearman": float(spearmanr(expected, dev).correlation),
            "coverage_90": float(np.mean(dev <= np.array([p.regret_quantile(0.9) for p in posts]))),
            "mean_expected_regret": float(np.mean(expected)), "min_ess": float(min(ess)),
            "median_ess": float(np.median(ess)), "cpu_s": cpu, "cpu_in_transfers": cpu / transfer_cpu}


def main(seed, n_train=60, n_test=30, n_directions=200_000, n_samples=200):
    gt, test, true, model = draw(seed, n_train, n_test)
    mdp = gt.mdp
    S, A = mdp.n_states, mdp.n_actions
    t = time.process_time()
    model.fit(mdp, gt.train_demos)
    fit_cpu = time.process_time() - t
    t = time.process_time()
    model.transfer(mdp, test)
    transfer_cpu = time.process_time() - t
    posts = model.transfer_posterior_
    M = np.stack([p.mean_rewards() for p in posts])
    dev = np.asarray(fo.deviation(mdp, true, M))
    reg = np.array([p.sample_regrets(n_samples, np.random.default_rng([seed, i])) for i, p in enumerate(posts)])
    library = {"spearman": float(spearmanr(reg.mean(axis=1), dev).correlation),
               "coverage_90": float(np.mean(dev <= np.quantile(reg, 0.9, axis=1)))}

    D = np.asarray(gt.dictionary, dtype=float)
    k = D.shape[1]
    D3 = D.reshape(S, A, k)
    W = np.linalg.lstsq(D, true.reshape(len(test), -1).T, rcond=None)[0].T  # (n_test, k) true coefficients
    fit_error = float(np.abs(W @ D.T - true.reshape(len(test), -1)).max())
    r_true = np.linalg.norm(W, axis=1)
    u_true = W / r_true[:, None]

    planner = get_planner(mdp, "auto")
    t = time.process_time()
    U = np.random.default_rng([seed, 4242]).standard_normal((n_directions, k))
    U /= np.linalg.norm(U, axis=1, keepdims=True)
    pol, vbar, QU = direction_plans(planner, D3, U)
    own_pol, own_vbar, _ = direction_plans(planner, D3, u_true)
    r_prior = np.linalg.norm(np.random.default_rng([seed, 5]).standard_normal((n_directions, k)), axis=1)
    plan_cpu = time.process_time() - t

    learnt_policy = plan(planner, M).policy  # (n_test, S): the policies the model acts with
    Ek = chi_mean(k)
    r_draws = np.linalg.norm(np.random.default_rng([seed, 99]).standard_normal((2000, k)), axis=1)
    exact, covered, n_acc, own_ok, dir_oracle, norm_oracle, check, boltzmann = [], [], [], [], [], [], [], []
    for i, demo in enumerate(test):
        pairs = np.asarray(demo).reshape(-1, 2)
        s, a = pairs[:, 0], pairs[:, 1]
        acc = np.all(pol[:, s] == a, axis=1)
        own_ok.append(bool(np.all(own_pol[i, s] == a)))
        # V^pi of the k primitives (mean over states): V^pi_{D u} = c @ u
        c = np.array([fo.policy_evaluation(mdp, D3[:, :, j], learnt_policy[i]).mean() for j in range(k)])
        dev_u = vbar[acc] - U[acc] @ c  # deviation of the model's policy under each accepted direction
        n_acc.append(int(acc.sum()))
        # the true world with a Boltzmann expert at the model's beta: w_j = r_j u_j, r_j from the prior
        ll = log_softmax_pairs(QU, s, a, model.beta * r_prior)
        wb = np.exp(ll - ll.max())
        boltzmann.append(float(wb @ (r_prior * (vbar - U @ c)) / wb.sum()))
        own_dev_u = own_vbar[i] - u_true[i] @ c
        check.append(abs(r_true[i] * own_dev_u - dev[i]))
        dir_oracle.append(Ek * own_dev_u)
        if not acc.any():  # no direction drawn is consistent: the task is left out of the exact rows
            exact.append(np.nan), covered.append(np.nan), norm_oracle.append(np.nan)
            continue
        exact.append(Ek * dev_u.mean())
        bound = np.quantile(np.multiply.outer(r_draws, dev_u).ravel(), 0.9)
        covered.append(float(dev[i] <= bound))
        norm_oracle.append(r_true[i] * dev_u.mean())
    importance = [library_importance(model, mdp, dev, M, seed, n, transfer_cpu) for n in PARTICLES]
    greedy = learnt_world_greedy(model, planner, test, dev, M, seed, PARTICLES[-1])
    return {
        "seed": seed, "n_train": n_train, "n_test": n_test, "n_directions": n_directions,
        "fit_cpu_s": fit_cpu, "transfer_cpu_s": transfer_cpu, "direction_plans_cpu_s": plan_cpu,
        "true_coefficients_fit_error": fit_error,
        "deviation_formula_max_error": float(max(check)),
        "own_direction_accepted": int(sum(own_ok)),
        "accepted_directions": {"min": min(n_acc), "median": float(np.median(n_acc)), "max": max(n_acc)},
        "library_conditional": library,
        "library_importance": importance,
        "exact_posterior": {"spearman": float(spearmanr(exact, dev, nan_policy="omit").correlation),
                            "coverage_90": float(np.nanmean(covered)), "tasks_without_direction": int(np.isnan(exact).sum())},
        "true_world_boltzmann_expert": {"spearman": float(spearmanr(boltzmann, dev).correlation)},
        "learnt_world_greedy_expert": greedy,
        "oracle_knows_direction": {"spearman": float(spearmanr(dir_oracle, dev).correlation)},
        "oracle_knows_norm": {"spearman": float(spearmanr(norm_oracle, dev, nan_policy="omit").correlation)},
        "mean_deviation": float(dev.mean()), "mean_exact_expected_regret": float(np.nanmean(exact)),
    }


if __name__ == "__main__":
    print(json.dumps(main(int(sys.argv[1]), *(int(a) for a in sys.argv[2:])), indent=2))
