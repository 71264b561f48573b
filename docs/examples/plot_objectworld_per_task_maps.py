"""
Objectworld with a map per task: transfer to maps never seen
============================================================

Every task may live in its own environment: ``fit`` takes one MDP per task and one feature
matrix per task with the same columns; the dictionary ``D`` (p, k) lives in feature space,
``R_i = Phi_i D h_i``. A dictionary learnt on some maps transfers to new tasks on maps no
demonstration was seen on, from one demonstration each, and ``fo.feature_rewards`` carries the
learnt weights to those maps.
"""

import matplotlib.pyplot as plt
import numpy as np

import factirl_opt as fo

train = fo.objectworld.objectworld_maps(10, size=8, n_blocked=2, rng=0)  # 10 tasks, each its own 8x8 map
mdps, feats = list(train.mdps), list(train.features)                   # per-task TabularMDPs and (S, p) features
demos = fo.sample_demonstrations(mdps, train.rewards, n_demos=8, length=8, rng=1)
fact = fo.FactIRL(n_primitives=3, features=feats, max_iter=20).fit(mdps, demos)  # one dictionary D (p, k)

test = fo.objectworld.objectworld_maps(5, size=8, n_blocked=2, rng=2)  # new tasks on maps never seen
new_mdps, new_feats = list(test.mdps), list(test.features)
one = fo.sample_demonstrations(new_mdps, test.rewards, n_demos=1, length=8, rng=3)
h = fact.transfer(new_mdps, one, features=new_feats)                   # (5, k), from one demonstration each
R_new = fo.feature_rewards(new_feats, h @ fact.dictionary_.T, new_mdps)
dev = fo.deviation(new_mdps, test.rewards, R_new)
print("deviation on the new maps:", np.round(dev, 2), "mean", dev.mean())

task = int(np.argsort(dev)[len(dev) // 2])  # the task of median deviation
v_true = np.max(fo.optimal_q(new_mdps[task], test.rewards[task])[0], axis=-1)
v_learnt = np.max(fo.optimal_q(new_mdps[task], R_new[task])[0], axis=-1)
fig, axes = plt.subplots(1, 2, figsize=(9, 4))
for ax, v, title in zip(axes, [v_true, v_learnt], ["true values", "transferred from one demonstration"]):
    image = ax.imshow(v.reshape(8, 8), cmap="viridis")
    path = one[task][0][:, 0]
    ax.plot(path % 8, path // 8, "w.-", label="the demonstration")
    ax.set_title(f"new map, task {task}: {title}")
    fig.colorbar(image, ax=ax, shrink=0.8)
axes[0].legend(loc="lower right", fontsize=8)
fig.tight_layout()
plt.show()
