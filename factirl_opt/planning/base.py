"""The planner interface: :class:`Planner` (bound to one MDP) and :class:`PolicySystem`.

A planner answers the engine's three questions about an MDP (docs/maths.md §2 and §4): the
Bellman backup ``P V`` of a batch of values, its transpose ``P^T G``, and the linear systems
``M = I - gamma P_pi`` of a batch of policies (:class:`PolicySystem`). Everything else (policy
iteration, adjoints, tangents) is written once, in :mod:`factirl_opt.planning.engine`, on top
of this interface. Batches keep tasks on the leading axis: values (n, S), rewards and action
values (n, S, A), deterministic policies (n, S) of action indices, stochastic ones (n, S, A).
"""

from __future__ import annotations

import abc
import contextlib
import weakref
from collections.abc import Iterator
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["Planner", "PolicySystem"]


class PolicySystem(abc.ABC):
    """``M = I - gamma P_pi`` for a batch of n policies: solve ``M X = B`` and ``M^T X = B``.

    Right-hand sides ``B`` are (n, S) or (n, S, k). Built by :meth:`Planner.system`.
    """

    n: int
    #: per-task solvers (sparse planners), or None
    solvers: list[Any] | None = None

    @abc.abstractmethod
    def solve(self, B: NDArray[np.float64]) -> NDArray[np.float64]:
        """``X`` with ``M X = B``, same shape as ``B``."""

    @abc.abstractmethod
    def solve_transpose(self, B: NDArray[np.float64]) -> NDArray[np.float64]:
        """``X`` with ``M^T X = B``, same shape as ``B``."""


class Planner(abc.ABC):
    """Base class: a planner bound to one MDP. Use :func:`factirl_opt.planning.get_planner`.

    A planner keeps only a weak reference to its MDP (:attr:`mdp`): the planners of an MDP are
    cached for the MDP's lifetime (:mod:`factirl_opt.planning.cache`) and must not keep it alive.
    A planner's precomputed arrays are never written after construction, so one planner may be
    shared by threads; a planner that caches work between calls keeps that cache per thread.

    Attributes
    ----------
    name : str
    S, A : int
    gamma : float
    """

    name = "base"

    def __init__(self, mdp: Any) -> None:
        self._mdp_ref = weakref.ref(mdp)
        self.S, self.A, self.gamma = mdp.n_states, mdp.n_actions, mdp.gamma

    @property
    def mdp(self) -> Any:
        """The MDP this planner is bound to (None once it has been garbage-collected)."""
        return self._mdp_ref()

    @abc.abstractmethod
    def backup(self, V: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(P V)[n, s, a] = sum_s' P(s'|s, a) V[n, s']``: (n, S) -> (n, S, A).

        With k directions, (n, S, k) -> (n, S*A, k) (row ``s * A + a``).
        """

    @abc.abstractmethod
    def pullback(self, G: NDArray[np.float64]) -> NDArray[np.float64]:
        """``(P^T G)[n, s'] = sum_{s,a} P(s'|s, a) G[n, s, a]``: (n, S, A) -> (n, S)."""

    @abc.abstractmethod
    def system(self, policy: NDArray[Any], hints: list[Any] | None = None) -> PolicySystem:
        """:class:`PolicySystem` of deterministic (n, S) int or stochastic (n, S, A) policies.

        ``hints``: per task, a solver of a nearby policy (``PolicySystem.solvers``) that a
        planner may reuse; planners without reuse ignore it.
        """

    def solver_system(self, solvers: list[Any]) -> PolicySystem:
        """The :class:`PolicySystem` made of per-task solvers (``PolicySystem.solvers``) this
        planner built earlier; only planners that expose solvers implement it."""
        raise NotImplementedError(f"the {self.name!r} planner has no per-task solvers")

    def clear_cache(self) -> None:
        """Forget any factorisations kept between calls (no-op for planners that keep none)."""

    def clear_thread_cache(self) -> None:
        """Forget the factorisations this thread keeps between calls (no-op for planners that keep none)."""

    @contextlib.contextmanager
    def transient_cache(self) -> Iterator[None]:
        """Inside the block, what this thread's planning would cache goes to a cache that is
        dropped on exit (a memory budget's chunks, :mod:`factirl_opt.planning.budget`); a no-op
        for planners that keep nothing between calls."""
        yield

    def task_bytes(self) -> int:
        """Estimated planning memory of one task during an evaluation (bytes), what a memory
        budget divides (:mod:`factirl_opt.planning.budget`): here one dense (S, S) system, the
        size of what the dense planner builds per task while it solves."""
        return 8 * self.S * self.S

    def q_from_values(self, R: NDArray[np.float64], V: NDArray[np.float64]) -> NDArray[np.float64]:
        """``Q = R + gamma P V``: R (n, S, A), V (n, S) -> (n, S, A)."""
        return R + self.gamma * self.backup(V)

    def initial_policy(self, R: NDArray[np.float64]) -> NDArray[np.intp]:
        """Where policy iteration starts without a warm start: greedy on the immediate reward."""
        return np.argmax(R, axis=2)

    def refine_policy(self, R: NDArray[np.float64], Q: NDArray[np.float64], policy: NDArray[np.intp],
                      previous: NDArray[np.intp]) -> NDArray[np.intp]:
        """The next policy of policy iteration, given the improved (greedy) ``policy`` on the
        exact ``Q`` (n, S, A) of the ``previous`` one. This planner takes it as is (Howard's
        policy iteration); see :meth:`SparseLUPlanner.refine_policy`."""
        return policy
