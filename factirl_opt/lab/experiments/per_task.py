"""The learners of the world with a map per task, and their scores on maps never seen.

In the world ``"objectworld-per-task"`` (:func:`.worlds.objectworld_per_task`) every task has
its own map, its own features ``Phi_i`` and its own true primitives, with the same columns on
every map, so every learner here learns *feature weights* and a reward is ``R_i = Phi_i w_i``
(docs/maths.md §7): GradIRL on per-task features (flat), FactIRL with ``w_i = D h_i``
(factorial, docs/maths.md §8), fitted over the tasks' own MDPs
(``fit(mdps, demos)`` with one feature matrix per task) and transferred to test tasks on maps
of their own (``FactIRL.transfer(mdps, demos, features=...)``).

Each builder returns a :class:`WeightsFit`: the rewards on the tasks' own maps (scored by the
runner like any other learner) and the weights, which :func:`add_new_map_scores` carries to
*fresh maps* of the same tasks (:meth:`.worlds.GroundTruth.fresh`: same true coefficients, new
objects; :func:`factirl_opt.feature_rewards`) and scores there with
:func:`factirl_opt.deviation`: ELIRL's and Levine's transfer score. The result rows get the
columns ``new_maps_deviation`` (mean over the tasks) and ``new_maps_deviation_std``.

Line-up ``"objectworld-per-task"``, train and test (one demonstration per test task):
``flat, features`` and ``flat MCE, features`` (GradIRL on the map's features, policy matching
and MCE); ``factorial, features`` and ``factorial MCE, features`` (FactIRL from the PCA of the
flat weights of the same objective; on test, the transfer of the training dictionary);
``factorial, features, random init`` and ``factorial MCE, features, random init`` (and their
transfers); ``flat, ground truth`` (GradIRL on the map's true primitives: the floor).
"""

from __future__ import annotations

import collections
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...evaluation import deviation
from ...objectives.sharding import Execution
from ...learners.factirl import FactIRL
from ...learners.gradirl import GradIRL
from ...datasets.objectworld import state_action_rewards
from ...tasks.features import feature_rewards
from .learner_names import (ADAPTIVE_FEATURES, FACTORIAL_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT, FACTORIAL_MCE_FEATURES,
                            FACTORIAL_MCE_FEATURES_RANDOM_INIT, FLAT_FEATURES, FLAT_GROUND_TRUTH, FLAT_MCE_FEATURES)
from .learner_solvers import factorial_options, flat_solver

__all__ = ["WeightsFit", "NEW_MAP_COLUMNS", "FEATURES", "PRIMITIVES", "add_new_map_scores", "per_task_rows",
           "per_task_sharing_rows",
           "flat_map_features", "flat_map_primitives", "factorial_map_features", "factorial_map_features_random_init",
           "transfer_map_features"]

#: what a builder of this module returns: the :class:`.learners.Fit` fields, the learnt feature
#: weights (n, p) and what they weight (:data:`FEATURES` or :data:`PRIMITIVES` of the maps)
WeightsFit = collections.namedtuple("WeightsFit", "rewards loss n_evaluations weights on")

#: the weights are on the maps' base features (Levine's discrete distance features)
FEATURES = "features"
#: the weights are on the maps' true primitives
PRIMITIVES = "primitives"

#: the result rows' columns added by :func:`add_new_map_scores`
NEW_MAP_COLUMNS = ("new_maps_deviation", "new_maps_deviation_std")


def _map_columns(maps: Any, on: str) -> list:
    """The per-task feature matrices the weights ``on`` apply to: each map's features or true primitives."""
    return list(maps.features if on == FEATURES else maps.primitives)


def _flat(gt: Any, preset: Any, ctx: Any, on: str) -> WeightsFit:
    split = ctx.split
    solver, _ = flat_solver(ctx.learner, preset)
    model = GradIRL(beta=preset.beta, features=_map_columns(gt.task_maps[split], on), max_iter=preset.flat_max_iter,
                    gtol=preset.flat_gtol, stol=preset.flat_stol, solver=solver, objective=ctx.learner.objective,
                    execution=Execution(planner=preset.planner))
    model.fit(gt.mdps(split), gt.demos(split))
    return WeightsFit(model.rewards_, model.loss_, model.n_evaluations_, model.weights_, on)


def flat_map_features(gt: Any, preset: Any, ctx: Any) -> WeightsFit:
    """GradIRL on each task's map features (the row's objective)."""
    return _flat(gt, preset, ctx, FEATURES)


def flat_map_primitives(gt: Any, preset: Any, ctx: Any) -> WeightsFit:
    """GradIRL on each task's true primitives (the floor)."""
    return _flat(gt, preset, ctx, PRIMITIVES)


def _factorial(gt: Any, preset: Any, ctx: Any, init: str, flat: str | None = None) -> WeightsFit:
    """FactIRL on the training maps' features, kept in ``ctx.models`` under the row's name for its transfer.

    ``init="pca"`` starts from the rewards learnt by the training row ``flat`` (their feature
    weights, docs/maths.md §8 PCA start); ``"random"`` from a random start.
    """
    rng = ctx.rngs["pca" if init == "pca" else "random_init"]
    model = FactIRL(rng=rng, features=_map_columns(gt.task_maps["train"], FEATURES),
                    **factorial_options(preset, ctx.spec.solvers, ctx.learner.objective,
                                      ctx.learner.adaptive, features=True, init=init))
    model.fit(gt.mdps("train"), gt.train_demos, flat_rewards=None if flat is None else ctx.rewards["train", flat])
    ctx.models[ctx.learner.name] = model
    weights = model.coefficients_ @ model.dictionary_.T + model.residuals_  # w_i = D h_i + delta_i
    return WeightsFit(model.rewards_, model.loss_, model.n_evaluations_, weights, FEATURES)


