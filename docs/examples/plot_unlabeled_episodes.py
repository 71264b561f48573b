"""
Unlabeled episodes: EM over intentions (MultiIntentIRL)
=======================================================

When the episodes come without task labels, ``fo.MultiIntentIRL`` clusters them by EM: each
episode's responsibility under each intention comes from its likelihood under that intention's
Boltzmann policy, and each M-step refits the intentions' rewards (here with a shared dictionary,
``n_primitives=2``). The plot shows the responsibilities, episodes sorted by their true task, and
the log-likelihood over the EM iterations; ``fo.adjusted_rand_index`` scores the clustering
(1 is perfect, 0 is chance).
"""

import matplotlib.pyplot as plt
import numpy as np

import factirl_opt as fo

mdp = fo.GridWorld(size=5)
D = fo.random_dictionary(mdp.n_params, 2, rng=0)
R = fo.task_rewards(D, fo.random_coefficients(3, 2, rng=1), mdp.n_states, mdp.n_actions)
demos = fo.sample_demonstrations(mdp, R, n_demos=12, length=12, rng=2)    # 3 tasks x 12 episodes
episodes = [episode for task in demos for episode in task]                 # the labels are dropped
true_labels = np.repeat(np.arange(3), 12)

em = fo.MultiIntentIRL(3, 2, max_iter=15, rng=0).fit(mdp, episodes)
print("adjusted Rand index:", fo.adjusted_rand_index(true_labels, em.labels_))

fig, axes = plt.subplots(1, 2, figsize=(10, 4), gridspec_kw={"width_ratios": [2, 1]})
image = axes[0].imshow(em.responsibilities_.T, aspect="auto", cmap="Blues", vmin=0, vmax=1)
for boundary in (11.5, 23.5):
    axes[0].axvline(boundary, color="r", lw=1)
axes[0].set_xlabel("episode (sorted by true task; red lines between tasks)")
axes[0].set_ylabel("intention")
axes[0].set_title("responsibilities P(intention | episode)")
fig.colorbar(image, ax=axes[0])
axes[1].plot(range(1, len(em.log_likelihood_) + 1), em.log_likelihood_, marker="o")
axes[1].set_xlabel("EM iteration")
axes[1].set_ylabel("log-likelihood of the actions")
fig.tight_layout()
plt.show()
