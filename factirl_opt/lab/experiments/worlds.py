"""The worlds of the experiments: what one run's learners see and are scored against.

A *world* is a named recipe ``(preset, n_tasks, demos_per_task, seed) -> GroundTruth``: an
MDP, a true reward dictionary, training tasks with ``demos_per_task`` demonstrations each and
test tasks with one demonstration each. :data:`WORLDS` maps a preset's ``world`` field to its
recipe; a new world is one more entry.

``"grid"`` (the paper's section 4)
    :class:`factirl_opt.GridWorld` of the preset's size and dynamics; tasks drawn by
    :func:`factirl_opt.datasets.synthetic.synthetic_tasks` from a random dictionary (``D ~ N(0, 1)``;
    coefficients ``N(0, 1)`` or ``|N(0, 1)|``). No base features.
``"objectworld"`` (the multi-task Objectworld of ELIRL, Mendez et al. 2018)
    :func:`factirl_opt.datasets.objectworld.make_objectworld` with ``N = grid_size``, ``c1 = n_primitives`` inner
    colours, ``c2 = n_outer_colours`` outer colours, ``object_density``, ``determinism =
    p_success`` and ``gamma``; tasks drawn by ELIRL's rule
    (:func:`factirl_opt.datasets.objectworld.multitask_rewards`: 2-4 inner colours per task, weights
    ``5 (3u - 2)``, reward ``sum_c w_c 1[distance to colour c < 3]``), state rewards repeated
    over the 5 actions; the true dictionary is the c1 primitives ``1[distance to colour c < 3]``
    (S, c1); the base features are Levine's discrete features (S, (N-1)(c1+c2))
    (:func:`factirl_opt.datasets.objectworld.objectworld_features`). Demonstrations of the greedy expert
    (:func:`factirl_opt.sample_demonstrations`, uniform start states), planned with the
    preset's planner. ``coefficient_kind`` is not used.

``"objectworld-per-task"`` (ELIRL's benchmark as its script ``multitask_transfer_objectworld.m`` runs it)
    Every task on its *own* map (:func:`factirl_opt.datasets.objectworld.maps`: the objects placed anew
    per task, the same size, colours, density and dynamics as ``"objectworld"``), its own
    discrete features (S, (N-1)(c1+c2)) and true primitives, coefficients by ELIRL's rule; the
    test tasks on further maps never seen in training, one demonstration each. Every map has
    the same dynamics, so the tasks of a split share one MDP object (planned as one batch).
    Each split's tasks are also scored on *fresh maps* (:meth:`GroundTruth.fresh`,
    :func:`factirl_opt.datasets.objectworld.fresh_maps`: the same coefficients on newly drawn maps), where a learnt
    reward is carried as feature weights: ELIRL's and Levine's "transfer" score. Protocol
    differences with ELIRL's script: the greedy expert demonstrates (ELIRL samples the
    soft-optimal policy at temperature 1), no bias column, every colour present on every map.
    Streams: training maps and coefficients, test maps and coefficients, training
    demonstrations, test demonstrations, learners, training fresh maps, test fresh maps.
``"babyai"`` and ``"babyai-large"`` (BabyAI GoTo levels: a layout per task, the bot's demonstrations)
    See :func:`babyai_world`: their ground truth is a :class:`~factirl_opt.datasets.babyai.BabyAITasks` (per-task
    MDPs, features and mission rewards), which scores the learners itself, in the environment.

Randomness: the run's seed makes a ``numpy.random.SeedSequence`` whose spawned children feed
independent streams, in this order: dictionary (Objectworld: the object layout), training
coefficients, test coefficients, training demonstrations, test demonstrations, learners
(random initialisation, choice of the ``features from ex.``; see :mod:`.learners`). So, for one
seed, every point of a sweep shares the same dictionary (world) and the same test tasks (with
the same demonstrations), and the training tasks of a smaller point are the first ones of a
larger point (paired comparisons across the sweep); nothing depends on which process runs what.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from ...tasks.demonstrations import sample_demonstrations
from ...exceptions import ValidationError
from ...mdp.tabular import GridWorld, TabularMDP
from ...datasets.objectworld import MOVES, make_objectworld, multitask_rewards, objectworld_features, state_action_rewards
from ...datasets.objectworld.maps import fresh_maps, objectworld_maps
from ...datasets.synthetic import random_dictionary, synthetic_tasks
from ...datasets.babyai import BabyAITasks, babyai_tasks

__all__ = ["GroundTruth", "WORLDS", "make_ground_truth", "grid_world", "objectworld", "objectworld_per_task", "N_STREAMS"]

#: children spawned from a run's SeedSequence (see the module docstring for their order)
N_STREAMS = 6
SPLITS = ("train", "test")


@dataclasses.dataclass
class GroundTruth:
    """Everything a run's learners see or are scored against.

    Attributes
    ----------
    mdp : TabularMDP
    dictionary : ndarray, shape (S*A, k) or (S, k)
        The true primitive rewards (state primitives are repeated over actions by the learners
        that take them as features).
    train_rewards : ndarray, shape (n_tasks, S, A)
    train_demos : list of n_tasks int arrays, each (demos_per_task, L, 2)
    test_rewards : ndarray, shape (n_test_tasks, S, A)
    test_demos : list of n_test_tasks int arrays, each (1, L, 2)
    learner_rng : numpy.random.Generator
        Parent of the learners' random streams (:class:`.learners.RunContext`).
    features : ndarray, shape (S*A, p) or (S, p), or None
        The world's base features (Objectworld: the discrete distance features); None when
        the world has none.
    map_extras : dict
        What the value-map figure needs besides the values, as plain JSON values (Objectworld:
        ``objects``, ``n_inner``, ``n_outer`` and the actions' ``moves``); empty for the grid.
    task_maps : dict
        Worlds with a map per task: ``split -> ObjectWorldMaps`` (:func:`factirl_opt.datasets.objectworld.maps`),
        each task's MDP, features and true primitives; empty when every task lives in ``mdp``.
    fresh_seeds : dict
        Worlds with a map per task: ``split -> SeedSequence`` of the fresh maps the learnt
        rewards are also scored on (:meth:`fresh`).
    """

    mdp: TabularMDP
    dictionary: np.ndarray
    train_rewards: np.ndarray
    train_demos: list
    test_rewards: np.ndarray
    test_demos: list
    learner_rng: np.random.Generator
    features: np.ndarray | None = None
    map_extras: dict = dataclasses.field(default_factory=dict)
    task_maps: dict = dataclasses.field(default_factory=dict)
    fresh_seeds: dict = dataclasses.field(default_factory=dict)

    def demos(self, split):
        """Demonstrations of the ``"train"`` or ``"test"`` tasks."""
        return self.train_demos if _check_split(split) == "train" else self.test_demos

    def rewards(self, split):
        """True rewards (n, S, A) of the ``"train"`` or ``"test"`` tasks."""
        return self.train_rewards if _check_split(split) == "train" else self.test_rewards

    def mdps(self, split):
        """The MDP the ``split`` tasks are fitted and scored on: ``mdp``, or one per task (a list)."""
        maps = self.task_maps.get(_check_split(split))
        return self.mdp if maps is None else list(maps.mdps)

    def fresh(self, split):
        """The ``split`` tasks on maps never seen (same true coefficients; :func:`factirl_opt.datasets.objectworld.fresh_maps`).

        Drawn anew at each call, from the split's fresh-map seed (same maps every time).
        """
        if _check_split(split) not in self.task_maps:
            raise ValidationError("this world has one map for every task: it has no fresh maps")
        seq = self.fresh_seeds[split]  # a copy: spawning from the maps' generator advances its SeedSequence
        return fresh_maps(self.task_maps[split], rng=np.random.SeedSequence(seq.entropy, spawn_key=seq.spawn_key))


def _check_split(split):
    if split not in SPLITS:
        raise ValidationError(f"split must be 'train' or 'test'; got {split!r}")
    return split


def grid_world(preset, n_tasks, demos_per_task, seed):
    """The paper's world: a noisy grid and tasks mixing random primitive rewards.

    Parameters
    ----------
    preset : Preset
    n_tasks : int
        Training tasks.
    demos_per_task : int
        Demonstrations of each training task (test tasks get one each).
    seed : int
        Entropy of the run's SeedSequence.

    Returns
    -------
    GroundTruth
    """
    mdp = GridWorld(size=preset.grid_size, p_success=preset.p_success, gamma=preset.gamma)
    S, A, k = mdp.n_states, mdp.n_actions, preset.n_primitives
    s_dict, s_train, s_test, s_train_demo, s_test_demo, s_learn = np.random.SeedSequence(seed).spawn(N_STREAMS)
    D = random_dictionary(S * A, k, rng=np.random.default_rng(s_dict))
    kw = dict(dictionary=D, kind=preset.coefficient_kind, planner=preset.planner)
    train = synthetic_tasks(mdp, n_tasks, demos_per_task, preset.demo_length, rng=s_train, demo_rng=s_train_demo, **kw)
    test = synthetic_tasks(mdp, preset.n_test_tasks, 1, preset.demo_length, rng=s_test, demo_rng=s_test_demo, **kw)
    return GroundTruth(mdp, D, train.rewards, train.demos, test.rewards, test.demos, np.random.default_rng(s_learn))


def objectworld(preset, n_tasks, demos_per_task, seed):
    """The multi-task Objectworld (ELIRL's benchmark; see the module docstring).

    Parameters
    ----------
    preset : Preset
    n_tasks : int
        Training tasks.
    demos_per_task : int
        Demonstrations of each training task (test tasks get one each).
    seed : int
        Entropy of the run's SeedSequence.

    Returns
    -------
    GroundTruth
        With ``dictionary`` the true primitives (S, c1), ``features`` the discrete features
        (S, (N-1)(c1+c2)) and the world's objects in ``map_extras``.
    """
    s_world, s_train, s_test, s_train_demo, s_test_demo, s_learn = np.random.SeedSequence(seed).spawn(N_STREAMS)
    world = make_objectworld(preset.grid_size, preset.n_primitives, preset.n_outer_colours, preset.object_density,
                             determinism=preset.p_success, gamma=preset.gamma, rng=np.random.default_rng(s_world))
    mdp = world.mdp()
    split = {}
    for name, n, m, s_tasks, s_demos in (("train", n_tasks, demos_per_task, s_train, s_train_demo),
                                         ("test", preset.n_test_tasks, 1, s_test, s_test_demo)):
        rewards, _, primitives = multitask_rewards(world, n, rng=np.random.default_rng(s_tasks))
        R = state_action_rewards(rewards, mdp.n_actions)
        split[name] = (R, sample_demonstrations(mdp, R, m, preset.demo_length, rng=np.random.default_rng(s_demos),
                                                planner=preset.planner))
    extras = dict(objects=world.objects.tolist(), n_inner=world.n_inner, n_outer=world.n_outer, moves=MOVES.tolist())
    return GroundTruth(mdp, primitives, *split["train"], *split["test"], np.random.default_rng(s_learn),
                       features=objectworld_features(world), map_extras=extras)


#: children spawned from the SeedSequence of a run in the world with a map per task
N_PER_TASK_STREAMS = 7


def objectworld_per_task(preset, n_tasks, demos_per_task, seed):
    """Objectworld with a map per task, as ELIRL's benchmark script draws it (see the module docstring).

    Parameters
    ----------
    preset : Preset
    n_tasks : int
        Training tasks (each on its own map).
    demos_per_task : int
        Demonstrations of each training task (test tasks, on maps of their own, get one each).
    seed : int
        Entropy of the run's SeedSequence.

    Returns
    -------
    GroundTruth
        ``task_maps`` holds the training and test tasks' :class:`~factirl_opt.datasets.objectworld.ObjectWorldMaps`
        (``mdp`` is the training maps' shared MDP, ``dictionary`` the training maps' true
        primitives, ``features`` None: the features are per task) and ``fresh_seeds`` the
        seeds of their fresh maps.
    """
    streams = np.random.SeedSequence(seed).spawn(N_PER_TASK_STREAMS)
    s_train, s_test, s_train_demo, s_test_demo, s_learn, s_train_fresh, s_test_fresh = streams
    kw = dict(size=preset.grid_size, n_inner=preset.n_primitives, n_outer=preset.n_outer_colours,
              object_density=preset.object_density, determinism=preset.p_success, gamma=preset.gamma)
    split, maps = {}, {}
    for name, n, m, s_maps, s_demos in (("train", n_tasks, demos_per_task, s_train, s_train_demo),
                                        ("test", preset.n_test_tasks, 1, s_test, s_test_demo)):
        maps[name] = objectworld_maps(n, rng=np.random.default_rng(s_maps), **kw)
        mdps = list(maps[name].mdps)
        R = state_action_rewards(maps[name].rewards, mdps[0].n_actions)
        split[name] = (R, sample_demonstrations(mdps, R, m, preset.demo_length, rng=np.random.default_rng(s_demos),
                                                planner=preset.planner))
    return GroundTruth(maps["train"].mdps[0], maps["train"].primitives, *split["train"], *split["test"],
                       np.random.default_rng(s_learn), task_maps=maps, fresh_seeds=dict(train=s_train_fresh, test=s_test_fresh))


#: world name -> BabyAI level (:data:`factirl_opt.datasets.babyai.GOTO_LEVELS`)
BABYAI_LEVELS = {"babyai": "BabyAI-GoToLocal-v0", "babyai-large": "BabyAI-GoToOpen-v0"}


def babyai_world(preset: Any, n_tasks: int, demos_per_task: int, seed: int) -> BabyAITasks:
    """BabyAI-GoToLocal-v0 layouts with the bot's demonstrations (:func:`factirl_opt.datasets.babyai.babyai_tasks`).

    Parameters
    ----------
    preset : Preset
        Uses ``n_test_tasks`` and ``gamma``.
    n_tasks : int
        Training layouts.
    demos_per_task : int
        Bot episodes per training layout (the first from the start, the others from random starts).
    seed : int
        Entropy of the run's SeedSequence.

    Returns
    -------
    BabyAITasks
    """
    return babyai_tasks(BABYAI_LEVELS["babyai"], n_tasks, demos_per_task, n_test_tasks=preset.n_test_tasks,
                        gamma=preset.gamma, seed=seed)


def babyai_large_world(preset: Any, n_tasks: int, demos_per_task: int, seed: int) -> BabyAITasks:
    """BabyAI-GoToOpen-v0 layouts (about 1,250 states each); otherwise as :func:`babyai_world`."""
    return babyai_tasks(BABYAI_LEVELS["babyai-large"], n_tasks, demos_per_task, n_test_tasks=preset.n_test_tasks,
                        gamma=preset.gamma, seed=seed)


#: world name (a preset's ``world``) -> recipe ``(preset, n_tasks, demos_per_task, seed) -> GroundTruth``
WORLDS = {"grid": grid_world, "objectworld": objectworld, "objectworld-per-task": objectworld_per_task,
          "babyai": babyai_world, "babyai-large": babyai_large_world}
#: the worlds whose tasks each have their own MDP (no ``GroundTruth.mdp`` shared by every task)
PER_TASK_WORLDS = ("objectworld-per-task", "babyai", "babyai-large")


def make_ground_truth(preset, n_tasks, demos_per_task, seed):
    """Generate the ground truth of the run ``(preset, n_tasks, demos_per_task, seed)`` in the preset's world."""
    try:
        world = WORLDS[preset.world]
    except KeyError:
        raise ValidationError(f"unknown world {preset.world!r}; available: {', '.join(WORLDS)}") from None
    return world(preset, n_tasks, demos_per_task, seed)