def factorial_map_features(gt: Any, preset: Any, ctx: Any) -> WeightsFit:
    """FactIRL from the PCA of the flat weights of the same objective (``flat, features`` or ``flat MCE, features``)."""
    flat = FLAT_MCE_FEATURES if ctx.learner.objective == "mce" else FLAT_FEATURES
    return _factorial(gt, preset, ctx, "pca", flat)


def factorial_map_features_random_init(gt: Any, preset: Any, ctx: Any) -> WeightsFit:
    """FactIRL on the training maps' features from a random start."""
    return _factorial(gt, preset, ctx, "random")


def transfer_map_features(gt: Any, preset: Any, ctx: Any) -> WeightsFit:
    """``FactIRL.transfer`` of the training row of the same name to the test tasks, on their own maps."""
    model = ctx.models[ctx.learner.name]
    H = model.transfer(gt.mdps("test"), gt.test_demos, features=_map_columns(gt.task_maps["test"], FEATURES))
    return WeightsFit(model.transfer_rewards_, model.transfer_loss_, model.transfer_n_evaluations_,
                      H @ model.dictionary_.T + model.transfer_residuals_, FEATURES)


def per_task_rows(learner_type: Any) -> tuple:
    """The rows of the line-up ``"objectworld-per-task"`` (see the module docstring), as ``learner_type`` instances.

    ``learner_type`` is :class:`.learners.Learner` (passed in, so this module does not import
    the line-ups' module, which registers these rows).
    """
    L, feats, fact = learner_type, "flat features", "factorial"
    flats = [(FLAT_FEATURES, "policy-matching"), (FLAT_MCE_FEATURES, "mce")]
    facts = [(FACTORIAL_FEATURES, "policy-matching", factorial_map_features, FLAT_FEATURES),
             (FACTORIAL_FEATURES_RANDOM_INIT, "policy-matching", factorial_map_features_random_init, None),
             (FACTORIAL_MCE_FEATURES, "mce", factorial_map_features, FLAT_MCE_FEATURES),
             (FACTORIAL_MCE_FEATURES_RANDOM_INIT, "mce", factorial_map_features_random_init, None)]
    train = [L("train", name, flat_map_features, objective=obj, solvers=feats) for name, obj in flats]
    train.append(L("train", FLAT_GROUND_TRUTH, flat_map_primitives, solvers=feats))
    train += [L("train", name, build, objective=obj, solvers=fact, needs=(("train", flat),) if flat else ())
              for name, obj, build, flat in facts]
    test = [L("test", name, flat_map_features, objective=obj, solvers=feats, per_seed=True) for name, obj in flats]
    test += [L("test", name, transfer_map_features, objective=obj, solvers=fact, needs=(("train", name),))
             for name, obj, _, _ in facts]
    test.append(L("test", FLAT_GROUND_TRUTH, flat_map_primitives, solvers=feats, per_seed=True))
    return tuple(train + test)


def per_task_sharing_rows(learner_type: Any) -> tuple:
    """The rows of the line-up ``"objectworld-per-task-sharing"`` ("which learner when"), as
    ``learner_type`` instances: ``flat, features``, ``factorial, features`` (the preset's k) and
    ``adaptive, features`` (k and the residual penalty chosen by validation), both factorial
    learners from the PCA of the flat weights; train, and test from one demonstration.
    """
    L, feats, fact, flat = learner_type, "flat features", "factorial", (("train", FLAT_FEATURES),)
    return (L("train", FLAT_FEATURES, flat_map_features, solvers=feats),
            L("train", FACTORIAL_FEATURES, factorial_map_features, solvers=fact, needs=flat),
            L("train", ADAPTIVE_FEATURES, factorial_map_features, solvers=fact, needs=flat, adaptive=True),
            L("test", FLAT_FEATURES, flat_map_features, solvers=feats, per_seed=True),
            L("test", FACTORIAL_FEATURES, transfer_map_features, solvers=fact, needs=(("train", FACTORIAL_FEATURES),)),
            L("test", ADAPTIVE_FEATURES, transfer_map_features, solvers=fact, needs=(("train", ADAPTIVE_FEATURES),),
              adaptive=True))


def add_new_map_scores(gt: Any, preset: Any, fits: dict, rows: Sequence[dict]) -> None:
    """Score every row's learnt weights on fresh maps of its tasks; adds :data:`NEW_MAP_COLUMNS` to ``rows``.

    Parameters
    ----------
    gt : GroundTruth
        Of a world with a map per task (``gt.task_maps``).
    preset : Preset
        Its planner plans the scores.
    fits : dict
        ``(split, learner name) -> WeightsFit`` of the run's rows.
    rows : list of dict
        The run's result rows (``split``, ``learner``), updated in place.
    """
    for split in ("train", "test"):
        names = [r["learner"] for r in rows if r["split"] == split]
        if not names:
            continue
        fresh = gt.fresh(split)
        mdps = list(fresh.mdps)
        true = state_action_rewards(fresh.rewards, mdps[0].n_actions)
        for row in (r for r in rows if r["split"] == split):
            fit = fits[split, row["learner"]]
            learnt = feature_rewards(_map_columns(fresh, fit.on), np.asarray(fit.weights), mdps)
            dev = deviation(mdps, true, learnt, planner=preset.planner)
            row.update(new_maps_deviation=float(np.mean(dev)), new_maps_deviation_std=float(np.std(dev)))
