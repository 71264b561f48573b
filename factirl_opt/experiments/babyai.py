"""The BabyAI world of the experiments: layouts read from the simulator, the BabyAI bot's
demonstrations, and success judged by the environment itself.

A run's tasks are BabyAI layouts (``env.reset(seed=...)`` of a GoTo level), each its own
tabular MDP with its own state features (:func:`factirl_opt.minigrid.from_minigrid`: the
agent's reachable ``(x, y, direction)``, the 127 features, same columns in every layout) and
its own mission ("go to the red key"). Worlds (a preset's ``world``):

``"babyai"``
    ``BabyAI-GoToLocal-v0``: one 8x8 room, 8 objects, about 112 states per layout.
``"babyai-large"``
    ``BabyAI-GoToOpen-v0``: 3x3 rooms with open doors (22x22), about 1,250 states per layout.

Protocol (:func:`babyai_world`)
-------------------------------
- **Training**: ``n_tasks`` layouts, ``demos_per_task`` bot episodes each: the first from the
  environment's start, the others from start states drawn uniformly among the layout's
  non-terminal states (the agent is moved there after the reset, as
  :func:`factirl_opt.minigrid.bot_demonstration` allows; a start from which the bot would pick
  up or move an object, which the model does not hold, is redrawn). A GoToLocal bot episode is a few
  steps long (the target is in sight), so the extra starts show the mission from elsewhere.
- **Test**: ``n_test_tasks`` further layouts (seeds never used in training) with their own
  missions, ONE bot episode each, from a uniform non-terminal start other than the
  environment's; the learnt policy is then run from the environment's start. (A
  demonstration from the start itself would be solved by copying it: a tabular reward on its
  few states already succeeds, which measures nothing.) A mission may repeat a training
  mission's (colour, type): there are 18 GoTo targets (6 colours x 3 types).
- Layout seeds are drawn one by one (test first, then training, skipping test seeds and
  layouts the model refuses, e.g. the agent starting in front of its target), so the training
  layouts of a smaller point are the first ones of a larger point, and every point of a seed
  has the same test layouts.
- ``demo_length``, ``p_success``, ``grid_size`` and the dictionary fields of the preset are
  not used: the bot ends its episodes, the dynamics are the simulator's.

Scores (:meth:`BabyAIGroundTruth.scores`; the columns of the tables)
-------------------------------------------------------------------
``success_rate``
    The metric that matters: the greedy policy of each learnt reward on its layout's MDP
    (:func:`factirl_opt.optimal_q`) is executed in the real environment from its start by
    :func:`factirl_opt.minigrid.run_policy`, judged by the environment's own termination and
    reward within its ``max_steps``; the fraction of layouts solved.
``deviation``
    Beside it, on the enumerated MDPs (:func:`factirl_opt.deviation`, docs/maths.md §9)
    against the mission's reward: 1 for a step that enters a state where the episode ends
    with success, 0 otherwise (its greedy policy is a shortest path to the target).
``bot_success_rate``
    The ceiling: the fraction of the split's layouts where the bot, run from the environment's
    start, succeeds (as the environment judges).
``random_success_rate``
    The floor: the probability that the uniformly random policy over left/right/forward
    succeeds within ``max_steps`` from the start, computed exactly on the enumerated model
    (which reproduces the environment's transitions: tests/minigrid), averaged over layouts.

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

import dataclasses
import importlib
from typing import Any

import numpy as np

from ..evaluation import deviation
from ..exceptions import ValidationError
from ..factirl import FactIRL
from ..gradirl import GradIRL
from ..minigrid import bot_demonstration, from_minigrid, parse_goto_mission, run_policy
from ..minigrid.model import ACTIONS, MiniGridModel, base_env, require_minigrid
from ..planning import optimal_q
from .learner_names import FACTORIAL_FEATURES, FACTORIAL_MCE_FEATURES, FLAT, FLAT_FEATURES, FLAT_MCE_FEATURES
from .claims import CLAIMS
from .learners import LINEUPS, Fit, Learner, Lineup, factorial_options, flat_solver

__all__ = ["ENV_IDS", "BabyAIGroundTruth", "babyai_world", "babyai_large_world", "mission_rewards",
           "random_success_probability", "flat_tabular", "flat_features", "factorial_features",
           "factorial_features_transfer", "LINEUP", "babyai_claims"]

#: world name -> BabyAI level
ENV_IDS = {"babyai": "BabyAI-GoToLocal-v0", "babyai-large": "BabyAI-GoToOpen-v0"}
#: children spawned from a run's SeedSequence: test layouts, training layouts, training
#: starts, learners, test starts
N_STREAMS = 5
#: layout seeds are drawn from [0, SEED_RANGE)
SEED_RANGE = 2**31 - 1
SPLITS = ("train", "test")


def mission_rewards(model: MiniGridModel) -> np.ndarray:
    """The mission's reward on a layout's model, (S, A): 1 for a step entering a success state.

    Terminal states are absorbing and pay nothing, so the return of a policy is ``gamma^(t-1)``
    for success at step ``t`` (docs/maths.md §2, §9).
    """
    P = model.mdp.transition_matrix
    entered = np.asarray(P @ model.success.astype(np.float64)).reshape(model.n_states, len(ACTIONS))
    entered[model.terminal] = 0.0
    return entered


def random_success_probability(model: MiniGridModel, max_steps: int) -> float:
    """Probability that the uniformly random policy succeeds within ``max_steps`` from the start.

    Exact on the model: the distribution over states is pushed ``max_steps`` times through the
    random policy's transition matrix, the terminal states absorbing.
    """
    S = model.n_states
    P = model.mdp.transition_matrix
    rows = [P[a::len(ACTIONS)] for a in range(len(ACTIONS))]
    P_random = sum(rows[1:], rows[0]) / len(ACTIONS)
    p = np.zeros(S)
    p[model.start] = 1.0
    PT = P_random.T.tocsr()
    for _ in range(int(max_steps)):
        p = PT @ p
    return float(p[model.success].sum())


@dataclasses.dataclass
class BabyAIGroundTruth:
    """Everything a run's learners see or are scored against in the BabyAI world.

    Attributes
    ----------
    env : gymnasium.Env
        The level, reused to score every learner (reset with each layout's seed).
    seeds : dict
        ``split -> list of layout seeds``.
    models : dict
        ``split -> list of MiniGridModel`` (one per task).
    train_demos, test_demos : list
        Per task, a list of (L_j, 2) bot episodes (test: one each).
    train_rewards, test_rewards : list of (S_i, A) arrays
        The missions' rewards (:func:`mission_rewards`).
    bot_success : dict
        ``split -> (n,) bool``, the success of the bot from each layout's start.
    learner_rng : numpy.random.Generator
    """

    env: Any
    seeds: dict
    models: dict
    train_demos: list
    test_demos: list
    train_rewards: list
    test_rewards: list
    bot_success: dict
    learner_rng: np.random.Generator
    map_extras: dict = dataclasses.field(default_factory=dict)
    #: the runner's per-map scores (:mod:`.per_task`) do not apply: every layout is scored in the environment
    task_maps: dict = dataclasses.field(default_factory=dict)

    def demos(self, split: str) -> list:
        """Demonstrations of the ``"train"`` or ``"test"`` tasks."""
        return self.train_demos if _check_split(split) == "train" else self.test_demos

    def rewards(self, split: str) -> list:
        """Mission rewards (list of (S_i, A)) of the split's tasks."""
        return self.train_rewards if _check_split(split) == "train" else self.test_rewards

    def mdps(self, split: str) -> list:
        """The split's per-task MDPs."""
        return [m.mdp for m in self.models[_check_split(split)]]

    def features(self, split: str) -> list:
        """The split's per-task state features, (S_i, p) each."""
        return [m.features for m in self.models[_check_split(split)]]

    def policies(self, split: str, rewards: Any, planner: str = "auto") -> list:
        """Greedy policies (list of (S_i,) int arrays) of learnt rewards on the split's MDPs."""
        _, policy = optimal_q(self.mdps(split), rewards, planner=planner)
        return [np.asarray(p, dtype=np.int64) for p in policy]

    def runs(self, split: str, rewards: Any, planner: str = "auto") -> list:
        """The greedy policies of ``rewards`` run in the environment (list of PolicyRun)."""
        return [run_policy(self.env, pol, seed=seed, model=model)
                for pol, seed, model in zip(self.policies(split, rewards, planner), self.seeds[split], self.models[split])]

    def scores(self, split: str, rewards: Any, planner: str = "auto") -> tuple[np.ndarray, dict]:
        """Deviation per task (n,) on the enumerated MDPs and the success-rate columns of the tables."""
        dev = np.asarray(deviation(self.mdps(split), self.rewards(split), rewards, planner=planner), dtype=np.float64)
        success = [r.success for r in self.runs(split, rewards, planner)]
        max_steps = int(base_env(self.env).max_steps)
        random = [random_success_probability(m, max_steps) for m in self.models[split]]
        return dev, dict(success_rate=float(np.mean(success)), bot_success_rate=float(np.mean(self.bot_success[split])),
                         random_success_rate=float(np.mean(random)))


def _check_split(split: str) -> str:
    if split not in SPLITS:
        raise ValidationError(f"split must be 'train' or 'test'; got {split!r}")
    return split


def _layouts(env: Any, n: int, rng: np.random.Generator, exclude: set, gamma: float) -> tuple[list, list]:
    """``n`` layout seeds drawn one by one (skipping ``exclude`` and refused layouts) and their models."""
    seeds: list[int] = []
    models: list[MiniGridModel] = []
    refused = 0
    while len(seeds) < n:
        seed = int(rng.integers(SEED_RANGE))
        if seed in exclude or seed in seeds:
            continue
        env.reset(seed=seed)
        try:
            model = from_minigrid(env, gamma)
            parse_goto_mission(model.mission)
        except ValidationError:  # e.g. the agent starts in front of its target
            refused += 1
            if refused > 10 * n + 100:
                raise
            continue
        seeds.append(seed)
        models.append(model)
    return seeds, models


def _bot_episodes(env: Any, seed: int, model: MiniGridModel, m: int, rng: np.random.Generator, gamma: float,
                  from_start: bool) -> tuple[list, bool]:
    """``m`` bot episodes in a layout, and whether the bot succeeds from the layout's start.

    With ``from_start`` the first episode is the one from the start, the others from uniform
    non-terminal starts; without, every episode starts from a uniform non-terminal state
    other than the layout's start. A start from which the bot leaves the model (it would pick
    up an object in its way) is redrawn.
    """
    first = bot_demonstration(env, seed=seed, gamma=gamma)
    episodes = [first.demonstration] if from_start else []
    candidates = np.flatnonzero(~model.terminal)
    if not from_start:
        candidates = candidates[candidates != model.start]
    refused = 0
    while len(episodes) < m:
        x, y, d = (int(v) for v in model.states[rng.choice(candidates)])
        start = (x, y, d)
        try:
            episodes.append(bot_demonstration(env, seed=seed, start=start, gamma=gamma).demonstration)
        except ValidationError:  # the bot would pick up or move an object: redraw the start
            refused += 1
            if refused > 20 * m:
                raise
    return episodes, bool(first.success)


def _world(env_id: str, preset: Any, n_tasks: int, demos_per_task: int, seed: int) -> BabyAIGroundTruth:
    require_minigrid("the BabyAI world")
    env = importlib.import_module("gymnasium").make(env_id)
    s_test, s_train, s_train_starts, s_learn, s_test_starts = np.random.SeedSequence(seed).spawn(N_STREAMS)
    test_seeds, test_models = _layouts(env, preset.n_test_tasks, np.random.default_rng(s_test), set(), preset.gamma)
    train_seeds, train_models = _layouts(env, n_tasks, np.random.default_rng(s_train), set(test_seeds), preset.gamma)
    demos: dict = {"train": [], "test": []}
    bot: dict = {"train": [], "test": []}
    for split, seeds, models, m, s_starts in (("train", train_seeds, train_models, demos_per_task, s_train_starts),
                                              ("test", test_seeds, test_models, 1, s_test_starts)):
        starts = np.random.default_rng(s_starts)
        for layout, model in zip(seeds, models):
            episodes, ok = _bot_episodes(env, layout, model, m, starts, preset.gamma, from_start=split == "train")
            demos[split].append(episodes)
            bot[split].append(ok)
    return BabyAIGroundTruth(env, dict(train=train_seeds, test=test_seeds), dict(train=train_models, test=test_models),
                             demos["train"], demos["test"], [mission_rewards(m) for m in train_models],
                             [mission_rewards(m) for m in test_models],
                             {k: np.array(v, dtype=bool) for k, v in bot.items()}, np.random.default_rng(s_learn),
                             map_extras=dict(env_id=env_id))


def babyai_world(preset: Any, n_tasks: int, demos_per_task: int, seed: int) -> BabyAIGroundTruth:
    """BabyAI-GoToLocal-v0 layouts with the bot's demonstrations (see the module docstring).

    Parameters
    ----------
    preset : Preset
        Uses ``n_test_tasks`` and ``gamma``.
    n_tasks : int
        Training layouts.
    demos_per_task : int
        Bot episodes per training layout (the first from the start, the others from random starts).
    seed : int
        Entropy of the run's SeedSequence (streams: test layouts, training layouts, training
        starts, learners, test starts).

    Returns
    -------
    BabyAIGroundTruth
    """
    return _world(ENV_IDS["babyai"], preset, n_tasks, demos_per_task, seed)


def babyai_large_world(preset: Any, n_tasks: int, demos_per_task: int, seed: int) -> BabyAIGroundTruth:
    """BabyAI-GoToOpen-v0 layouts (about 1,250 states each); otherwise as :func:`babyai_world`."""
    return _world(ENV_IDS["babyai-large"], preset, n_tasks, demos_per_task, seed)


# --- builders of the line-up "babyai": (gt, preset, ctx) -> Fit; the row is ctx.learner ---------


def _gradirl(preset: Any, ctx: Any, features: Any = None) -> GradIRL:
    solver, _ = flat_solver(ctx.learner, preset)
    return GradIRL(beta=preset.beta, features=features, max_iter=preset.flat_max_iter, solver=solver,
                   objective=ctx.learner.objective, planner=preset.planner)


def flat_tabular(gt: BabyAIGroundTruth, preset: Any, ctx: Any) -> Any:
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


def flat_features(gt: BabyAIGroundTruth, preset: Any, ctx: Any) -> Any:
    """GradIRL on each layout's features: per-task weights, each from its own layout's demonstrations."""
    model = _gradirl(preset, ctx, gt.features(ctx.split)).fit(gt.mdps(ctx.split), gt.demos(ctx.split))
    return Fit(list(model.rewards_), np.asarray(model.loss_), int(model.n_evaluations_))


def factorial_features(gt: BabyAIGroundTruth, preset: Any, ctx: Any) -> Any:
    """FactIRL on the training layouts' features, from the PCA of the flat weights of the same objective."""
    objective = ctx.learner.objective
    flat = FLAT_MCE_FEATURES if objective == "mce" else FLAT_FEATURES
    model = FactIRL(init="pca", rng=ctx.rngs["pca"], features=gt.features("train"),
                    **factorial_options(preset, ctx.spec.solvers, objective))
    model.fit(gt.mdps("train"), gt.train_demos, flat_rewards=ctx.rewards["train", flat])
    ctx.models[ctx.learner.name] = model
    return Fit(list(model.rewards_), np.asarray(model.loss_), int(model.n_evaluations_))


def factorial_features_transfer(gt: BabyAIGroundTruth, preset: Any, ctx: Any) -> Any:
    """``FactIRL.transfer`` of the training dictionary to the test layouts, their features and one demonstration each."""
    model = ctx.models[ctx.learner.name]
    model.transfer(gt.mdps("test"), gt.test_demos, features=gt.features("test"))
    return Fit(list(model.transfer_rewards_), np.asarray(model.transfer_loss_), int(model.transfer_n_evaluations_))


_FEATURES, _FACTORIAL = "flat features", "factorial"

#: the line-up ``"babyai"`` (see the module docstring); importing this module adds it to
#: :data:`.learners.LINEUPS` (:mod:`.worlds` imports it with the BabyAI worlds)
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
LINEUPS[LINEUP.name] = LINEUP


def _success(rows: Any, learner: str, n: int, m: int) -> dict:
    return {r["seed"]: r["success_rate"] for r in rows
            if r["split"] == "test" and r["learner"] == learner and r["n_tasks"] == n and r["demos_per_task"] == m}


def babyai_claims(rows: Any, preset: Any) -> list[dict | None]:
    """The BabyAI claims: on new layouts with one demonstration each, each factorial learner on
    features reaches a higher success rate in the environment than its flat counterpart, at
    every number of training layouts (:mod:`.claims`' format; ``measured`` gives success rates)."""
    out: list[dict | None] = []
    m = preset.default_demos
    for fact, flat in ((FACTORIAL_FEATURES, FLAT_FEATURES), (FACTORIAL_MCE_FEATURES, FLAT_MCE_FEATURES)):
        for n in sorted(preset.tasks_sweep):
            a, b = _success(rows, fact, n, m), _success(rows, flat, n, m)
            seeds = sorted(set(a) & set(b))
            if not seeds:
                continue
            va, vb = np.array([a[s] for s in seeds]), np.array([b[s] for s in seeds])
            out.append(dict(claim=f"test: {fact} succeeds more often than {flat} (success rate in the environment)",
                            source="BabyAI benchmark", point=f"{n} tasks, {m} demos",
                            measured=f"success {fact}: {va.mean():.2f}; {flat}: {vb.mean():.2f}",
                            holds=bool(va.mean() > vb.mean()), seeds=f"{int(np.sum(va > vb))}/{len(seeds)}"))
    return out


CLAIMS[LINEUP.name] = ("BabyAI claims", babyai_claims)
