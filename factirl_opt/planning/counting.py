"""A planner that counts the Bellman systems it builds and solves: the measure of planning work.

Wrap any planner (``CountingPlanner(get_planner(mdp))``) and pass the wrapper wherever a planner
goes (``planner=`` of the objectives, ``optimal_q``): every result is the wrapped planner's, and
the counters say how much planning it took. The solver comparisons (notebook 02, ``bench fit``)
and the MCE benchmark (``bench mce``) count with it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from .base import Planner, PolicySystem

__all__ = ["CountingPlanner"]

#: the counters of a :class:`CountingPlanner`, in the order of :meth:`CountingPlanner.counts`
COUNTERS = ("n_systems", "n_stochastic_systems", "n_forward", "n_transpose", "n_forward_calls", "n_transpose_calls")


class _CountingSystem(PolicySystem):
    """A :class:`~factirl_opt.planning.base.PolicySystem` that counts its forward and transposed solves."""

    def __init__(self, system: PolicySystem, counter: CountingPlanner) -> None:
        self.system, self.counter, self.n = system, counter, system.n
        self.solvers = getattr(system, "solvers", None)

    def solve(self, B: Any) -> Any:
        self.counter.n_forward += self.n
        self.counter.n_forward_calls += 1
        return self.system.solve(B)

    def solve_transpose(self, B: Any) -> Any:
        self.counter.n_transpose += self.n
        self.counter.n_transpose_calls += 1
        return self.system.solve_transpose(B)


class CountingPlanner(Planner):
    """A planner that delegates to another and counts the task systems it builds and solves.

    Parameters
    ----------
    planner : Planner
        The planner doing the work (e.g. ``factirl_opt.planning.get_planner(mdp)``).

    Attributes
    ----------
    n_systems, n_stochastic_systems : int
        Task systems ``M = I - gamma P_pi`` asked for (all, and those of stochastic policies:
        each one a new factorisation with the sparse planner).
    n_forward, n_transpose : int
        Task systems solved, ``M x = b`` and ``M^T x = b``: a batched solve of n tasks counts n,
        whatever its number of right-hand sides.
    n_forward_calls, n_transpose_calls : int
        Batched solve calls.
    """

    def __init__(self, planner: Planner) -> None:
        super().__init__(planner.mdp)
        self.planner, self.name = planner, planner.name
        self.n_systems = self.n_stochastic_systems = 0
        self.n_forward = self.n_transpose = self.n_forward_calls = self.n_transpose_calls = 0

    @property
    def n_solves(self) -> int:
        """Task systems solved, forward and transposed (``n_forward + n_transpose``)."""
        return self.n_forward + self.n_transpose

    def backup(self, V: Any) -> Any:
        return self.planner.backup(V)

    def pullback(self, G: Any) -> Any:
        return self.planner.pullback(G)

    def system(self, policy: Any, hints: Any = None) -> PolicySystem:
        n = len(policy)
        self.n_systems += n
        if np.ndim(policy) == 3:
            self.n_stochastic_systems += n
        return _CountingSystem(self.planner.system(policy, hints), self)

    def solver_system(self, solvers: Any) -> PolicySystem:
        return _CountingSystem(self.planner.solver_system(solvers), self)

    def counts(self) -> dict[str, int]:
        """The counters as a dict."""
        return {key: int(getattr(self, key)) for key in COUNTERS}

    def __getattr__(self, name: str) -> Any:  # anything else a planner offers (value sweeps, caches): the wrapped one's
        return getattr(self.__dict__["planner"], name)
