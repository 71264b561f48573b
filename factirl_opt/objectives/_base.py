"""What every objective shares: a batched per-task loss over rewards, bound to the data.

An objective turns rewards into a loss per task and ``dJ/dR`` (docs/maths.md §5, §6); everything
else (planning, step solvers, the factorial scheme) is shared and never knows which objective
runs. Subclasses implement the forward pass (:meth:`Objective._forward`), what warm-starts the
next one (:meth:`Objective._warm_start`) and the gradient (:meth:`Objective._grad`);
least-squares objectives (``least_squares = True``) also give residuals and their
derivatives, which the Gauss-Newton solvers need.

Under a planning memory budget (``planner_options={"max_bytes": ...}`` or
:func:`factirl_opt.planning.planning_budget`) that the tasks of a call do not fit in, every
operation runs chunk by chunk, each chunk's factorisations released before the next
(:mod:`factirl_opt.planning.budget`); without one, or when they fit, every task is planned at
once, as always.
"""

import functools

import numpy as np

from solvers import Linearization

from .._validation import check_beta, check_mdp, check_statistics
from ..exceptions import ValidationError
from ..planning import get_planner, plan
from ..planning.budget import check_planner_options, chunk_size, effective_budget, task_bytes
from .contract import TaskObjective, limit_of

__all__ = ["Objective"]


