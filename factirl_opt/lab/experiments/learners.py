"""The learners of the experiments, as data: named line-ups of builders.

A *line-up* is an ordered table of :class:`Learner` rows ``(split, name, build, version,
needs, per_seed, objective, solvers)``, named by the constants of :mod:`.learner_names`.
``build(gt, preset, ctx)`` fits one learner on the ground truth's ``split`` tasks and
returns a :class:`Fit` (learnt rewards, final loss per task, Q* evaluations); the runner times
and scores it. Rows run in table order and share a :class:`RunContext` (the run's solver
settings, random streams, and what earlier rows learnt), so a learner that builds on another
(the factorial transfer on the factorial fit) names it in ``needs``. A new learner (another
objective, features, another D-step solver) is a new row or a new line-up, not a new code
path; bump a builder's ``version`` when its behaviour changes, so cached runs made with the
old one are recomputed (:mod:`.store`).

Line-up ``"paper"`` (the paper's section 4, names as in the paper):

train tasks (``split = "train"``)
    ``flat`` (GradIRL, tabular); ``flat, ground truth`` (GradIRL with the true dictionary as
    features); ``flat, PCA features`` (GradIRL with the first ``n_pca_components`` components
    of the uncentred PCA of the flat rewards); ``factorial`` (FactIRL initialised by that PCA,
    the paper's heuristic, reusing the flat rewards); ``factorial, random init``.
test tasks (``split = "test"``, one demonstration each)
    ``flat`` (from scratch); ``factorial`` (``FactIRL.transfer`` with the dictionary learnt by
    ``factorial``); ``flat, features from ex.`` (GradIRL with ``n_features_from_examples``
    learnt flat training rewards, chosen at random, as features); ``flat, PCA features`` (the
    training PCA components); ``flat, ground truth`` (the floor).

Line-up ``"objectworld"`` (the world's base features are Levine's discrete distance
features, the true dictionary ELIRL's primitives):

train tasks
    ``flat`` (GradIRL, tabular); ``flat, features`` (GradIRL on the base features); ``flat,
    ground truth`` (GradIRL with the true primitives as features: the floor); ``factorial``
    (FactIRL, tabular, from the PCA of ``flat``); ``factorial, features`` (FactIRL with
    ``R_i = Phi D h_i`` on the base features, from the PCA of the feature weights of ``flat,
    features``); ``factorial, features, random init``.
test tasks (one demonstration each)
    ``flat``; ``flat, features``; ``factorial`` and ``factorial, features`` (``transfer`` of
    the training dictionaries); ``flat, ground truth``.

Line-ups ``"paper+mce"`` and ``"objectworld+mce"``: the line-up, plus a flat and a
factorial learner on the maximum causal entropy likelihood (``objective="mce"``), train and
test: ``flat MCE`` (GradIRL), ``factorial MCE`` (FactIRL from the PCA of ``flat MCE``'s
rewards; its ``transfer`` on the test tasks); on Objectworld both on the base features
(``flat MCE, features``, ``factorial MCE, features``). The Gauss-Newton solvers need a
least-squares objective: where a run names one, the MCE learners take L-BFGS steps
(:data:`GRADIENT_FALLBACK`), and :func:`substitutions` names every such replacement before the
runs start (the command line prints it and the manifest records it).

Line-ups ``"sharing"`` (the grid) and ``"objectworld-sharing"`` (Objectworld, one map): "which
learner when", the flat learner, the factorial learner with the preset's k, and the *adaptive*
learner (``FactIRL(n_primitives="auto", residual_penalty="auto")``: k and the residual penalty
chosen by validation, :mod:`factirl_opt.learners.selection`), each from the same flat start,
train and test (``transfer`` from one demonstration): ``flat``, ``factorial``, ``adaptive`` on
the grid; ``flat, features``, ``factorial, features``, ``adaptive, features`` on Objectworld.
The same three on the worlds with a task per map and on BabyAI: ``"objectworld-per-task-sharing"``
(:func:`.per_task.per_task_sharing_rows`) and ``"babyai-sharing"`` (:data:`.babyai.SHARING_LINEUP`).

Line-up ``"objectworld-per-task"`` (the world with a map per task; every learner on feature
weights, scored on its tasks' own maps and on fresh maps): see :mod:`.per_task`.
Line-up ``"babyai"`` (the BabyAI worlds: a layout per task, its own features) is defined by
:mod:`.babyai`; :data:`LINEUPS` lists it with the others. The row types are in :mod:`.lineup`.

Figure 3 shows the value functions of the line-up's ``value_maps`` test learners.
"""

