"""What every objective shares: a batched per-task loss over rewards, bound to the data.

An objective turns rewards into a loss per task and ``dJ/dR`` (docs/maths.md §5, §6); everything
else (planning, step solvers, the factorial scheme) is shared and never knows which objective
runs. Subclasses implement the forward pass (:meth:`Objective._forward`), what warm-starts the
next one (:meth:`Objective._warm_start`) and the gradient (:meth:`Objective._grad`);
least-squares objectives (``least_squares = True``) also give residuals and their
derivatives, which the Gauss-Newton solvers need.
"""

import numpy as np

from .._validation import check_beta, check_mdp, check_statistics
from ..exceptions import ValidationError
from ..planning import get_planner

__all__ = ["Objective"]


class Objective:
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

    Attributes
    ----------
    n_evaluations : int
        Batched planning evaluations so far (one call plans every task it is asked about at
        once; a repeated call at the same rewards is served from a cache and not counted).
    n_tasks : int
    """

    name = "base"
    #: whether the loss is ``||residual||^2`` per task (Gauss-Newton solvers apply)
    least_squares = False

    def __init__(self, mdp, mu_hat, pi_hat, beta, planner="auto"):
        self.mdp = check_mdp(mdp)
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

    def loss_and_grad(self, rewards, rows=None):
        """Loss per task (r,) and ``dJ/dR`` (r, S, A) at ``rewards`` of tasks ``rows``.

        A task last evaluated at exactly these rewards is served from a per-task cache (no
        planning, not counted).
        """
        rows = self._rows(rows)
        rewards = np.asarray(rewards, dtype=np.float64)
        if np.array_equal(self._last_R[rows], rewards):
            return self._last_loss[rows].copy(), self._last_grad[rows].copy()
        point = self._evaluate(rewards, rows)
        grad = self._grad(point)
        self._last_R[rows], self._last_loss[rows], self._last_grad[rows] = rewards, point.loss, grad
        return point.loss, grad

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
        point = self._evaluate(rewards, self._rows(rows))
        return point.loss, self._linearize(point).residual, self._jacobian(point, features)

    def linearize(self, rewards, rows=None):
        """``solvers.Linearization`` at ``rewards`` of tasks ``rows``, in reward space.

        ``residual`` is (r, m); ``jvp`` maps reward directions (r, S, A) to (r, m) (forward mode,
        one solve per task); ``vjp`` maps (r, m) to (r, S, A) (one transposed solve per task).
        """
        self._require_least_squares("linearize")
        return self._linearize(self._evaluate(rewards, self._rows(rows)))
