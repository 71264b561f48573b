"""The adapters layer: models and demonstrations from other libraries.

- :mod:`~factirl_opt.adapters.gymnasium`: Gymnasium toy-text environments (FrozenLake,
  CliffWalking, Taxi) as :class:`~factirl_opt.TabularMDP` (extra ``.[gymnasium]``).
- :mod:`~factirl_opt.adapters.minari`: Minari datasets as logged episodes (extra ``.[minari]``).
- :mod:`~factirl_opt.adapters.minigrid`: BabyAI/MiniGrid models enumerated from the simulator,
  the BabyAI bot's demonstrations (extra ``.[minigrid]``); import it explicitly
  (``factirl_opt.minigrid`` loads it on first access).

Each optional library is imported only when its adapter is used.
"""

from .gymnasium import from_gymnasium, gymnasium_rewards
from .minari import LoggedEpisodes, read_minari

__all__ = ["from_gymnasium", "gymnasium_rewards", "read_minari", "LoggedEpisodes"]