from __future__ import annotations

import numpy as np

from ...objectives.sharding import Execution
from ...exceptions import ValidationError
from ...learners.factirl import FactIRL, pca_dictionary
from ...learners.gradirl import GradIRL
from .learner_solvers import (DEFAULT_OBJECTIVE, GRADIENT_FALLBACK, SOLVER_ROLES, factorial_options, factorial_solvers,
                              flat_solver, substitutions)
from .babyai import LINEUP as BABYAI_LINEUP, SHARING_LINEUP as BABYAI_SHARING_LINEUP
from .lineup import STREAMS, Fit, Learner, Lineup, RunContext
from .per_task import per_task_rows, per_task_sharing_rows
from .learner_names import (ADAPTIVE, ADAPTIVE_FEATURES, FACTORIAL, FACTORIAL_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT, FACTORIAL_MCE,
                            FACTORIAL_MCE_FEATURES, FACTORIAL_RANDOM_INIT, FLAT, FLAT_FEATURES,
                            FLAT_FEATURES_FROM_EXAMPLES, FLAT_GROUND_TRUTH, FLAT_MCE, FLAT_MCE_FEATURES,
                            FLAT_PCA_FEATURES)

__all__ = ["Fit", "Learner", "Lineup", "LINEUPS", "RunContext", "get_lineup", "factorial_options", "flat_solver", "transfer",
           "factorial_solvers", "substitutions", "SOLVER_ROLES", "GRADIENT_FALLBACK", "DEFAULT_OBJECTIVE"]

# --- builders: (gt, preset, ctx) -> Fit; the row being built is ctx.learner -----------------


def _gradirl(gt, preset, ctx, features=None):
    solver, _ = flat_solver(ctx.learner, preset)
    model = GradIRL(beta=preset.beta, features=features, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol,
                    stol=preset.flat_stol, solver=solver, objective=ctx.learner.objective,
                    execution=Execution(planner=preset.planner))
    model.fit(gt.mdp, gt.demos(ctx.split))
    return Fit(model.rewards_, model.loss_, model.n_evaluations_)


def _pca_features(gt, preset, ctx):
    """The first components of the uncentred PCA of the flat training rewards, (S*A, k)."""

    def make():
        flat_rewards = ctx.rewards["train", FLAT]
        d = gt.mdp.n_params
        D, _ = pca_dictionary(flat_rewards.reshape(flat_rewards.shape[0], d), min(preset.n_pca_components, d),
                              rng=ctx.rngs["pca"])
        return D

    return ctx.shared("pca_features", make)


def flat(gt, preset, ctx):
    """GradIRL, tabular rewards."""
    return _gradirl(gt, preset, ctx)


def flat_ground_truth(gt, preset, ctx):
    """GradIRL with the true dictionary as features (the floor)."""
    return _gradirl(gt, preset, ctx, gt.dictionary)


def flat_pca_features(gt, preset, ctx):
    """GradIRL with the PCA components of the flat training rewards as features."""
    return _gradirl(gt, preset, ctx, _pca_features(gt, preset, ctx))


