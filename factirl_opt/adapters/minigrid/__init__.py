"""BabyAI (MiniGrid) layouts as tabular MDPs with features, the BabyAI bot's demonstrations,
and learnt policies run in the real environment.

- :func:`from_minigrid` reads one layout (after ``env.reset(seed=...)``) into a
  :class:`MiniGridModel`: navigation states ``(x, y, direction)``, sparse deterministic
  dynamics found by the environment's own ``step``, absorbing terminal states, and features
  with the same columns in every layout (:mod:`factirl_opt.adapters.minigrid.features`).
- :func:`parse_goto_mission` reads a GoTo mission ("go to the red key") as (colour, type).
- :func:`bot_demonstration` rolls ``minigrid.utils.baby_ai_bot.BabyAIBot`` and returns its
  episode as the library's demonstrations, checked step by step against the model.
- :func:`run_policy` runs a policy (e.g. greedy on a learnt reward) in the environment and
  reports success as the environment judges it.

minigrid is optional: ``pip install -e ".[minigrid]"``. ``import factirl_opt`` does not import
it; importing this package does, when it is installed (so that gymnasium knows the MiniGrid and
BabyAI environment ids), and without it the functions raise
:class:`~factirl_opt.exceptions.MissingDependencyError` with the pip command.
The conventions (state numbering, actions, terminal states) are in
:mod:`factirl_opt.adapters.minigrid.model`.

Examples
--------
>>> import gymnasium as gym
>>> import minigrid  # registers the MiniGrid and BabyAI ids with gymnasium  # doctest: +SKIP
>>> import factirl_opt as fo
>>> env = gym.make("BabyAI-GoToLocal-v0")  # doctest: +SKIP
>>> episode = fo.minigrid.bot_demonstration(env, seed=0)  # doctest: +SKIP
>>> model = episode.model  # the layout: model.mdp, model.features, model.states, model.start
>>> fo.minigrid.parse_goto_mission(episode.mission)  # doctest: +SKIP
('green', 'ball')
>>> _, policy = fo.optimal_q(model.mdp, rewards)  # greedy on (S, A) rewards  # doctest: +SKIP
>>> fo.minigrid.run_policy(env, policy, seed=0, model=model).success  # doctest: +SKIP
"""

import importlib as _importlib

try:  # registers MiniGrid's and BabyAI's environments with gymnasium
    _importlib.import_module("minigrid")
except ImportError:  # the functions raise MissingDependencyError when called
    pass

from .episodes import BotDemonstration, PolicyRun, bot_demonstration, run_policy
from .features import COLOURS, DEFAULT_THRESHOLDS, OBJECT_TYPES, minigrid_feature_names, minigrid_features, parse_goto_mission
from .model import ACTIONS, MiniGridModel, from_minigrid

__all__ = [
    "ACTIONS",
    "COLOURS",
    "OBJECT_TYPES",
    "DEFAULT_THRESHOLDS",
    "MiniGridModel",
    "from_minigrid",
    "minigrid_feature_names",
    "minigrid_features",
    "parse_goto_mission",
    "BotDemonstration",
    "bot_demonstration",
    "PolicyRun",
    "run_policy",
]
