"""The BabyAI world of the experiments: layouts read from the simulator, the BabyAI bot's
demonstrations, and success judged by the environment itself.

A run's tasks are BabyAI layouts (``env.reset(seed=...)`` of a GoTo level), each its own
tabular MDP with its own state features (:func:`factirl_opt.adapters.minigrid.from_minigrid`: the
agent's reachable ``(x, y, direction)``, the 127 features, same columns in every layout) and
its own mission ("go to the red key"). Worlds (a preset's ``world``):

``"babyai"``
    ``BabyAI-GoToLocal-v0``: one 8x8 room, 8 objects, about 112 states per layout.
``"babyai-large"``
    ``BabyAI-GoToOpen-v0``: 3x3 rooms with open doors (22x22), about 1,250 states per layout.

The tasks, their protocol and their scores are the library's :func:`factirl_opt.datasets.babyai.babyai_tasks`
(:class:`~factirl_opt.datasets.babyai.BabyAITasks`); :mod:`.worlds` builds them from a preset. A GoToLocal bot
episode is a few steps long (the target is in sight), so the extra training starts show the mission from
elsewhere. ``demo_length``, ``p_success``, ``grid_size`` and the dictionary fields of the preset are not used:
the bot ends its episodes, the dynamics are the simulator's.

Learners (line-ups ``"babyai"``; :data:`.learners.LINEUPS`)
----------------------------------------------------------
Every learner fits feature weights ``R_i(s, a) = Phi_i(s) w_i`` with the layout's own
features ``Phi_i`` (docs/maths.md §7), except ``flat`` (tabular). Train: ``flat, features``
and ``flat MCE, features`` (GradIRL, policy matching and maximum causal entropy, docs/maths.md
§5-6), ``factorial, features`` and ``factorial MCE, features`` (FactIRL ``R_i = Phi_i D h_i``
from the PCA of the flat weights, docs/maths.md §8). Test, from the ONE demonstration of
each new layout: ``flat`` (GradIRL on tabular rewards of that layout: a tabular reward is
tied to one layout's states, so nothing learnt in training carries over; it is fitted from
the one demonstration alone), ``flat, features`` and ``flat MCE, features`` (the weights of
each layout fitted from its one demonstration), ``factorial, features`` and ``factorial MCE,
features`` (``FactIRL.transfer(new_mdps, demos, features=new_features)``: the coefficients
``h`` of the new mission on the training dictionary ``D``).
"""

from __future__ import annotations

from ...objectives.sharding import Execution
from typing import Any

import numpy as np

from ...datasets.babyai import BabyAITasks
from ...learners.factirl import FactIRL
from ...learners.gradirl import GradIRL
from .learner_names import ADAPTIVE_FEATURES, FACTORIAL_FEATURES, FACTORIAL_MCE_FEATURES, FLAT, FLAT_FEATURES, FLAT_MCE_FEATURES
from .learner_solvers import factorial_options, flat_solver
from .lineup import Fit, Learner, Lineup

__all__ = ["flat_tabular", "flat_features", "factorial_features", "factorial_features_transfer", "LINEUP",
           "SHARING_LINEUP", "babyai_claims"]

# --- builders of the line-up "babyai": (gt, preset, ctx) -> Fit; the row is ctx.learner ---------


def _gradirl(preset: Any, ctx: Any, features: Any = None) -> GradIRL:
    solver, _ = flat_solver(ctx.learner, preset)
    return GradIRL(beta=preset.beta, features=features, max_iter=preset.flat_max_iter, gtol=preset.flat_gtol,
                   stol=preset.flat_stol, solver=solver, objective=ctx.learner.objective,
                    execution=Execution(planner=preset.planner))


def flat_tabular(gt: BabyAITasks, preset: Any, ctx: Any) -> Any:
    """GradIRL on the tabular rewards of each layout, from that layout's demonstrations alone.

    A tabular reward lives on one layout's states: one fit per layout, nothing shared.
    """
    rewards, loss, evaluations = [], [], 0
    for mdp, demos in zip(gt.mdps(ctx.split), gt.demos(ctx.split)):
        model = _gradirl(preset, ctx).fit(mdp, [demos])
        rewards.append(model.rewards_[0])
        loss.append(float(np.sum(model.loss_)))
        evaluations += int(model.n_evaluations_)
    return Fit(rewards, np.array(loss), evaluations)


def flat_features(gt: BabyAITasks, preset: Any, ctx: Any) -> Any:
    """GradIRL on each layout's features: per-task weights, each from its own layout's demonstrations."""
    model = _gradirl(preset, ctx, gt.features(ctx.split)).fit(gt.mdps(ctx.split), gt.demos(ctx.split))
    return Fit(list(model.rewards_), np.asarray(model.loss_), int(model.n_evaluations_))


def factorial_features(gt: BabyAITasks, preset: Any, ctx: Any) -> Any:
    """FactIRL on the training layouts' features, from the PCA of the flat weights of the same objective."""
    objective = ctx.learner.objective
    flat = FLAT_MCE_FEATURES if objective == "mce" else FLAT_FEATURES
    model = FactIRL(rng=ctx.rngs["pca"], features=gt.features("train"),
                    **factorial_options(preset, ctx.spec.solvers, objective, ctx.learner.adaptive, features=True))
    model.fit(gt.mdps("train"), gt.train_demos, flat_rewards=ctx.rewards["train", flat])
    ctx.models[ctx.learner.name] = model
    return Fit(list(model.rewards_), np.asarray(model.loss_), int(model.n_evaluations_))