def flat_features_from_examples(gt, preset, ctx):
    """GradIRL with ``n_features_from_examples`` learnt flat training rewards as features."""
    flat_train = ctx.rewards["train", FLAT]
    n = flat_train.shape[0]
    n_ex = min(preset.n_features_from_examples, n)
    chosen = np.sort(ctx.rngs["examples"].choice(n, size=n_ex, replace=False))
    return _gradirl(gt, preset, ctx, flat_train[chosen].reshape(n_ex, gt.mdp.n_params).T)


def flat_features(gt, preset, ctx):
    """GradIRL on the world's base features (Objectworld: the discrete distance features)."""
    return _gradirl(gt, preset, ctx, gt.features)


def _fit_factorial(gt, preset, ctx, init, flat=None, features=None):
    """Fit a FactIRL on the training tasks, keep it in ``ctx.models`` (under the row's name) for its transfer.

    ``init="pca"`` starts from the uncentred PCA of the rewards learnt by the training row
    ``flat`` (random stream ``"pca"``); ``init="random"`` from a random start (stream
    ``"random_init"``). ``features``: the base features of ``R_i = Phi D h_i`` (None: tabular).
    """
    rng = ctx.rngs["pca" if init == "pca" else "random_init"]
    model = FactIRL(rng=rng, features=features,
                    **factorial_options(preset, ctx.spec.solvers, ctx.learner.objective, ctx.learner.adaptive,
                                      features=features is not None, init=init))
    model.fit(gt.mdp, gt.train_demos, flat_rewards=None if flat is None else ctx.rewards["train", flat])
    ctx.models[ctx.learner.name] = model
    return Fit(model.rewards_, model.loss_, model.n_evaluations_)


def _transfer(gt, ctx, name):
    """``FactIRL.transfer`` of the dictionary of the fitted model ``name`` to the test tasks."""
    model = ctx.models[name]
    model.transfer(gt.mdp, gt.test_demos)
    return Fit(model.transfer_rewards_, model.transfer_loss_, model.transfer_n_evaluations_)


def factorial(gt, preset, ctx):
    """FactIRL from the PCA of the flat training rewards (the paper's heuristic)."""
    return _fit_factorial(gt, preset, ctx, "pca", flat=FLAT)


def factorial_random_init(gt, preset, ctx):
    """FactIRL from a random start."""
    return _fit_factorial(gt, preset, ctx, "random")


def factorial_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the training dictionary to the test tasks."""
    return _transfer(gt, ctx, FACTORIAL)


def transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the training row of the same name to the test tasks."""
    return _transfer(gt, ctx, ctx.learner.name)


def factorial_features(gt, preset, ctx):
    """FactIRL on the world's base features, from the PCA of ``flat, features``'s weights."""
    return _fit_factorial(gt, preset, ctx, "pca", flat=FLAT_FEATURES, features=gt.features)


def factorial_features_random_init(gt, preset, ctx):
    """FactIRL on the world's base features from a random start."""
    return _fit_factorial(gt, preset, ctx, "random", features=gt.features)


def factorial_features_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the feature-space dictionary to the test tasks."""
    return _transfer(gt, ctx, FACTORIAL_FEATURES)


def factorial_mce(gt, preset, ctx):
    """FactIRL on the MCE likelihood, from the PCA of ``flat MCE``'s rewards."""
    return _fit_factorial(gt, preset, ctx, "pca", flat=FLAT_MCE)


def factorial_mce_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the MCE dictionary to the test tasks (MCE likelihood)."""
    return _transfer(gt, ctx, FACTORIAL_MCE)


def factorial_mce_features(gt, preset, ctx):
    """FactIRL on the MCE likelihood and the base features, from the PCA of ``flat MCE, features``."""
    return _fit_factorial(gt, preset, ctx, "pca", flat=FLAT_MCE_FEATURES, features=gt.features)


def factorial_mce_features_transfer(gt, preset, ctx):
    """``FactIRL.transfer`` of the MCE feature-space dictionary to the test tasks."""
    return _transfer(gt, ctx, FACTORIAL_MCE_FEATURES)


def _extended(learners, train, test):
    """A line-up's learners with more train rows after its train rows and test rows at the end."""
    return tuple(lr for lr in learners if lr.split == "train") + train + tuple(lr for lr in learners if lr.split == "test") + test


