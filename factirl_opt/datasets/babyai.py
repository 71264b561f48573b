"""BabyAI tasks: GoTo layouts read from the simulator, the BabyAI bot's demonstrations, success judged by the environment.

A task is a BabyAI layout (``env.reset(seed=...)`` of a GoTo level), its own tabular MDP with
its own state features (:func:`factirl_opt.adapters.minigrid.from_minigrid`: the agent's
reachable ``(x, y, direction)``, the 127 features, the same columns in every layout) and its
own mission ("go to the red key"). :func:`babyai_tasks` draws training and test layouts and
the bot's demonstrations; :class:`BabyAITasks` holds them and scores learnt rewards.

Protocol
--------
- **Training**: ``n_tasks`` layouts (a layout from whose start the bot would leave the model is
  drawn again), ``demos_per_task`` bot episodes each: the first from the environment's start,
  the others from start states drawn uniformly among the layout's non-terminal states (the agent is moved there after the reset, as
  :func:`factirl_opt.adapters.minigrid.bot_demonstration` allows; a start from which the bot
  would pick up or move an object, which the model does not hold, is redrawn).
- **Test**: ``n_test_tasks`` further layouts (seeds never used in training) with their own
  missions, ONE bot episode each, from a uniform non-terminal start other than the
  environment's; a learnt policy is then run from the environment's start (a demonstration
  from the start itself would be solved by copying it). There are 18 GoTo targets (6 colours
  x 3 types), so a test mission may repeat a training one.
- Layout seeds are drawn one by one (test first, then training, skipping test seeds and
  layouts the model refuses, e.g. the agent starting in front of its target), so the training
  layouts of a smaller draw are the first ones of a larger draw with the same seed.

Scores (:meth:`BabyAITasks.scores`)
-----------------------------------
``success_rate``
    The greedy policy of each learnt reward on its layout's MDP, executed in the real
    environment from its start (:func:`factirl_opt.adapters.minigrid.run_policy`), judged by
    the environment's own termination and reward within its ``max_steps``.
``deviation``
    On the enumerated MDPs (:func:`factirl_opt.deviation`, docs/maths.md §9) against the
    mission's reward (:func:`mission_rewards`).
``bot_success_rate``, ``random_success_rate``
    The ceiling (the bot from the start) and the floor (the uniformly random policy, exact on
    the model: :func:`random_success_probability`).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from .._validation import check_int, check_real
from ..adapters.minigrid import bot_demonstration, from_minigrid, parse_goto_mission, run_policy
from ..adapters.minigrid.model import ACTIONS, MiniGridModel, base_env, make_env
from ..evaluation import deviation
from ..exceptions import ValidationError
from ..planning import optimal_q

__all__ = ["BabyAITasks", "babyai_tasks", "mission_rewards", "random_success_probability", "GOTO_LEVELS", "SPLITS"]

#: the BabyAI GoTo levels the tasks are drawn from: one 8x8 room with 8 objects (about 112
#: states per layout), and 3x3 rooms with open doors (22x22, about 1,250 states per layout)
GOTO_LEVELS = ("BabyAI-GoToLocal-v0", "BabyAI-GoToOpen-v0")

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
class BabyAITasks:
    """BabyAI layouts as training and test tasks: what learners see and what scores them.

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
    #: the runner's per-map scores (:mod:`factirl_opt.lab.experiments.per_task`) do not apply: every layout is scored in the environment
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


def _layouts(env: Any, n: int, rng: np.random.Generator, exclude: set, gamma: float) -> tuple[list, list, list]:
    """``n`` layout seeds drawn one by one (skipping ``exclude`` and refused layouts), their models,
    and the bot's episode from each layout's start (:func:`bot_demonstration`).

    A layout is refused when it is not modelled (e.g. the agent starts in front of its target) or
    when the bot, from the layout's start, leaves the model (it would pick up or move an object in
    its way: GoToOpen's larger rooms have such layouts)."""
    seeds: list[int] = []
    models: list[MiniGridModel] = []
    firsts: list = []
    refused = 0
    while len(seeds) < n:
        seed = int(rng.integers(SEED_RANGE))
        if seed in exclude or seed in seeds:
            continue
        env.reset(seed=seed)
        try:
            model = from_minigrid(env, gamma)
            parse_goto_mission(model.mission)
            first = bot_demonstration(env, seed=seed, gamma=gamma)
        except ValidationError:  # e.g. the agent starts in front of its target, or the bot picks up an object
            refused += 1
            if refused > 10 * n + 100:
                raise
            continue
        seeds.append(seed)
        models.append(model)
        firsts.append(first)
    return seeds, models, firsts


