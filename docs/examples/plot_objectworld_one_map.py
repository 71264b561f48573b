"""
Objectworld on one map: true and learnt rewards
===============================================

Levine et al.'s Objectworld: objects with an inner and an outer colour on a grid, and the
"distance to the nearest object of colour c is below d" features. ELIRL's multi-task version
draws each task's reward as a combination of a few colour primitives. FactIRL learns a dictionary
over the features from every task's demonstrations; below, one task's true state values next to
the values of its learnt reward (``fo.objectworld.plot_objectworld``).
"""

import matplotlib.pyplot as plt
import numpy as np

import factirl_opt as fo

world = fo.objectworld.make_objectworld(size=10, rng=0)
mdp = world.mdp()                                                # a sparse TabularMDP
features = fo.objectworld.objectworld_features(world)            # (S, p) state features
R, _, _ = fo.objectworld.multitask_rewards(world, n_tasks=12, rng=1)
demos = fo.sample_demonstrations(mdp, R, n_demos=16, length=12, rng=2)

model = fo.FactIRL(n_primitives=3, features=features, max_iter=15, start=fo.Start(flat_max_iter=40), rng=0)
model.fit(mdp, demos)
print("train deviation, mean over tasks:", fo.deviation(mdp, R, model.rewards_).mean())

task = 0
q_true, _ = fo.optimal_q(mdp, R[task])
q_learnt, _ = fo.optimal_q(mdp, model.rewards_[task])
fig, axes = plt.subplots(1, 2, figsize=(9, 4))
fo.objectworld.plot_objectworld(world, ax=axes[0], values=np.max(q_true, axis=-1))
axes[0].set_title("true values of task 0")
fo.objectworld.plot_objectworld(world, ax=axes[1], values=np.max(q_learnt, axis=-1))
axes[1].set_title("values of the learnt reward")
fig.tight_layout()
plt.show()
