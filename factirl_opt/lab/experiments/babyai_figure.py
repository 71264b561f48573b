"""The BabyAI figure: one test layout with the learnt value map, the bot's demonstration and
the learnt policy's path in the environment (matplotlib, Agg).

:func:`babyai_figure_data` fits the ``babyai`` line-up's flat and factorial learners on
features (policy matching) at one point of a preset, on the training layouts of one seed, and
reads one test layout: for each learner, the optimal values of its learnt reward on that
layout's MDP (``V*(s) = max_a Q*(s, a)``, docs/maths.md §2) and the states its greedy policy
visits when run in the environment (:func:`factirl_opt.adapters.minigrid.run_policy`).
:func:`plot_babyai_layout` draws them side by side: per cell the largest value over the four
directions (walls and objects blank), the objects (marker per type, in their colour, the
mission's targets ringed), the bot's one demonstration (dashed, from its start) and the
learnt policy's path from the layout's start (solid).
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ...learners.factirl import FactIRL
from ...learners.gradirl import GradIRL
from ...objectives.sharding import Execution
from ...adapters.minigrid import COLOURS, OBJECT_TYPES, parse_goto_mission, run_policy
from ...planning import optimal_q
from .learner_names import FACTORIAL_FEATURES, FLAT_FEATURES
from .learners import factorial_options
from .presets import Preset, get_preset
from .worlds import make_ground_truth

__all__ = ["babyai_figure_data", "plot_babyai_layout"]

#: matplotlib colours of MiniGrid's object colours, and markers of its object types
MARKER_COLOURS = {"red": "#d62728", "green": "#2ca02c", "blue": "#1f77b4", "purple": "#9467bd", "yellow": "#e6c619",
                  "grey": "#7f7f7f"}
MARKERS = {"ball": "o", "box": "s", "key": "^"}


def _learnt_rewards(gt: Any, preset: Preset, task: int) -> dict:
    """Rewards on test layout ``task`` of flat and factorial learners on features (policy matching)."""
    mdps, F, demos = gt.mdps("train"), gt.features("train"), gt.train_demos
    flat = GradIRL(beta=preset.beta, features=F, max_iter=preset.flat_max_iter, solver=preset.flat_features_solver,
                   gtol=preset.flat_gtol, stol=preset.flat_stol, execution=Execution(planner=preset.planner)).fit(mdps, demos)
    fact = FactIRL(rng=np.random.default_rng(0), features=F,
                   **factorial_options(preset, preset.solvers))
    fact.fit(mdps, demos, flat_rewards=list(flat.rewards_))
    test_mdp, test_F, test_demo = gt.mdps("test")[task], gt.features("test")[task], gt.test_demos[task]
    fact.transfer([test_mdp], [test_demo], features=[test_F])
    one = GradIRL(beta=preset.beta, features=[test_F], max_iter=preset.flat_max_iter, solver=preset.flat_features_solver,
                  gtol=preset.flat_gtol, stol=preset.flat_stol,
                  execution=Execution(planner=preset.planner)).fit([test_mdp], [test_demo])
    return {FLAT_FEATURES: one.rewards_[0], FACTORIAL_FEATURES: fact.transfer_rewards_[0]}


def babyai_figure_data(preset: str | Preset = "babyai", seed: int = 0, n_tasks: int | None = None,
                       task: int = 0) -> dict[str, Any]:
    """What :func:`plot_babyai_layout` draws, as plain JSON values.

    Parameters
    ----------
    preset : str or Preset
        A preset of a BabyAI world (its learners' budgets and solvers are used).
    seed : int
        The run's seed (its layouts and demonstrations are those of the runner's run).
    n_tasks : int, optional
        Training layouts (default: the smallest of the preset's tasks sweep).
    task : int
        Which test layout.

    Returns
    -------
    dict
        ``grid_size``, ``mission``, ``objects`` (rows x, y, colour, type), ``states`` (S, 3), ``start``,
        ``demo`` (the states of the bot's demonstration, its last state included) and, per
        learner, ``values`` (S,), ``path`` (states visited in the environment), ``success``.
    """
    preset = get_preset(preset)
    n = min(preset.tasks_sweep) if n_tasks is None else int(n_tasks)
    gt = make_ground_truth(preset, n, preset.default_demos, seed)
    model, layout = gt.models["test"][task], gt.seeds["test"][task]
    P = model.mdp.transition_matrix
    demo = gt.test_demos[task][0]
    last = P.indices[P.indptr[demo[-1, 0] * 3 + demo[-1, 1]]]
    data: dict[str, Any] = dict(grid_size=list(model.grid_size), mission=model.mission, objects=model.objects.tolist(),
                                states=model.states.tolist(), demo=[*demo[:, 0].tolist(), int(last)], learners={})
    for name, R in _learnt_rewards(gt, preset, task).items():
        Q, policy = optimal_q(model.mdp, R, planner=preset.planner)
        run = run_policy(gt.env, np.asarray(policy, dtype=np.int64), seed=layout, model=model)
        data["learners"][name] = dict(values=Q.max(axis=-1).tolist(), path=run.states.tolist(), success=run.success)
    data.update(seed=seed, layout_seed=layout, n_tasks=n, start=model.start)
    return data


def _cells(states: np.ndarray, path: list) -> np.ndarray:
    return states[np.asarray(path, dtype=np.int64)][:, :2].astype(float)


def _draw(ax: Any, data: dict, name: str) -> None:
    width, height = data["grid_size"]
    states = np.asarray(data["states"])
    learnt = data["learners"][name]
    grid = np.full((height, width), np.nan)
    for (x, y, _), v in zip(states, learnt["values"]):
        grid[y, x] = v if np.isnan(grid[y, x]) else max(grid[y, x], v)
    ax.imshow(grid, cmap="Blues", origin="upper")
    colour, kind = parse_goto_mission(data["mission"])
    for x, y, c, t in data["objects"]:
        target = COLOURS[c] == (colour or COLOURS[c]) and OBJECT_TYPES[t] == kind
        ax.scatter([x], [y], marker=MARKERS.get(OBJECT_TYPES[t], "x"), s=120, c=MARKER_COLOURS.get(COLOURS[c], "k"),
                   edgecolors="k" if target else "none", linewidths=2.5)
    demo, path = _cells(states, data["demo"]), _cells(states, learnt["path"])
    ax.plot(demo[:, 0], demo[:, 1], "--", color="darkorange", lw=2, label="bot's demonstration")
    ax.plot(demo[:1, 0], demo[:1, 1], "o", color="darkorange")
    ax.plot(path[:, 0] + 0.12, path[:, 1] + 0.12, "-", color="crimson", lw=2, label="learnt policy in the env")
    ax.plot(path[:1, 0] + 0.12, path[:1, 1] + 0.12, "o", color="crimson")
    ax.set_title(f"{name}: {'success' if learnt['success'] else 'failure'} ({len(learnt['path']) - 1} steps)", fontsize=9)
    ax.set_xticks([])
    ax.set_yticks([])


def plot_babyai_layout(data: dict, path: str | os.PathLike) -> str:
    """Draw :func:`babyai_figure_data`'s layout, one panel per learner; returns the file's path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(data["learners"])
    fig, axes = plt.subplots(1, len(names), figsize=(4.2 * len(names), 4.6))
    for ax, name in zip(np.atleast_1d(axes), names):
        _draw(ax, data, name)
    np.atleast_1d(axes)[0].legend(loc="lower left", fontsize=7, framealpha=0.9)
    fig.suptitle(f"{data['mission']!r}: test layout (seed {data['layout_seed']}), one demonstration; "
                 f"{data['n_tasks']} training layouts", fontsize=9)
    fig.tight_layout()
    path = os.fspath(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