def _mce_rows(flat_name, fact_name, flat_build, flat_solvers, fact_build, transfer_build):
    """The train and test rows of a flat MCE learner and its factorial counterpart."""
    train = (Learner("train", flat_name, flat_build, solvers=flat_solvers, objective="mce"),
             Learner("train", fact_name, fact_build, needs=(("train", flat_name),), solvers="factorial", objective="mce"))
    test = (Learner("test", flat_name, flat_build, per_seed=True, solvers=flat_solvers, objective="mce"),
            Learner("test", fact_name, transfer_build, needs=(("train", fact_name),), solvers="factorial",
                    objective="mce"))
    return train, test


_TRAIN_FLAT = (("train", FLAT),)
_FEATURES, _FACTORIAL = "flat features", "factorial"

#: line-up name (a preset's ``lineup``) -> Lineup
LINEUPS = {
    "paper": Lineup(
        name="paper",
        learners=(
            Learner("train", FLAT, flat),
            Learner("train", FLAT_GROUND_TRUTH, flat_ground_truth, solvers=_FEATURES),
            Learner("train", FLAT_PCA_FEATURES, flat_pca_features, needs=_TRAIN_FLAT, solvers=_FEATURES),
            Learner("train", FACTORIAL, factorial, needs=_TRAIN_FLAT, solvers=_FACTORIAL),
            Learner("train", FACTORIAL_RANDOM_INIT, factorial_random_init, solvers=_FACTORIAL),
            Learner("test", FLAT, flat, per_seed=True),
            Learner("test", FACTORIAL, factorial_transfer, needs=(("train", FACTORIAL),), solvers=_FACTORIAL),
            Learner("test", FLAT_FEATURES_FROM_EXAMPLES, flat_features_from_examples, needs=_TRAIN_FLAT, solvers=_FEATURES),
            Learner("test", FLAT_PCA_FEATURES, flat_pca_features, needs=_TRAIN_FLAT, solvers=_FEATURES),
            Learner("test", FLAT_GROUND_TRUTH, flat_ground_truth, per_seed=True, solvers=_FEATURES),
        ),
        value_maps=(FLAT, FACTORIAL),
        one_mdp=True,
    ),
    "objectworld": Lineup(
        name="objectworld",
        learners=(
            Learner("train", FLAT, flat),
            Learner("train", FLAT_FEATURES, flat_features, solvers=_FEATURES),
            Learner("train", FLAT_GROUND_TRUTH, flat_ground_truth, solvers=_FEATURES),
            Learner("train", FACTORIAL, factorial, needs=_TRAIN_FLAT, solvers=_FACTORIAL),
            Learner("train", FACTORIAL_FEATURES, factorial_features, needs=(("train", FLAT_FEATURES),), solvers=_FACTORIAL),
            Learner("train", FACTORIAL_FEATURES_RANDOM_INIT, factorial_features_random_init, solvers=_FACTORIAL),
            Learner("test", FLAT, flat, per_seed=True),
            Learner("test", FLAT_FEATURES, flat_features, per_seed=True, solvers=_FEATURES),
            Learner("test", FACTORIAL, factorial_transfer, needs=(("train", FACTORIAL),), solvers=_FACTORIAL),
            Learner("test", FACTORIAL_FEATURES, factorial_features_transfer, needs=(("train", FACTORIAL_FEATURES),),
                    solvers=_FACTORIAL),
            Learner("test", FLAT_GROUND_TRUTH, flat_ground_truth, per_seed=True, solvers=_FEATURES),
        ),
        value_maps=(FLAT_FEATURES, FACTORIAL_FEATURES),
        worlds=("objectworld",),
    ),
}
LINEUPS["paper+mce"] = Lineup(
    name="paper+mce",
    learners=_extended(LINEUPS["paper"].learners,
                       *_mce_rows(FLAT_MCE, FACTORIAL_MCE, flat, "flat", factorial_mce, factorial_mce_transfer)),
    value_maps=(FLAT, FACTORIAL, FLAT_MCE, FACTORIAL_MCE),
    one_mdp=True,
)
LINEUPS["objectworld+mce"] = Lineup(
    name="objectworld+mce",
    learners=_extended(LINEUPS["objectworld"].learners,
                       *_mce_rows(FLAT_MCE_FEATURES, FACTORIAL_MCE_FEATURES, flat_features, "flat features",
                                  factorial_mce_features, factorial_mce_features_transfer)),
    value_maps=(FLAT_FEATURES, FACTORIAL_FEATURES, FLAT_MCE_FEATURES, FACTORIAL_MCE_FEATURES),
    worlds=("objectworld",),
)

