"""
How much to share: the number of primitives and the residual penalty, chosen by validation
==========================================================================================

``FactIRL(n_primitives="auto", residual_penalty="auto")`` chooses k and the residual penalty
lambda of ``R_i = Phi_i (D h_i + delta_i)`` by K-fold validation over tasks: learn a dictionary on
some tasks, transfer it to each held-out task from one demonstration, and score the transferred
reward on that task's other demonstrations (their likelihood under the learner's policy
model, its temperature fitted per task). A candidate that shares replaces the flat model only if
its gain, paired over the held-out tasks, is significant; k is then bisected around a chosen
shared candidate. ``validation_`` holds the table (one
row per candidate) and ``plot_validation`` draws it: lambda = inf is the paper's factorial model,
0 the flat one.
"""

import matplotlib.pyplot as plt

import factirl_opt as fo
from factirl_opt.learners import plot_validation

world = fo.objectworld.make_objectworld(size=5, rng=0)
mdp, features = world.mdp(), fo.objectworld.objectworld_features(world)
R, _, _ = fo.objectworld.multitask_rewards(world, n_tasks=6, rng=1)
demos = fo.sample_demonstrations(mdp, R, n_demos=6, length=8, rng=2)

model = fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=features,
                   max_iter=5, flat_max_iter=20, rng=0).fit(mdp, demos)
print(f"chosen: k = {model.n_primitives_}, lambda = {model.residual_penalty_}")
for row in model.validation_:
    print({key: row[key] for key in ("n_primitives", "residual_penalty", "score", "score_std", "chosen")})

fig, ax = plt.subplots(figsize=(7, 4))
plot_validation(model, ax=ax)
ax.set_title("validation over tasks (circled: the chosen pair)")
fig.tight_layout()
plt.show()
