"""The MDP layer: tabular models, successor lists, models estimated from logs, per-task environments.

Nothing here plans or learns; every other layer builds on these types.

- :mod:`~factirl_opt.mdp.tabular`: :class:`TabularMDP` (dense (S, A, S) or sparse (S*A, S)
  dynamics) and the paper's :class:`GridWorld`; successor lists in and out.
- :mod:`~factirl_opt.mdp.successors`: the array side of successor lists (Levine, ELIRL).
- :mod:`~factirl_opt.mdp.estimation`: models estimated from logged transitions.
- :mod:`~factirl_opt.mdp.environments`: tasks on one shared MDP or one MDP per task (an
  *environment* is always one MDP on which tasks are demonstrated), grouped by identity.
"""

from .estimation import as_transitions, estimate_mdp, sample_transitions, transition_counts, transition_log_likelihood
from .tabular import GridWorld, TabularMDP, from_successors, to_successors

__all__ = [
    "TabularMDP",
    "GridWorld",
    "from_successors",
    "to_successors",
    "estimate_mdp",
    "as_transitions",
    "transition_counts",
    "transition_log_likelihood",
    "sample_transitions",
]
