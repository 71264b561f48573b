"""The dense planner: batched dense LU on (n, S, S) systems (docs/maths.md §4).

Best for small S (the paper's 10x10 grid). Systems are built chunk by chunk from the policies,
never all n (S, S) matrices at once; nothing is kept between calls, so the planner has no cache
and is safe to share between threads.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._batched import rows_matmul
from ..exceptions import ValidationError
from .base import Planner, PolicySystem

__all__ = ["DensePlanner", "DenseSystem", "DENSE_CHUNK_BYTES"]

#: memory for one chunk of dense (c, S, S) systems
DENSE_CHUNK_BYTES = 256 * 2**20


class DenseSystem(PolicySystem):
    """Dense systems built chunk by chunk from the policies (never all n (S, S) at once)."""

    def __init__(self, planner: DensePlanner, policy: NDArray[Any]) -> None:
        self.planner, self.policy, self.n = planner, policy, policy.shape[0]

    def _solve(self, B: NDArray[np.float64], transpose: bool) -> NDArray[np.float64]:
        S = self.planner.S
        chunk = max(1, DENSE_CHUNK_BYTES // (8 * S * S))
        out = np.empty_like(B, dtype=np.float64)
        for lo in range(0, self.n, chunk):
            sl = slice(lo, lo + chunk)
            M = np.eye(S)[None] - self.planner.gamma * self.planner.policy_matrix(self.policy[sl])
            b = B[sl]
            x = np.linalg.solve(np.swapaxes(M, 1, 2) if transpose else M, b[..., None] if b.ndim == 2 else b)
            out[sl] = x[..., 0] if b.ndim == 2 else x
        return out

    def solve(self, B: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._solve(B, False)

    def solve_transpose(self, B: NDArray[np.float64]) -> NDArray[np.float64]:
        return self._solve(B, True)


class DensePlanner(Planner):
    """Batched dense LU on (n, S, S) systems (best for small S).

    Howard's policy iteration from the immediate-reward greedy policy (the base class's
    :meth:`~Planner.initial_policy` and :meth:`~Planner.refine_policy`). Refuses a sparse model
    whose dense (S, A, S) copy would exceed twice :data:`DENSE_CHUNK_BYTES`.
    """

    name = "dense"

    def __init__(self, mdp: Any) -> None:
        super().__init__(mdp)
        if mdp.is_sparse and 8 * self.S * self.S * self.A > DENSE_CHUNK_BYTES * 2:
            raise ValidationError(
                f"the dense planner needs the (S, A, S) = ({self.S}, {self.A}, {self.S}) transitions "
                f"({8 * self.S * self.S * self.A / 2**30:.2f} GiB) of this sparse model; use planner='sparse-lu' or 'auto'"
            )
        self.P3 = mdp.transitions
        self.P2 = self.P3.reshape(self.S * self.A, self.S)

    def backup(self, V: NDArray[np.float64]) -> NDArray[np.float64]:
        if V.ndim == 3:  # k directions: (n, S, k) -> (n, S*A, k)
            return self.P2 @ V
        return rows_matmul(V, self.P2.T).reshape(V.shape[0], self.S, self.A)

    def pullback(self, G: NDArray[np.float64]) -> NDArray[np.float64]:
        return rows_matmul(G.reshape(G.shape[0], self.S * self.A), self.P2)

    def policy_matrix(self, policy: NDArray[Any]) -> NDArray[np.float64]:
        """``P_pi`` (n, S, S) of deterministic (n, S) or stochastic (n, S, A) policies."""
        if policy.ndim == 2:
            return self.P3[np.arange(self.S)[None, :], policy]
        return np.einsum("nsa,sat->nst", policy, self.P3)

    def system(self, policy: NDArray[Any], hints: list[Any] | None = None) -> DenseSystem:
        return DenseSystem(self, policy)
