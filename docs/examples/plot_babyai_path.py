"""
BabyAI: a learnt path in a new layout
=====================================

``fo.minigrid.from_minigrid`` enumerates a MiniGrid/BabyAI layout into a sparse ``TabularMDP``
over the agent's ``(x, y, direction)`` with features that have the same columns in every layout;
``fo.minigrid.bot_demonstration`` rolls the BabyAI bot (the expert) in it. FactIRL learns a
dictionary over the features from a few layouts, then a new layout with a new mission is learnt
from ONE bot demonstration, and ``fo.minigrid.run_policy`` runs the greedy policy of the learnt
reward in the real environment, which decides success. Needs the ``minigrid`` extra.
"""

import gymnasium as gym
import matplotlib.pyplot as plt
import minigrid  # noqa: F401  (registers the BabyAI levels with Gymnasium)

import factirl_opt as fo

env = gym.make("BabyAI-GoToLocal-v0")
episodes = [fo.minigrid.bot_demonstration(env, seed=s) for s in range(12)]  # 12 layouts, one bot episode each
model = fo.FactIRL(n_primitives=4, features=[ep.model.features for ep in episodes],
                   max_iter=10, start=fo.Start(flat_max_iter=50), rng=0)
model.fit([ep.model.mdp for ep in episodes], [ep.demonstrations for ep in episodes])

# new layouts with new missions, one bot demonstration each
tests = []
for seed in range(100, 106):
    new = fo.minigrid.bot_demonstration(env, seed=seed)
    model.transfer([new.model.mdp], [new.demonstrations], features=[new.model.features])
    _, policy = fo.optimal_q(new.model.mdp, model.transfer_rewards_[0])
    run = fo.minigrid.run_policy(env, policy, seed=seed, model=new.model)
    print(f"layout {seed}, {new.mission!r}: {'success' if run.success else 'failure'} in {len(run.actions)} steps "
          f"(the bot took {len(new.demonstration)})")
    tests.append((new, run))
print(f"success rate: {sum(run.success for _, run in tests)} of {len(tests)}")


def draw(ax, new, run):
    """The layout's objects, the bot's demonstration and the learnt policy's path."""
    width, height = new.model.grid_size
    ax.set_xlim(-0.5, width - 0.5)
    ax.set_ylim(height - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.set_xticks(range(width))
    ax.set_yticks(range(height))
    ax.grid(True, color="0.85")
    for x, y, colour, kind in new.model.objects:
        name = fo.minigrid.COLOURS[colour]
        ax.scatter([x], [y], s=250, marker="s", color="0.5" if name == "grey" else name, edgecolor="k")
        ax.annotate(fo.minigrid.OBJECT_TYPES[kind], (x, y), ha="center", va="center", fontsize=6, color="w")
    for states, style, label in [(new.demonstration[:, 0], "k--", "the bot's demonstration"),
                                 (run.states, "m-", "the learnt policy")]:
        xy = new.model.states[states][:, :2]
        ax.plot(xy[:, 0], xy[:, 1], style, lw=2, label=label)
    start = new.model.states[new.model.start]
    ax.plot([start[0]], [start[1]], "g^", markersize=10, label="start")
    ax.set_title(f"{new.mission}: {'success' if run.success else 'failure'}", fontsize=9)


fig, axes = plt.subplots(1, 2, figsize=(10, 5))
for ax, (new, run) in zip(axes, tests[:2]):
    draw(ax, new, run)
axes[1].legend(loc="upper left", bbox_to_anchor=(1, 1), fontsize=8)
fig.tight_layout()
plt.show()