def _bot_episodes(env: Any, seed: int, model: MiniGridModel, first: Any, m: int, rng: np.random.Generator,
                  gamma: float, from_start: bool) -> tuple[list, bool]:
    """``m`` bot episodes in a layout, and whether the bot succeeds from the layout's start.

    With ``from_start`` the first episode is ``first``, the bot's from the start, the others from uniform
    non-terminal starts; without, every episode starts from a uniform non-terminal state
    other than the layout's start. A start from which the bot leaves the model (it would pick
    up an object in its way) is redrawn.
    """
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


def babyai_tasks(env_id: str = "BabyAI-GoToLocal-v0", n_tasks: int = 4, demos_per_task: int = 3, *,
                 n_test_tasks: int = 4, gamma: float = 0.9, seed: int = 0) -> BabyAITasks:
    """Training and test tasks on BabyAI GoTo layouts, with the bot's demonstrations.

    Parameters
    ----------
    env_id : str, default="BabyAI-GoToLocal-v0"
        A registered BabyAI GoTo level (e.g. one of :data:`GOTO_LEVELS`).
    n_tasks : int, default=4
        Training layouts.
    demos_per_task : int, default=3
        Bot episodes per training layout (the first from the start, the others from random
        non-terminal starts).
    n_test_tasks : int, default=4
        Test layouts, one bot episode each from a random start.
    gamma : float, default=0.9
        Discount factor of the enumerated MDPs.
    seed : int, default=0
        Entropy of the draw's SeedSequence (streams: test layouts, training layouts, training
        starts, learners, test starts); the same seed gives the same tasks.

    Returns
    -------
    BabyAITasks

    Raises
    ------
    MissingDependencyError
        Without the ``minigrid`` extra.
    ValidationError
        For a count below 1, a discount outside [0, 1), or an ``env_id`` that is not a
        registered environment id (named, with gymnasium's reason).
    """
    n_tasks = check_int(n_tasks, "n_tasks", 1)
    demos_per_task = check_int(demos_per_task, "demos_per_task", 1)
    n_test_tasks = check_int(n_test_tasks, "n_test_tasks", 1)
    gamma = check_real(gamma, "gamma", 0.0, 1.0, high_open=True)
    env = make_env(env_id, "env_id", "the BabyAI tasks")
    s_test, s_train, s_train_starts, s_learn, s_test_starts = np.random.SeedSequence(seed).spawn(N_STREAMS)
    test_seeds, test_models, test_firsts = _layouts(env, n_test_tasks, np.random.default_rng(s_test), set(), gamma)
    train_seeds, train_models, train_firsts = _layouts(env, n_tasks, np.random.default_rng(s_train), set(test_seeds),
                                                       gamma)
    demos: dict = {"train": [], "test": []}
    bot: dict = {"train": [], "test": []}
    for split, seeds, models, firsts, m, s_starts in (
            ("train", train_seeds, train_models, train_firsts, demos_per_task, s_train_starts),
            ("test", test_seeds, test_models, test_firsts, 1, s_test_starts)):
        starts = np.random.default_rng(s_starts)
        for layout, model, first in zip(seeds, models, firsts):
            episodes, ok = _bot_episodes(env, layout, model, first, m, starts, gamma, from_start=split == "train")
            demos[split].append(episodes)
            bot[split].append(ok)
    return BabyAITasks(env, dict(train=train_seeds, test=test_seeds), dict(train=train_models, test=test_models),
                             demos["train"], demos["test"], [mission_rewards(m) for m in train_models],
                             [mission_rewards(m) for m in test_models],
                             {k: np.array(v, dtype=bool) for k, v in bot.items()}, np.random.default_rng(s_learn),
                             map_extras=dict(env_id=env_id))
