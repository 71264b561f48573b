"""
A model estimated from logs (fo.estimate_mdp)
=============================================

When the dynamics are not given, ``fo.estimate_mdp`` builds a sparse ``TabularMDP`` from logged
(s, a, s') transitions as the Dirichlet posterior mean; pairs never tried get the prior (here a
self-loop). With more logged transitions the estimate approaches the true model: the plot shows
the held-out transitions' log-likelihood (``fo.mdp.transition_log_likelihood``) and the
deviation of the flat learner fitted on each estimated model, scored on the true one.
"""

import matplotlib.pyplot as plt
import numpy as np

import factirl_opt as fo

true = fo.GridWorld(size=5)
D = fo.random_dictionary(true.n_params, 2, rng=0)
R = fo.task_rewards(D, fo.random_coefficients(6, 2, rng=1), true.n_states, true.n_actions)
demos = fo.sample_demonstrations(true, R, n_demos=8, length=8, rng=2)
held_out = fo.mdp.sample_transitions(true, 2000, rng=3)                    # (2000, 3) rows (s, a, s')

sizes = [30, 100, 300, 1000, 3000, 10000]
log_likelihood, deviation = [], []
for n in sizes:
    logs = fo.mdp.sample_transitions(true, n, rng=4)                       # exploration logs
    model = fo.estimate_mdp(logs, true.n_states, true.n_actions, gamma=true.gamma)
    log_likelihood.append(fo.mdp.transition_log_likelihood(model, held_out) / len(held_out))
    flat = fo.GradIRL(max_iter=40).fit(model, demos)
    deviation.append(fo.deviation(true, R, flat.rewards_).mean())          # judged on the true model
exact = fo.GradIRL(max_iter=40).fit(true, demos)
exact_deviation = fo.deviation(true, R, exact.rewards_).mean()

fig, axes = plt.subplots(1, 2, figsize=(10, 4))
axes[0].plot(sizes, log_likelihood, marker="o", label="estimated model")
axes[0].axhline(fo.mdp.transition_log_likelihood(true, held_out) / len(held_out), color="k", ls="--",
                label="true model")
axes[0].set_ylabel("held-out log-likelihood per transition")
axes[1].plot(sizes, deviation, marker="o", label="fitted on the estimated model")
axes[1].axhline(exact_deviation, color="k", ls="--", label="fitted on the true model")
axes[1].set_ylabel("train deviation of the flat learner")
for ax in axes:
    ax.set_xscale("log")
    ax.set_xlabel("logged transitions")
    ax.legend()
fig.tight_layout()
plt.show()