LINEUPS["objectworld-per-task"] = Lineup(name="objectworld-per-task", learners=per_task_rows(Learner),
                                         worlds=("objectworld-per-task",))

LINEUPS[BABYAI_LINEUP.name] = BABYAI_LINEUP

LINEUPS["sharing"] = Lineup(
    name="sharing",
    learners=(
        Learner("train", FLAT, flat),
        Learner("train", FACTORIAL, factorial, needs=_TRAIN_FLAT, solvers=_FACTORIAL),
        Learner("train", ADAPTIVE, factorial, needs=_TRAIN_FLAT, solvers=_FACTORIAL, adaptive=True),
        Learner("test", FLAT, flat, per_seed=True),
        Learner("test", FACTORIAL, transfer, needs=(("train", FACTORIAL),), solvers=_FACTORIAL),
        Learner("test", ADAPTIVE, transfer, needs=(("train", ADAPTIVE),), solvers=_FACTORIAL, adaptive=True),
    ),
    value_maps=(FLAT, FACTORIAL, ADAPTIVE),
    one_mdp=True,
)
_TRAIN_FLAT_FEATURES = (("train", FLAT_FEATURES),)
LINEUPS["objectworld-sharing"] = Lineup(
    name="objectworld-sharing",
    learners=(
        Learner("train", FLAT_FEATURES, flat_features, solvers=_FEATURES),
        Learner("train", FACTORIAL_FEATURES, factorial_features, needs=_TRAIN_FLAT_FEATURES, solvers=_FACTORIAL),
        Learner("train", ADAPTIVE_FEATURES, factorial_features, needs=_TRAIN_FLAT_FEATURES, solvers=_FACTORIAL,
                adaptive=True),
        Learner("test", FLAT_FEATURES, flat_features, per_seed=True, solvers=_FEATURES),
        Learner("test", FACTORIAL_FEATURES, transfer, needs=(("train", FACTORIAL_FEATURES),), solvers=_FACTORIAL),
        Learner("test", ADAPTIVE_FEATURES, transfer, needs=(("train", ADAPTIVE_FEATURES),), solvers=_FACTORIAL,
                adaptive=True),
    ),
    value_maps=(FLAT_FEATURES, FACTORIAL_FEATURES, ADAPTIVE_FEATURES),
    worlds=("objectworld",),
)
LINEUPS["objectworld-per-task-sharing"] = Lineup(name="objectworld-per-task-sharing",
                                                 learners=per_task_sharing_rows(Learner),
                                                 worlds=("objectworld-per-task",))
LINEUPS[BABYAI_SHARING_LINEUP.name] = BABYAI_SHARING_LINEUP


def get_lineup(lineup: str | Lineup) -> Lineup:
    """A :class:`Lineup` from its name (or a Lineup, returned as is)."""
    if isinstance(lineup, Lineup):
        return lineup
    if isinstance(lineup, str) and lineup in LINEUPS:
        return LINEUPS[lineup]
    raise ValidationError(f"unknown learner line-up {lineup!r}; available: {', '.join(LINEUPS)}")
