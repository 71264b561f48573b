"""
How sure is a transferred reward, and where to ask next
=======================================================

After ``FactIRL.transfer`` a new task's reward is learnt from one demonstration. Its
``transfer_posterior_`` is a Gaussian over the task's coefficients (the Laplace approximation
at the MAP under a prior fitted to the training tasks' coefficients, docs/maths.md §10):
``sample_rewards`` draws rewards from it and ``sample_regrets`` the regret of acting on its
mean reward, in the units of ``fo.deviation``. ``FactIRL.request_starts`` ranks start states by
how much a demonstration from each is expected to tell about the coefficients.

Below: the mean reward's state values with the demonstration and the requested start (left),
how much the values vary across posterior draws (middle), and the posterior regret with its 90%
upper bound next to the task's true deviation (right).
"""

import matplotlib.pyplot as plt
import numpy as np

import factirl_opt as fo

size = 8
mdp = fo.GridWorld(size=size, p_success=0.8, gamma=0.9)
rng = np.random.default_rng(0)
D = fo.random_dictionary(mdp.n_params, 3, rng=rng)
train_R = fo.task_rewards(D, fo.random_coefficients(30, 3, rng=rng), mdp.n_states, mdp.n_actions)
train_demos = fo.sample_demonstrations(mdp, train_R, n_demos=6, length=10, rng=1)
new_R = fo.task_rewards(D, fo.random_coefficients(1, 3, rng=rng), mdp.n_states, mdp.n_actions)
new_demos = fo.sample_demonstrations(mdp, new_R, n_demos=1, length=10, rng=2)

model = fo.FactIRL(n_primitives=3, max_iter=20, rng=0).fit(mdp, train_demos)
model.transfer(mdp, new_demos)
post = model.transfer_posterior_[0]
print("posterior mean of the coefficients:", np.round(post.mean, 2))
print("posterior standard deviations:", np.round(np.sqrt(np.diag(post.covariance)), 2))

start = model.request_starts(mdp, new_demos, n_requests=1)[0][0]
values = np.max(fo.optimal_q(mdp, post.mean_rewards())[0], axis=-1)
draws = post.sample_rewards(50, rng=3)
spread = np.std([np.max(fo.optimal_q(mdp, R)[0], axis=-1) for R in draws], axis=0)
regrets = post.sample_regrets(200, rng=4)
true_dev = fo.deviation(mdp, new_R[0], post.mean_rewards())

fig, axes = plt.subplots(1, 3, figsize=(13, 4))
path = new_demos[0][0][:, 0]
for ax, grid, title in ((axes[0], values, "values of the posterior mean"),
                        (axes[1], spread, "std of the values over 50 draws")):
    im = ax.imshow(grid.reshape(size, size), cmap="viridis")
    ax.plot(path % size, path // size, "w.-", label="demonstration")
    ax.plot(start % size, start // size, "r*", markersize=16, label="requested start")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, shrink=0.8)
axes[0].legend(loc="lower left", fontsize=8)
axes[2].hist(regrets, bins=30, color="0.6")
axes[2].axvline(np.quantile(regrets, 0.9), color="k", linestyle="--", label="90% upper bound")
axes[2].axvline(true_dev, color="r", label="true deviation")
axes[2].set_xlabel("regret of acting on the mean reward")
axes[2].set_title("posterior regret")
axes[2].legend()
fig.tight_layout()
plt.show()