def factorial_features_transfer(gt: BabyAITasks, preset: Any, ctx: Any) -> Any:
    """``FactIRL.transfer`` of the training dictionary to the test layouts, their features and one demonstration each."""
    model = ctx.models[ctx.learner.name]
    model.transfer(gt.mdps("test"), gt.test_demos, features=gt.features("test"))
    return Fit(list(model.transfer_rewards_), np.asarray(model.transfer_loss_), int(model.transfer_n_evaluations_))


_FEATURES, _FACTORIAL = "flat features", "factorial"

#: the line-up ``"babyai"`` (see the module docstring), listed in :data:`.learners.LINEUPS`;
#: its claims (:func:`babyai_claims`) are listed in :data:`.claims.CLAIMS`
LINEUP = Lineup(
    name="babyai",
    learners=(
        Learner("train", FLAT_FEATURES, flat_features, solvers=_FEATURES),
        Learner("train", FLAT_MCE_FEATURES, flat_features, solvers=_FEATURES, objective="mce"),
        Learner("train", FACTORIAL_FEATURES, factorial_features, needs=(("train", FLAT_FEATURES),), solvers=_FACTORIAL),
        Learner("train", FACTORIAL_MCE_FEATURES, factorial_features, needs=(("train", FLAT_MCE_FEATURES),),
                solvers=_FACTORIAL, objective="mce"),
        Learner("test", FLAT, flat_tabular, per_seed=True),
        Learner("test", FLAT_FEATURES, flat_features, per_seed=True, solvers=_FEATURES),
        Learner("test", FLAT_MCE_FEATURES, flat_features, per_seed=True, solvers=_FEATURES, objective="mce"),
        Learner("test", FACTORIAL_FEATURES, factorial_features_transfer, needs=(("train", FACTORIAL_FEATURES),),
                solvers=_FACTORIAL),
        Learner("test", FACTORIAL_MCE_FEATURES, factorial_features_transfer, needs=(("train", FACTORIAL_MCE_FEATURES),),
                solvers=_FACTORIAL, objective="mce"),
    ),
    worlds=("babyai", "babyai-large"),
)


#: the line-up ``"babyai-sharing"`` ("which learner when"): flat on features, factorial on
#: features (the preset's k) and the adaptive learner on features (``n_primitives="auto",
#: residual_penalty="auto"``), both from the PCA of the flat weights; train, and test from one
#: demonstration of each new layout
SHARING_LINEUP = Lineup(
    name="babyai-sharing",
    learners=(
        Learner("train", FLAT_FEATURES, flat_features, solvers=_FEATURES),
        Learner("train", FACTORIAL_FEATURES, factorial_features, needs=(("train", FLAT_FEATURES),), solvers=_FACTORIAL),
        Learner("train", ADAPTIVE_FEATURES, factorial_features, needs=(("train", FLAT_FEATURES),), solvers=_FACTORIAL,
                adaptive=True),
        Learner("test", FLAT_FEATURES, flat_features, per_seed=True, solvers=_FEATURES),
        Learner("test", FACTORIAL_FEATURES, factorial_features_transfer, needs=(("train", FACTORIAL_FEATURES),),
                solvers=_FACTORIAL),
        Learner("test", ADAPTIVE_FEATURES, factorial_features_transfer, needs=(("train", ADAPTIVE_FEATURES),),
                solvers=_FACTORIAL, adaptive=True),
    ),
    worlds=("babyai", "babyai-large"),
)


def _success(rows: Any, learner: str, n: int, m: int) -> dict:
    return {r["seed"]: r["success_rate"] for r in rows
            if r["split"] == "test" and r["learner"] == learner and r["n_tasks"] == n and r["demos_per_task"] == m}


def babyai_claims(rows: Any, preset: Any) -> list[dict | None]:
    """The BabyAI claims: on new layouts with one demonstration each, each factorial learner on
    features reaches a higher success rate in the environment than its flat counterpart, at
    every number of training layouts (``measured`` gives success rates; ``paired``, what
    :func:`.claims.evaluate_claims` reads a failing claim's reason from)."""
    out: list[dict | None] = []
    m = preset.default_demos
    for fact, flat in ((FACTORIAL_FEATURES, FLAT_FEATURES), (FACTORIAL_MCE_FEATURES, FLAT_MCE_FEATURES)):
        for n in sorted(preset.tasks_sweep):
            a, b = _success(rows, fact, n, m), _success(rows, flat, n, m)
            seeds = sorted(set(a) & set(b))
            if not seeds:
                continue
            va, vb = np.array([a[s] for s in seeds]), np.array([b[s] for s in seeds])
            holds, wins = bool(va.mean() > vb.mean()), int(np.sum(va > vb))
            out.append(dict(claim=f"test: {fact} succeeds more often than {flat} (success rate in the environment)",
                            source="BabyAI benchmark", point=f"{n} tasks, {m} demos",
                            measured=f"success {fact}: {va.mean():.2f}; {flat}: {vb.mean():.2f}",
                            holds=holds, seeds=f"{wins}/{len(seeds)}",
                            paired=(fact, flat, (va - vb).tolist(), wins, "higher")))
    return out
