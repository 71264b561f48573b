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

from ._validation import check_array, check_int
from .exceptions import ValidationError

__all__ = ["TaskFeatures"]


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
