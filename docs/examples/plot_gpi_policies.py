"""
A new task's policy without planning: GPI over successor features
==================================================================

FactIRL learns a dictionary of primitive rewards on an Objectworld map. A new task in the
dictionary's span, ``R = Phi D h``, gets its policy either by planning (``fo.optimal_q`` on its
reward) or by generalised policy improvement over the successor features of a library of
policies (``FactIRL.gpi_policies``: the optimal policies of the primitives, of their negatives
and of the training tasks, computed once): ``pi(s) = argmax_a max_l psi_l(s, a) h``, with no
Bellman solve. Below, the two policies of one new task side by side over the task's optimal
values; arrows show the moves (a dot: stay), red where they differ.
"""

import matplotlib.pyplot as plt
import numpy as np

import factirl_opt as fo

world = fo.objectworld.make_objectworld(size=10, rng=0)
mdp = world.mdp()
features = fo.objectworld.objectworld_features(world)
R, _, _ = fo.objectworld.multitask_rewards(world, n_tasks=12, rng=1)
demos = fo.sample_demonstrations(mdp, R, n_demos=16, length=12, rng=2)
model = fo.FactIRL(n_primitives=3, features=features, max_iter=15, start=fo.Start(flat_max_iter=40), rng=0).fit(mdp, demos)

# a new task: one demonstration, its coefficients by transfer
R_new, _, _ = fo.objectworld.multitask_rewards(world, n_tasks=1, rng=3)
h = model.transfer(mdp, fo.sample_demonstrations(mdp, R_new, n_demos=1, length=12, rng=4))
gpi = model.gpi_policies(mdp, h)[0]                       # no planning
report = model.gpi_report_
q, planned = fo.optimal_q(mdp, model.transfer_rewards_[0])  # planning the learnt reward
print(f"value: GPI {report.gpi_value[0]:.3f}, best library policy ({report.best_library_policy[0]}) "
      f"{report.best_library_value[0]:.3f}, planned {q.max(axis=1).mean():.3f}")

N = world.size
rows, cols = np.divmod(np.arange(mdp.n_states), N)
fig, axes = plt.subplots(1, 2, figsize=(10, 4.5))
for ax, policy, title in ((axes[0], planned, "planned (optimal_q)"), (axes[1], gpi, "GPI (gpi_policies)")):
    fo.objectworld.plot_objectworld(world, ax=ax, values=q.max(axis=1))
    move = fo.objectworld.MOVES[policy]
    differ = policy != planned
    for mask, colour in ((~differ, "white"), (differ, "red")):
        ax.quiver(cols[mask], rows[mask], move[mask, 1], -move[mask, 0], color=colour, scale=25, width=0.006)
    ax.set_title(title if policy is planned else f"{title}: {int(differ.sum())} states differ")
fig.tight_layout()
plt.show()
