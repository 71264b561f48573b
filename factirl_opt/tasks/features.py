"""Reward features per task: ``R_i = Phi_i w_i`` when every task has its own environment.

With tasks in several environments each task ``i`` has its own features ``Phi_i``, state
features (S_i, p) or state-action features (S_i*A, p), with one shared column meaning (the
same p). This module holds the products the learners need (docs/maths.md §7, §8):

- rewards ``R_i = Phi_i w_i`` (:meth:`TaskFeatures.rewards`), with ``w_i = D h_i`` in the
  factorial model;
- the chain rule ``dJ_i/dw_i = Phi_i^T y_i`` from ``y_i = dJ_i/dR_i`` (:meth:`TaskFeatures.pull`),
  hence ``dJ/dh_i = D^T Phi_i^T y_i`` (eq. 12) and the dictionary gradient
  ``dJ/dD = sum_i Phi_i^T y_i h_i^T`` (eq. 11; :meth:`TaskFeatures.dictionary_gradient`);
- the per-task Jacobian features ``Phi_i M`` (e.g. ``Phi_i D`` for the Gauss-Newton H-step;
  :meth:`TaskFeatures.products`).

State features are never repeated over the actions: ``Phi_i^T y_i`` is computed as
``Phi_i^T sum_a y_i(., a)`` (A times less memory and work than the (S*A, p) copy).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._batched import rows_matmul
from .._validation import check_array, check_int
from ..exceptions import ValidationError
from ..mdp.environments import check_environments
from ..mdp.tabular import TabularMDP

__all__ = ["TaskFeatures", "StateBroadcast", "task_rewards", "linear_rewards", "factorial_rewards", "feature_rewards",
           "dense_features", "FEATURE_SCALE_LIMIT", "overflow_error", "check_reward_scale"]


class TaskFeatures:
    """One feature matrix per task, validated against each task's environment size.

    Parameters
    ----------
    features : sequence of n array_like, each (S_i, p) or (S_i*A, p)
        Task ``i``'s state or state-action features (row ``s`` or ``s * A + a``).
    n_states : array_like of int, shape (n,)
        ``S_i`` of each task's MDP.
    n_actions : int
        ``A``, shared by every environment.

    Attributes
    ----------
    n_tasks, n_features, n_actions : int
    n_states : ndarray of intp, shape (n,)
    state_features : ndarray of bool, shape (n,)
        Whether task ``i``'s features are per state (repeated over the actions).
    ragged : bool
        Whether the tasks' numbers of states differ (per-task arrays are then lists).

    Raises
    ------
    ValidationError
        For a wrong count, or features whose rows or columns do not fit, naming the task.
    """

    def __init__(self, features: Sequence[ArrayLike], n_states: ArrayLike, n_actions: int) -> None:
        self.n_actions = check_int(n_actions, "n_actions", minimum=1)
        S = np.asarray(n_states, dtype=np.intp).reshape(-1)
        if isinstance(features, np.ndarray) and features.ndim == 2 or not isinstance(features, (Sequence, np.ndarray)):
            raise ValidationError("features must be a sequence of one (S_i, p) or (S_i*A, p) matrix per task")
        if len(features) != S.size:
            raise ValidationError(f"got {len(features)} feature matrices for {S.size} tasks: give one per task")
        self._F: list[NDArray[np.float64]] = []
        for i, F in enumerate(features):
            F = check_array(F, f"features[{i}] (task {i})", ndim=2)
            if F.shape[0] not in (S[i], S[i] * self.n_actions):
                raise ValidationError(f"features of task {i} must have S = {S[i]} or S*A = {S[i] * self.n_actions} rows "
                                      f"(its MDP); got {F.shape}")
            if F.shape[1] != np.shape(self._F[0] if self._F else F)[1]:
                raise ValidationError(f"every task's features must have the same number of columns p: task {i} has "
                                      f"{F.shape[1]}, task 0 has {self._F[0].shape[1]}")
            self._F.append(F)
        self.n_states, self.n_tasks, self.n_features = S, S.size, self._F[0].shape[1]
        self.state_features = np.array([F.shape[0] == s and s * self.n_actions != s for F, s in zip(self._F, S)])
        self.ragged = bool(np.any(S != S[0]))

    @classmethod
    def _trusted(cls, matrices: list[NDArray[np.float64]], like: TaskFeatures) -> TaskFeatures:
        """Matrices already validated (products of ``like``'s), with ``like``'s sizes and kinds."""
        out = cls.__new__(cls)
        out._F, out.n_actions, out.n_states, out.n_tasks = matrices, like.n_actions, like.n_states, like.n_tasks
        out.n_features, out.state_features, out.ragged = matrices[0].shape[1], like.state_features, like.ragged
        return out

    def times(self, M: ArrayLike) -> TaskFeatures:
        """The per-task features ``Phi_i M`` (p, k) -> (S_i or S_i*A, k), kept per state where ``Phi_i`` is.

        E.g. ``Phi_i D``, the features of the H-step (eq. 12): per-state products stay (S_i, k).
        """
        Mx = check_array(M, "M", ndim=2)
        if Mx.shape[0] != self.n_features:
            raise ValidationError(f"M must have shape ({self.n_features}, k); got {Mx.shape}")
        with np.errstate(over="ignore", invalid="ignore"):
            prods = [F @ Mx for F in self._F]
        if not all(np.all(np.isfinite(P)) for P in prods):
            raise ValidationError(
                f"the product features @ dictionary overflows float64: the largest |dictionary entry| is "
                f"{np.max(np.abs(Mx)):.3g}; rescale the features (e.g. to entries of order 1)")
        return TaskFeatures._trusted(prods, self)

    def dense(self, rows: ArrayLike | None = None) -> list[NDArray[np.float64]]:
        """Task features of ``rows`` as (S_i*A, p) matrices (per-state features repeated over the actions)."""
        return [np.repeat(self._F[i], self.n_actions, axis=0) if self.state_features[i] else self._F[i]
                for i in self._rows(rows)]

    def _rows(self, rows: ArrayLike | None) -> NDArray[np.intp]:
        return np.arange(self.n_tasks) if rows is None else np.asarray(rows, dtype=np.intp).reshape(-1)

    def take(self, rows: ArrayLike) -> TaskFeatures:
        """The features of tasks ``rows`` only (a row subset, in the order of ``rows``)."""
        idx = self._rows(rows)
        out = TaskFeatures.__new__(TaskFeatures)
        out._F, out.n_actions, out.n_states = [self._F[i] for i in idx], self.n_actions, self.n_states[idx]
        out.n_tasks, out.n_features, out.state_features = idx.size, self.n_features, self.state_features[idx]
        out.ragged = bool(idx.size and np.any(out.n_states != out.n_states[0]))
        return out

    def matrix(self, task: int) -> NDArray[np.float64]:
        """Task ``task``'s features as given ((S_i, p) or (S_i*A, p))."""
        return self._F[task]

    def rewards(self, weights: ArrayLike, rows: ArrayLike | None = None) -> Any:
        """``R_i = Phi_i w_i`` for weights (r, p) of tasks ``rows``; stacked (r, S, A) or a list of (S_i, A).

        With a trailing axis, weights (r, p, k) give directions (S_i, A, k) (e.g. ``Phi_i M``).
        """
        rows = self._rows(rows)
        W = np.asarray(weights, dtype=np.float64)
        if W.shape[0] != rows.size or W.shape[1] != self.n_features:
            raise ValidationError(f"weights must have shape ({rows.size}, {self.n_features}, ...); got {W.shape}")
        A, out = self.n_actions, []
        for j, i in enumerate(rows):
            R = self._F[i] @ W[j]
            S = int(self.n_states[i])
            if self.state_features[i]:
                R = np.repeat(R[:, None], A, axis=1)
            out.append(R.reshape(S, A, *W.shape[2:]))
        return out if self.ragged else np.stack(out)

    def pull(self, grads: Any, rows: ArrayLike | None = None) -> NDArray[np.float64]:
        """``Phi_i^T y_i`` (r, p) for reward gradients ``y_i`` (S_i, A) of tasks ``rows`` (stacked or a list)."""
        rows = self._rows(rows)
        if len(grads) != rows.size:
            raise ValidationError(f"grads must hold one (S_i, A) array per row ({rows.size}); got {len(grads)}")
        out = np.empty((rows.size, self.n_features))
        for j, i in enumerate(rows):
            y = np.asarray(grads[j], dtype=np.float64)
            S = int(self.n_states[i])
            if y.shape != (S, self.n_actions):
                raise ValidationError(f"the gradient of task {int(i)} must have shape ({S}, {self.n_actions}); got {y.shape}")
            out[j] = self._F[i].T @ (y.sum(axis=1) if self.state_features[i] else y.reshape(-1))
        return out

    def dictionary_gradient(self, grads: Any, coefficients: ArrayLike) -> NDArray[np.float64]:
        """``sum_i Phi_i^T y_i h_i^T`` (p, k) over every task (eq. 11), ``H`` (n, k)."""
        H = check_array(coefficients, "coefficients", ndim=2)
        if H.shape[0] != self.n_tasks:
            raise ValidationError(f"coefficients must have one row per task ({self.n_tasks}); got {H.shape}")
        return self.pull(grads).T @ H

    def products(self, M: ArrayLike, rows: ArrayLike | None = None) -> list[NDArray[np.float64]]:
        """Per-task ``Phi_i M`` as (S_i*A, k) matrices, e.g. the H-step's features ``Phi_i D``."""
        rows = self._rows(rows)
        Mx = check_array(M, "M", ndim=2)
        if Mx.shape[0] != self.n_features:
            raise ValidationError(f"M must have shape ({self.n_features}, k); got {Mx.shape}")
        dirs = self.rewards(np.broadcast_to(Mx, (rows.size, *Mx.shape)), rows)
        return [np.reshape(d, (-1, Mx.shape[1])) for d in dirs]


def _feature_list(features: Any, n: int) -> list[Any]:
    """n per-task feature matrices: one shared 2-d matrix repeated, or the n given."""
    if isinstance(features, np.ndarray):
        if features.ndim != 3:
            return [check_array(features, "features", ndim=2)] * n
        shared = False
    elif isinstance(features, Sequence) and not isinstance(features, (str, bytes)) and len(features) > 0:
        shared = np.ndim(features[0]) != 2
    else:
        raise ValidationError(f"features must be one (S, p) or (S*A, p) matrix or a sequence of one per task; "
                              f"got {type(features).__name__}")
    if shared:
        return [check_array(features, "features", ndim=2)] * n
    if len(features) != n:
        raise ValidationError(f"got {len(features)} feature matrices for {n} tasks (the rows of weights): give one per "
                              "task, or one shared matrix")
    return list(features)


def feature_rewards(features: ArrayLike | Sequence[ArrayLike], weights: ArrayLike,
                    mdps: TabularMDP | Sequence[TabularMDP] | None = None) -> NDArray[np.float64] | list[NDArray[np.float64]]:
    """Rewards ``R_i = Phi_i w_i`` of feature weights, on the tasks' own or on new environments.

    The way to score a reward learnt on features where no demonstration was given
    (docs/maths.md §7, §9)::

        fo.deviation(new_mdps, true_rewards, fo.feature_rewards(new_features, model.weights_, new_mdps))

    Parameters
    ----------
    features : array_like (S, p) or (S*A, p), or sequence of n array_like (S_i, p) or (S_i*A, p)
        One matrix shared by every task, or one per task (rows ``s`` for state features, rows
        ``s * A + a`` for state-action features); the same p columns everywhere.
    weights : array_like, shape (n, p)
        Row ``i`` weights task ``i``'s features (e.g. a flat learner's ``weights_``, or ``D h_i``).
    mdps : TabularMDP or sequence of n TabularMDP, optional
        The environments the rewards are for: they give ``A`` and check each ``S_i``. Without
        them, the rows of every matrix are states (state features only).

    Returns
    -------
    rewards : ndarray or list of ndarray
        With ``mdps``: (n, S, A) when every task has S states, else a list of n (S_i, A)
        arrays. Without: state rewards (n, S), or a list of n (S_i,) arrays, which every
        scoring function repeats over the actions.

    Raises
    ------
    ValidationError
        For weights that are not (n, p) with n >= 1, a wrong number of matrices or MDPs,
        features whose rows or columns do not fit, or rewards that overflow float64 (naming
        the task).
    """
    W = check_array(weights, "weights", ndim=2)
    n = W.shape[0]
    if n == 0:
        raise ValidationError(f"weights must have shape (n, p) with n >= 1 (one row per task); got {W.shape}")
    F = _feature_list(features, n)
    if mdps is None:
        rows = [np.shape(f)[0] for f in F]
        if 0 in rows:
            raise ValidationError(f"features of task {rows.index(0)} have no rows (shape {np.shape(F[rows.index(0)])}); "
                                  "give one row per state")
        with np.errstate(over="ignore", invalid="ignore"):  # an overflow is reported below, naming the task
            R = _check_overflow(TaskFeatures(F, rows, 1).rewards(W), F, W)
        return [r[:, 0] for r in R] if isinstance(R, list) else R[:, :, 0]
    envs = check_environments(mdps, n)
    with np.errstate(over="ignore", invalid="ignore"):
        return _check_overflow(TaskFeatures(F, [m.n_states for m in envs], envs[0].n_actions).rewards(W), F, W)


def _check_overflow(R: Any, F: list[Any], W: NDArray[np.float64]) -> Any:
    """``R`` (an array or a list of per-task arrays), or a ValidationError naming the first task whose rewards overflow."""
    for i, r in enumerate(R):
        if not np.all(np.isfinite(r)):
            raise ValidationError(
                f"the rewards features @ weights of task {i} overflow float64 (largest |features| entry "
                f"{np.max(np.abs(np.asarray(F[i], dtype=float))):.3g}, largest |weights[{i}]| entry {np.max(np.abs(W[i])):.3g}): "
                "rescale the features or the weights towards order 1")
    return R


class StateBroadcast:
    """``Phi = kron(I_S, 1_A)``, shape (S*A, S): a state reward repeated over the actions, never formed.

    Row ``s * A + a`` of ``Phi`` is the indicator of state ``s``, so ``Phi w`` is the reward
    ``R(s, a) = w(s)`` and ``Phi^T y`` sums ``y(s, a)`` over the actions: both cost O(S*A)
    per column, the cost of tabular rewards. Supports the products the learners use,
    ``Phi @ M`` (S, m) -> (S*A, m), ``Y @ Phi`` (r, S*A) -> (r, S), ``Phi.T @ G``
    (S*A, m) -> (S, m) and ``X @ Phi.T`` (r, S) -> (r, S*A), and :meth:`toarray`.
    """

    __array_ufunc__ = None  # ndarray @ StateBroadcast defers to __rmatmul__

    def __init__(self, n_states: int, n_actions: int) -> None:
        self.n_states, self.n_actions = int(n_states), int(n_actions)
        self.shape = (self.n_states * self.n_actions, self.n_states)

    def __matmul__(self, M: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.repeat(np.asarray(M, dtype=np.float64), self.n_actions, axis=0)

    def __rmatmul__(self, Y: NDArray[np.float64]) -> NDArray[np.float64]:
        Y = np.asarray(Y, dtype=np.float64)
        return Y.reshape(*Y.shape[:-1], self.n_states, self.n_actions).sum(axis=-1)

    @property
    def T(self) -> "_SumOverActions":
        return _SumOverActions(self)

    def toarray(self) -> NDArray[np.float64]:
        """The dense (S*A, S) matrix (for Jacobians with one column per parameter)."""
        return np.kron(np.eye(self.n_states), np.ones((self.n_actions, 1))).astype(np.float64)


class _SumOverActions:
    """``Phi^T`` of a :class:`StateBroadcast` (S, S*A)."""

    __array_ufunc__ = None

    def __init__(self, phi: StateBroadcast) -> None:
        self.phi = phi
        self.shape = phi.shape[::-1]

    def __matmul__(self, G: NDArray[np.float64]) -> NDArray[np.float64]:
        G = np.asarray(G, dtype=np.float64)
        return G.reshape(self.phi.n_states, self.phi.n_actions, *G.shape[1:]).sum(axis=1)

    def __rmatmul__(self, X: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.repeat(np.asarray(X, dtype=np.float64), self.phi.n_actions, axis=-1)


#: largest |entry| of features treated as "of order 1" when naming the cause of an overflow
FEATURE_SCALE_LIMIT = 1e8


def dense_features(features: Any) -> NDArray[np.float64] | None:
    """``features`` as a dense (S*A, p) array (a :class:`StateBroadcast` formed), or None."""
    return features.toarray() if isinstance(features, StateBroadcast) else features


def _largest(a: Any) -> float:
    if isinstance(a, TaskFeatures):
        a = [a.matrix(i) for i in range(a.n_tasks)]
    if isinstance(a, StateBroadcast):
        return 1.0
    parts = a if isinstance(a, list) else [a]
    with np.errstate(invalid="ignore"):
        return max((float(np.max(np.abs(np.asarray(x, dtype=np.float64)), initial=0.0)) for x in parts), default=0.0)


def overflow_error(features: Any, weights: Any, names: tuple[str, str] = ("features", "weights")) -> ValidationError:
    """The error of rewards ``features @ weights`` that overflow: both inputs' largest magnitudes, and
    which to rescale (the features when an entry exceeds ``FEATURE_SCALE_LIMIT``)."""
    big_f, big_w = _largest(features), _largest(weights)
    if big_f > FEATURE_SCALE_LIMIT or not big_w > FEATURE_SCALE_LIMIT:  # the weights grow with the features' scale
        advice = f"the {names[0]} are far from order 1: rescale them (e.g. divide by {big_f:.3g})"
    else:
        advice = f"the {names[1]} grew to {big_w:.3g}: rescale the {names[0]} or start from smaller {names[1]}"
    return ValidationError(
        f"the rewards {names[0]} @ {names[1]} overflow float64 (largest |{names[0]}| = {big_f:.3g}, largest "
        f"|{names[1]}| = {big_w:.3g}): {advice}"
    )


def _first_non_finite(a: Any) -> str | None:
    """Where ``a`` (an array, a list of arrays, TaskFeatures) first holds NaN or inf, as text; None if nowhere."""
    if isinstance(a, TaskFeatures):
        a = [a.matrix(i) for i in range(a.n_tasks)]
    if isinstance(a, StateBroadcast):
        return None
    parts = a if isinstance(a, list) else [a]
    for k, x in enumerate(parts):
        x = np.asarray(x)
        if x.dtype.kind not in "fc":
            continue
        bad = np.argwhere(~np.isfinite(x))
        if bad.size:
            at = tuple(int(i) for i in bad[0])
            return f"{x[at]!s} at index {at}" + (f" of matrix {k}" if len(parts) > 1 else "")
    return None


def non_finite_error(features: Any, weights: Any, names: tuple[str, str] = ("features", "weights")) -> ValidationError | None:
    """The error of rewards ``features @ weights`` whose inputs hold NaN or inf (not an overflow), naming
    the input and the entry; None when both are finite."""
    for name, value in zip(names, (features, weights)):
        where = _first_non_finite(value)
        if where is not None:
            return ValidationError(f"the rewards {names[0]} @ {names[1]} are not finite: the {name} hold {where}")
    return None


def check_reward_scale(rewards: Any, limit: float, features: Any, weights: Any, names: tuple[str, str]) -> Any:
    """``rewards`` (an array, or a list of per-task arrays) formed as ``features @ weights``, or an
    error when they are not finite or reach ``limit`` (:func:`reward_limit`): the planner would
    overflow on them. The error names a non-finite input (:func:`non_finite_error`), else the
    overflow and what to rescale (:func:`overflow_error`); the inputs are read only then."""
    big = _largest(rewards)
    if not big <= limit:
        raise non_finite_error(features, weights, names) or overflow_error(features, weights, names)
    return rewards


def linear_rewards(features: Any, weights: NDArray[np.float64], n_states: int, n_actions: int,
                   names: tuple[str, str] = ("features", "weights")) -> NDArray[np.float64]:
    """Rewards ``R_i = F w_i`` as (n, S, A) from ``F`` (S*A, p) and ``W`` (n, p).

    Parameters
    ----------
    features : ndarray, shape (S*A, p), or StateBroadcast
    weights : ndarray, shape (n, p)
    n_states, n_actions : int
    names : (str, str)
        What ``F`` and ``W`` are, for the message.

    Raises
    ------
    ValidationError
        When the product overflows float64; the message names both inputs with their largest
        magnitude and says which to rescale (the features when an entry exceeds
        ``FEATURE_SCALE_LIMIT``).
    """
    if isinstance(features, StateBroadcast):
        return np.repeat(weights, n_actions, axis=1).reshape(-1, n_states, n_actions)
    F_shape, W_shape = np.shape(features), np.shape(weights)
    if len(F_shape) != 2 or F_shape[0] != n_states * n_actions:
        raise ValidationError(f"the {names[0]} must have shape (S*A, p) = ({n_states * n_actions}, p); got {F_shape}")
    if len(W_shape) != 2 or W_shape[1] != F_shape[1]:
        raise ValidationError(f"the {names[1]} must have shape (n, p) = (n, {F_shape[1]}) (p: the {names[0]}' columns); "
                              f"got {W_shape}")
    try:
        return task_rewards(features, weights, n_states, n_actions)
    except ValidationError:
        raise non_finite_error(features, weights, names) or overflow_error(features, weights, names) from None


def task_rewards(dictionary: ArrayLike, coefficients: ArrayLike, n_states: int, n_actions: int) -> NDArray[np.float64]:
    """Rewards ``R_i = D h_i`` as (n, S, A) from D (S*A, k) and H (n, k).

    The library's one home of this product (FactIRL's rewards, transfer, the experiments).
    For rewards on base features ``Phi`` (S*A, p) pass ``Phi @ D`` as the dictionary.
    """
    D = check_array(dictionary, "dictionary", ndim=2)
    H = check_array(coefficients, "coefficients", ndim=2)
    if D.shape[0] != n_states * n_actions:
        raise ValidationError(f"dictionary must have shape (S*A, k) = ({n_states * n_actions}, k); got {D.shape}")
    if H.shape[1] != D.shape[1]:
        raise ValidationError(f"coefficients must have shape (n, {D.shape[1]}); got {H.shape}")
    with np.errstate(over="ignore", invalid="ignore"):
        R = rows_matmul(H, D.T).reshape(-1, n_states, n_actions)
    if not np.all(np.isfinite(R)):
        i = int(np.argmax(~np.all(np.isfinite(R.reshape(len(R), -1)), axis=1)))
        raise ValidationError(
            f"the rewards D h_i of task {i} overflow float64 (largest |dictionary| entry {np.max(np.abs(D)):.3g}, "
            f"largest |coefficients[{i}]| entry {np.max(np.abs(H[i])):.3g}): rescale the dictionary (for rewards on base "
            "features Phi, the dictionary given here is Phi @ D: rescale the features) or the coefficients"
        )
    return R


def factorial_rewards(mdp: Any, Phi: Any, D: NDArray[np.float64], H: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rewards ``R_i = Phi D h_i`` (n, S, A) from D (p, k) and H (n, k); ``Phi`` None is tabular.

    The older form of :meth:`factirl_opt.tasks.basis.RewardBasis.factorial_rewards` (the same
    products), for callers holding features rather than a basis.

    An overflow names the inputs (:func:`linear_rewards`). With per-task
    features ``Phi`` (:class:`~factirl_opt.tasks.features.TaskFeatures`; ``mdp`` unused) the
    rewards are stacked (n, S, A) for equal-sized environments, else a list of (S_i, A).
    """
    if isinstance(Phi, TaskFeatures):
        return Phi.times(D).rewards(H)
    if Phi is None:
        return linear_rewards(D, H, mdp.n_states, mdp.n_actions, ("dictionary", "coefficients"))
    with np.errstate(over="ignore", invalid="ignore"):
        F = Phi @ D
    if not np.all(np.isfinite(F)):  # a StateBroadcast only repeats D: a feature matrix overflowed
        raise ValidationError(
            f"the product features @ dictionary overflows float64: the largest |feature| is {np.max(np.abs(Phi)):.3g} and "
            f"the largest |dictionary entry| {np.max(np.abs(D)):.3g}; rescale the features (e.g. to entries of order 1)")
    return linear_rewards(F, H, mdp.n_states, mdp.n_actions, ("features @ dictionary", "coefficients"))


def weights_rewards(features: Any, weights: NDArray[np.float64], n_states: int, n_actions: int) -> NDArray[np.float64]:
    """Rewards (n, S, A) of weights (n, p): ``R_i = F w_i``, or ``w_i`` reshaped when ``F`` is None (tabular)."""
    if features is None:
        return weights.reshape(-1, n_states, n_actions)
    return linear_rewards(features, weights, n_states, n_actions)