class Objective(TaskObjective):
    """A per-task loss over a fixed set of tasks, with warm-started planning and counts.

    Parameters
    ----------
    mdp : TabularMDP
    mu_hat : ndarray, shape (n, S)
        Empirical state frequencies.
    pi_hat : ndarray, shape (n, S, A)
        Empirical policies.
    beta : float
        Inverse temperature.
    planner : str or Planner, default="auto"
    planner_options : dict, optional
        ``{"max_bytes": int}``: this objective's planning memory budget in bytes (see
        :mod:`factirl_opt.planning.budget`; default None: the :func:`~factirl_opt.planning.planning_budget`
        in force where a method is called, if any).

    Attributes
    ----------
    n_evaluations : int
        Batched planning evaluations so far (one call plans every task it is asked about at
        once; a repeated call at the same rewards is served from a cache and not counted).
    n_tasks : int
    max_bytes : int or None
        This objective's own planning budget (from ``planner_options``).
    """

    name = "base"
    n_evaluations = 0  # counted per instance (the contract's property, as a plain attribute)
    #: whether the loss is ``||residual||^2`` per task (Gauss-Newton solvers apply)
    least_squares = False
    #: whether the objective gives the Hessian of its loss in linear reward weights (``hessian``)
    has_hessian = False

    @classmethod
    def log_policy(cls, planner, rewards, beta):
        """Action log-probabilities ``log pi(a|s)`` (n, S, A) of the policy this objective models.

        The policy whose fit to the demonstrations the objective measures, as a function of the
        rewards (n, S, A) on the planner's MDP; finite for any finite rewards. Multi-intent EM
        scores episodes with it (:func:`factirl_opt.learners.em.log_policies`).

        Raises
        ------
        ValidationError
            For an objective that models no policy (see :meth:`models_policy`).
        """
        raise ValidationError(f"the objective {cls.name!r} models no policy of the rewards (it defines no log_policy)")

    @classmethod
    def log_policy_and_values(cls, planner, rewards, beta):
        """:meth:`log_policy` (n, S, A) and the optimal state values ``V*`` (n, S) of the same rewards.

        By default the policy and a plan of the rewards of its own; an objective whose policy is
        built on the optimal ``Q*`` gives both from one plan.
        """
        return cls.log_policy(planner, rewards, beta), plan(planner, rewards).V

    @classmethod
    def models_policy(cls):
        """Whether the objective defines :meth:`log_policy` (a policy model that can score episodes)."""
        return cls.log_policy.__func__ is not Objective.log_policy.__func__

    def __init__(self, mdp, mu_hat, pi_hat, beta, planner="auto", planner_options=None):
        self.mdp = check_mdp(mdp)
        self.max_bytes = check_planner_options(planner_options)["max_bytes"]
        self.mu, self.pi_hat = check_statistics(mdp, mu_hat, pi_hat)
        self.beta = check_beta(beta)
        self.planner = get_planner(mdp, planner)
        self.n_tasks = self.mu.shape[0]
        self.n_evaluations = 0
        S, A = mdp.n_states, mdp.n_actions
        self._warm = None  # per-task warm start of the planning (objective-specific)
        self._last_R = np.full((self.n_tasks, S, A), np.nan)
        self._last_loss = np.zeros(self.n_tasks)
        self._last_grad = np.zeros((self.n_tasks, S, A))

    def reward_limit(self):
        """The largest ``|reward|`` planned without overflow on this objective's MDP (:func:`limit_of`)."""
        return limit_of([self.mdp.gamma])

    def reset(self):
        """Forget the warm starts and the last-point cache; keep the statistics and ``n_evaluations``.

        The next evaluations plan from scratch, as those of a new objective over the same data
        would, so one objective (one parse of the demonstrations) can serve fits in turn with
        the results of separate objectives (FactIRL's flat start, then its factorial fit).
        """
        self._warm = None
        self._last_R = np.full_like(self._last_R, np.nan)
        self._last_loss = np.zeros_like(self._last_loss)
        self._last_grad = np.zeros_like(self._last_grad)

    # -- what a subclass implements -----------------------------------------------------------
    def _forward(self, R, rows, warm):  # pragma: no cover - interface
        """Forward pass at rewards R (r, S, A) of tasks ``rows``; an object with ``.loss``.

        ``warm`` is None or the :meth:`_warm_start` of the rows' last points.
        """
        raise NotImplementedError

    def _warm_start(self, point):  # pragma: no cover - interface
        """What starts the next planning of these tasks (an array with the tasks first)."""
        raise NotImplementedError

    def _point(self, R, rows):
        point = self._forward(R, rows, None if self._warm is None else self._warm[rows])
        state = self._warm_start(point)
        if self._warm is None:
            self._warm = np.zeros((self.n_tasks, *state.shape[1:]), dtype=state.dtype)
        self._warm[rows] = state
        return point

    def _grad(self, point):  # pragma: no cover - interface
        """``dJ/dR`` (r, S, A) at a point."""
        raise NotImplementedError

    def _linearize(self, point):  # pragma: no cover - least-squares objectives only
        raise NotImplementedError

    def _jacobian(self, point, features):  # pragma: no cover - least-squares objectives only
        raise NotImplementedError

    # -- the operations step problems use -------------------------------------------------------
    def _rows(self, rows):
        return np.arange(self.n_tasks) if rows is None else np.asarray(rows)

    def _evaluate(self, rewards, rows):
        point = self._point(np.asarray(rewards, dtype=np.float64), rows)
        self.n_evaluations += 1
        return point

    def _chunk(self, n, directions=0):
        """Tasks per chunk under the planning budget in force (``n``: one chunk, as without a budget)."""
        return chunk_size(n, task_bytes(self.planner, directions), effective_budget(self.max_bytes))

    def _chunked(self, rewards, rows, work, size):
        """Loss (r,) and the arrays of ``work(point)`` (a tuple, tasks first) over chunks of ``size``
        tasks, written in place in task order; one evaluation counted. Each chunk is planned with
        a transient factorisation cache and its point dropped before the next, so at most one
        chunk's factorisations are alive (this thread's own cache is emptied first: a budget
        keeps nothing between calls)."""
        self.planner.clear_thread_cache()
        loss, stacked = np.empty(len(rows)), None
        for c in _slices(len(rows), size):
            with self.planner.transient_cache():
                point = self._point(rewards[c], rows[c])
                loss[c], parts = point.loss, work(point)
                del point
            if stacked is None:
                stacked = tuple(np.empty((len(rows), *np.shape(x)[1:]), dtype=np.asarray(x).dtype) for x in parts)
            for out, x in zip(stacked, parts):
                out[c] = x
            del parts
        self.n_evaluations += 1
        return (loss, *stacked)

    def loss_and_grad(self, rewards, rows=None):
        """Loss per task (r,) and ``dJ/dR`` (r, S, A) at ``rewards`` of tasks ``rows``.

        A task last evaluated at exactly these rewards is served from a per-task cache (no
        planning, not counted).
        """
        rows = self._rows(rows)
        rewards = np.asarray(rewards, dtype=np.float64)
        if np.array_equal(self._last_R[rows], rewards):
            return self._last_loss[rows].copy(), self._last_grad[rows].copy()
        size = self._chunk(len(rows))
        if size >= len(rows):
            point = self._evaluate(rewards, rows)
            loss, grad = point.loss, self._grad(point)
        else:
            loss, grad = self._chunked(rewards, rows, lambda point: (self._grad(point),), size)
        self._last_R[rows], self._last_loss[rows], self._last_grad[rows] = rewards, loss, grad
        return loss, grad

    def _require_least_squares(self, what):
        if not self.least_squares:
            raise ValidationError(
                f"{what} needs a least-squares objective (residuals); the {self.name!r} objective has none: "
                "use a gradient solver (armijo, lbfgs)"
            )

    def residual_jacobian(self, rewards, rows, features):
        """Loss (r,), residuals (r, m) and their Jacobian (r, m, p) for rewards ``R = F w``.

        Parameters
        ----------
        features : ndarray, shape (S*A, p)
            ``F``: the Jacobian is with respect to the weights ``w``.
        """
        self._require_least_squares("residual_jacobian")
        rows = self._rows(rows)
        rewards = np.asarray(rewards, dtype=np.float64)
        size = self._chunk(len(rows), np.shape(features)[-1])
        if size >= len(rows):
            point = self._evaluate(rewards, rows)
            return point.loss, self._linearize(point).residual, self._jacobian(point, features)
        return self._chunked(rewards, rows, lambda point: (self._linearize(point).residual,
                                                           self._jacobian(point, features)), size)

    def linearize(self, rewards, rows=None):
        """``solvers.Linearization`` at ``rewards`` of tasks ``rows``, in reward space.

        ``residual`` is (r, m); ``jvp`` maps reward directions (r, S, A) to (r, m) (forward mode,
        one solve per task); ``vjp`` maps (r, m) to (r, S, A) (one transposed solve per task).
        Under a planning budget that the tasks do not fit in, only each task's greedy policy is
        kept, and every product plans each chunk again from it (one factorisation per task, the
        same policy), applies the product and releases the chunk.
        """
        self._require_least_squares("linearize")
        rows = self._rows(rows)
        rewards = np.asarray(rewards, dtype=np.float64)
        size = self._chunk(len(rows))
        if size >= len(rows):
            return self._linearize(self._evaluate(rewards, rows))
        loss, residual, warm = self._chunked(rewards, rows, lambda point: (self._linearize(point).residual,
                                                                           self._warm_start(point)), size)
        rewards, rows = rewards.copy(), rows.copy()  # the caller may reuse its arrays before the products

        def product(name, X):
            X = np.asarray(X)
            return np.concatenate([self._replayed(name, rewards[c], rows[c], warm[c], X[c])
                                   for c in _slices(len(rows), size)])

        return Linearization(loss, residual, functools.partial(product, "jvp"), functools.partial(product, "vjp"))

    def _replayed(self, name, R, rows, warm, X):
        """The Jacobian product ``name`` (``"jvp"`` or ``"vjp"``) of X at tasks ``rows``, planned
        again from their greedy policies ``warm`` with a transient cache (not counted)."""
        with self.planner.transient_cache():
            return getattr(self._linearize(self._forward(R, rows, warm)), name)(X)


def _slices(n, size):
    """Consecutive slices of ``size`` positions covering ``range(n)``."""
    return [slice(lo, lo + size) for lo in range(0, n, size)]
