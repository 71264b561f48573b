"""The candidates of the sharing search: pairs ``(k, lambda)`` of a learner's ``"auto"`` values, and the largest k."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from ...tasks.task_set import task_set
from ..fitting import resolve_step_solver
from ..solver_settings import estimator_solvers

__all__ = ["AUTO", "K_CANDIDATES", "LAMBDA_CANDIDATES", "sharing_candidates", "max_primitives"]

#: the value of ``n_primitives`` / ``residual_penalty`` that asks for validation
AUTO = "auto"
#: candidate numbers of primitives (those <= min(p, number of training tasks of a fold) are tried)
K_CANDIDATES = (1, 2, 4, 8, 16)
#: candidate residual penalties, from the factorial model (inf) to the flat one (0)
LAMBDA_CANDIDATES = (np.inf, 1.0, 1e-2, 0.0)

def _candidates(k_fixed: Any, lam_fixed: Any, k_max: int, constrained: bool, k_grid: Sequence[int] = K_CANDIDATES,
                lam_grid: Sequence[float] = LAMBDA_CANDIDATES) -> list[tuple[int, float]]:
    """The candidate pairs: k up to ``k_max``; lambda from inf to 0 (inf only for a constrained
    H-solver, which the residual model does not take)."""
    if k_fixed == AUTO:
        ks = [int(k) for k in k_grid if k <= k_max] or [1]
    else:
        ks = [int(k_fixed)]
    if lam_fixed == AUTO:
        lams = [np.inf] if constrained else [float(lam) for lam in lam_grid]
    else:
        lams = [float(lam_fixed)]
    out = []
    for lam in lams:
        for k in (ks[:1] if lam == 0.0 else ks):  # lambda = 0: the dictionary plays no part
            out.append((k, lam))
    return out



def sharing_candidates(learner: Any, k_max: int, k_grid: Sequence[int] = K_CANDIDATES,
                       lam_grid: Sequence[float] = LAMBDA_CANDIDATES) -> list[tuple[int, float]]:
    """The candidate pairs ``(k, lambda)`` of ``learner``'s ``"auto"`` values, in the order scored.

    k from ``k_grid`` up to ``k_max`` (or the learner's fixed k); lambda from ``lam_grid`` (or the
    fixed one), np.inf only for a constrained H-solver (the residual model needs an
    unconstrained one); ``lambda = 0`` once, with the smallest k (the dictionary plays no part).
    """
    h_name, h_options, _, _ = estimator_solvers(learner)
    constrained = resolve_step_solver(h_name, h_options, learner.objective, "solver").constraint != "none"
    return _candidates(learner.n_primitives, learner.residual_penalty, k_max, constrained, k_grid, lam_grid)


def max_primitives(learner: Any, mdp: Any, n_tasks: int, folds: Sequence[np.ndarray]) -> int:
    """The largest k a candidate may have: the reward directions the basis spans (its rank, at most
    the reward dimension p), and the training tasks of the smallest fold's fit."""
    return min(_basis_rank(learner, mdp, n_tasks), min(n_tasks - len(f) for f in folds))


def _basis_rank(learner: Any, mdp: Any, n_tasks: int) -> int:
    """The reward directions ``learner``'s features span on ``n_tasks`` tasks of ``mdp``
    (:meth:`~factirl_opt.tasks.basis.RewardBasis.rank`, at most the reward dimension p; the
    demonstrations play no part)."""
    return task_set(mdp, [None] * n_tasks, learner.features, learner.reward).basis.rank(n_tasks)
