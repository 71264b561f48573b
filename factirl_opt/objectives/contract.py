"""The objective's contract: what every kind of objective offers the step problems and the learners.

Five kinds of objective carry a fit's tasks: :class:`~factirl_opt.objectives.Objective` (tasks
of one MDP, in this process), :class:`~factirl_opt.objectives.environments.MultiEnvironmentObjective`
(one objective per environment), :class:`~factirl_opt.objectives.distributed.ShardedObjective`
and :class:`~factirl_opt.objectives.sharded_environments.ShardedEnvironments` (the same over
worker processes) and :class:`~factirl_opt.learners.multi_intent_fit.WeightedObjective` (EM's
weighted intentions). Each subclasses :class:`TaskObjective`, which names what they share;
the step problems (:mod:`factirl_opt.objectives.problems`) and the factorial loop use nothing
else, and ask no objective what it can do: its capabilities are declared here.

Per-task arrays (rewards, ``dJ/dR``) are stacked (r, S, A) arrays, or lists of (S_i, A) arrays
for tasks in environments of different sizes.
"""

from __future__ import annotations

import abc
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
from numpy.typing import NDArray

from .._validation import REWARD_LIMIT

__all__ = ["TaskObjective", "FactorialPoint", "limit_of"]

#: ``gradients(D, H) -> (dJ/dH (n, k), dJ/dD (p, k))`` at a factorial point (eqs. 11-12)
FactorialPoint = Callable[[NDArray[np.float64], NDArray[np.float64]], tuple[NDArray[np.float64], NDArray[np.float64]]]


def limit_of(gammas: list[float]) -> float:
    """The largest ``|reward|`` planned without overflow over MDPs of discounts ``gammas``:
    ``REWARD_LIMIT * (1 - max gamma)`` (as :func:`~factirl_opt._validation.check_rewards`), inf without any."""
    return REWARD_LIMIT * (1.0 - max(gammas)) if gammas else np.inf


class TaskObjective(abc.ABC):
    """A loss per task over rewards, bound to the tasks' data (docs/maths.md §5-6).

    Attributes
    ----------
    name : str
        The registered objective's name.
    least_squares : bool
        Whether the loss is ``||residual||^2`` per task: :meth:`residual_jacobian` and
        :meth:`linearize` apply (the Gauss-Newton solvers).
    n_tasks : int
    n_evaluations : int
        Batched planning evaluations so far.
    builds_problems : bool (class attribute)
        Declared capability: the objective builds its step problems itself, where its tasks
        are evaluated (:meth:`weights_problem`, :meth:`dictionary_problem`; the sharded
        objective of one MDP, so that only weights travel). Otherwise the step problems are
        built on its :meth:`loss_and_grad` and the other operations, in this process.
    has_hessian : bool
        Declared capability: :meth:`hessian` gives the Hessian of the loss in linear reward
        weights (the MCE objective, :meth:`~factirl_opt.objectives.mce.MCEObjective.hessian`):
        the step problems then carry it (the ``"newton"`` solver).
    """

    name: str
    least_squares: bool
    n_tasks: int
    builds_problems: ClassVar[bool] = False
    has_hessian: bool = False

    @property
    @abc.abstractmethod
    def n_evaluations(self) -> int:
        """Batched planning evaluations so far (a counter an objective may keep as a plain attribute)."""

    @abc.abstractmethod
    def loss_and_grad(self, rewards: Any, rows: Any = None) -> tuple[NDArray[np.float64], Any]:
        """Loss per task (r,) and ``dJ/dR`` at ``rewards`` of tasks ``rows`` (all when None)."""

    @abc.abstractmethod
    def residual_jacobian(self, rewards: Any, rows: Any, features: Any) -> tuple:
        """Loss (r,), residuals (r, m) and their Jacobian (r, m, p) along ``features`` (least squares)."""

    @abc.abstractmethod
    def linearize(self, rewards: Any, rows: Any = None) -> Any:
        """A :class:`solvers.Linearization` in reward space (least squares)."""

    @abc.abstractmethod
    def reset(self) -> None:
        """Forget warm starts and the last-point cache (statistics and counts kept)."""

    @abc.abstractmethod
    def reward_limit(self) -> float:
        """The largest ``|reward|`` the objective plans without overflow (:func:`limit_of` of its MDPs)."""

    def hessian(self, rewards: Any, rows: Any, features: Any) -> NDArray[np.float64]:
        """Hessian (r, p, p) of the loss of tasks ``rows`` in the weights of ``R_i = F_i w_i``
        (``features`` one (S*A, p) matrix or one per row; only with :attr:`has_hessian`)."""
        raise NotImplementedError(f"the {self.name!r} objective gives no Hessian")

    def environment_groups(self) -> list[tuple[Any, NDArray[np.intp], NDArray[np.intp]]]:
        """``(objective, tasks, local rows)`` per environment: the objective of one MDP that holds
        those tasks (its ``mdp``, ``mu``, ``pi_hat``) and their rows in it. One group, this
        objective and every task, for an objective of one MDP in this process."""
        rows = np.arange(self.n_tasks)
        return [(self, rows, rows)]

    def factorial_point(self, basis: Any, dictionary: NDArray[np.float64],
                        coefficients: NDArray[np.float64]) -> tuple[NDArray[np.float64], FactorialPoint]:
        """Loss per task (n,) at ``R_i = Phi_i D h_i`` of every task, and the gradients there.

        Returns ``(loss, gradients)``, ``gradients(D', H')`` giving ``(dJ/dH, dJ/dD)`` with the
        ``dJ/dR`` of this point and the (renormalised) pair ``(D', H')`` (eqs. 11-12): what the
        factorial loop's optimality measure needs.
        """
        loss, y = self.loss_and_grad(basis.factorial_rewards(dictionary, coefficients))
        return loss, lambda D, H: basis.factorial_gradients(y, D, H)

    def weights_problem(self, basis: Any, names: tuple[str, str] | None) -> Any:  # pragma: no cover - builds_problems
        """The weights problem built where the tasks are (only with :attr:`builds_problems`)."""
        raise NotImplementedError(f"{type(self).__name__} does not build its step problems")

    def dictionary_problem(self, coefficients: NDArray[np.float64], basis: Any,
                           unit_norm: bool) -> Any:  # pragma: no cover - builds_problems
        """The dictionary problem built where the tasks are (only with :attr:`builds_problems`)."""
        raise NotImplementedError(f"{type(self).__name__} does not build its step problems")
