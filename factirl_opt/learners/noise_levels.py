"""The noise level of a task's demonstrations, estimated from its misfit (docs/maths.md §10).

Under policy matching, eq. (5)'s residuals have a variance per visit that the multinomial model
of the demonstrations fixes; a task whose demonstrations the model explains worse than that has a
larger one. :func:`misfit_noise_levels` estimates it per task as regression does (``s^2 = RSS /
(n - d)``); a fit stores its training tasks' levels (``FactIRL.noise_levels_``,
:func:`task_noise_levels`), and with ``PosteriorSettings(noise="misfit")`` the transfer
posterior scales each new task's curvature by its own level over their median
(:func:`noise_reference`, :func:`noise_ratios`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from ..exceptions import ValidationError

__all__ = ["NOISE_RATIO_MIN", "misfit_noise_levels", "task_noise_levels", "noise_reference", "noise_ratios"]


#: the smallest ratio of a new task's noise level to the training tasks' (:func:`laplace_posteriors`'s
#: ``noise_reference``): a demonstration its MAP matches exactly does not make the likelihood infinitely sharp
NOISE_RATIO_MIN = 0.01


def misfit_noise_levels(loss: ArrayLike, n_pairs: ArrayLike, n_visited: ArrayLike, n_actions: ArrayLike,
                        n_params: int) -> NDArray[np.float64]:
    """Each task's noise level from its misfit, as ``s^2 = RSS / (n - d)`` in regression (docs/maths.md §10).

    ``shat_i^2 = N_i J_i / max(n_i (A - 1) - d, 1)``: eq. (5)'s ``J_i = ||r_i||^2`` at the fit,
    whose residuals ``r = sqrt(mu) (pi - pi_hat)`` have variance ``sigma^2 / N_i`` per component
    (so ``N_i J_i`` is the residual sum of squares on the scale of one visit), over the
    ``n_i (A - 1)`` non-degenerate components of the ``n_i`` demonstrated states less the ``d``
    fitted parameters.

    Parameters
    ----------
    loss : array_like, shape (n,)
        ``J_i`` (policy matching's eq. 5) at each task's fitted rewards.
    n_pairs : array_like, shape (n,)
        ``N_i``, the task's demonstrated (state, action) pairs.
    n_visited : array_like, shape (n,)
        ``n_i``, the distinct states its demonstrations visit.
    n_actions : int or array_like, shape (n,)
    n_params : int
        ``d``, the parameters fitted per task (``k``).

    Returns
    -------
    ndarray, shape (n,)
    """
    J, N = np.asarray(loss, dtype=np.float64), np.asarray(n_pairs, dtype=np.float64)
    dof = np.maximum(np.asarray(n_visited, dtype=np.float64) * (np.asarray(n_actions, dtype=np.float64) - 1) - n_params, 1.0)
    return N * J / dof


def task_noise_levels(tasks: Any, loss: ArrayLike, n_params: int) -> NDArray[np.float64]:
    """:func:`misfit_noise_levels` of a fitted task set (``FactIRL.noise_levels_``): ``loss`` (n,) its per-task eq. (5)."""
    visited = [np.unique(parsed.steps[:, 0]).size for parsed in tasks.demonstrations]  # parsed when the set was made
    return misfit_noise_levels(loss, tasks.n_pairs, visited, tasks.basis.n_actions, n_params)


def noise_reference(model: Any) -> float | None:
    """The training tasks' noise level the posterior scales each new task's by (``PosteriorSettings(noise="misfit")``):
    the median of ``noise_levels_``; None for the multinomial noise level alone."""
    settings = getattr(model, "posterior", None)
    if settings is None or getattr(settings, "noise", "multinomial") != "misfit":
        return None
    levels = getattr(model, "noise_levels_", None)
    if levels is None:
        raise ValidationError("posterior noise='misfit' needs noise_levels_, which this model's fit did not store "
                              "(a policy-matching fit stores them): fit it again")
    return float(np.median(levels))


def noise_ratios(problem: Any, loss: ArrayLike, k: int, reference: float) -> NDArray[np.float64]:
    """``rho_i`` (n,) of :func:`~factirl_opt.learners.posterior.laplace_posteriors`'s ``noise_reference``: each
    task's misfit level at ``loss`` over the reference, floored at :data:`NOISE_RATIO_MIN`."""
    visited = [int(np.count_nonzero(problem.statistics(t)[1] > 0)) for t in range(problem.n_tasks)]
    levels = misfit_noise_levels(loss, problem.n_pairs, visited, [m.n_actions for m in problem.mdps], k)
    return np.maximum(levels / reference, NOISE_RATIO_MIN)
