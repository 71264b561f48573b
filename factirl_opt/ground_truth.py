"""Ground-truth generators for experiments: random dictionaries and mixing coefficients.

Distributions (DESIGN section 4 leaves them open; fixed here):

- dictionary: ``D[j, l] ~ N(0, 1)`` i.i.d. over (state, action) pairs j and primitives l;
- ``"gaussian"`` coefficients: ``H[i, l] ~ N(0, 1)``;
- ``"nonneg"`` coefficients: ``H[i, l] = |N(0, 1)|`` (half-normal), for the nonnegative
  H-step variants;
- ``sparsity`` (both kinds): each coefficient is zeroed with that probability, keeping at
  least one nonzero coefficient per task.

Task rewards are ``R_i = D h_i`` reshaped to (S, A).
"""

import numpy as np

from ._validation import check_positive
from .demonstrations import as_rng
from .exceptions import ValidationError

__all__ = ["random_dictionary", "random_coefficients", "task_rewards"]

COEFFICIENT_KINDS = ("gaussian", "nonneg")


def random_dictionary(n_params, n_primitives=5, rng=None):
    """A random dictionary ``D`` of shape (n_params, n_primitives), entries N(0, 1)."""
    check_positive(n_params, "n_params", integer=True)
    check_positive(n_primitives, "n_primitives", integer=True)
    return as_rng(rng).standard_normal((n_params, n_primitives))


def random_coefficients(n_tasks, n_primitives=5, kind="gaussian", sparsity=0.0, rng=None):
    """Random mixing coefficients ``H`` of shape (n_tasks, n_primitives).

    Parameters
    ----------
    kind : {"gaussian", "nonneg"}
        N(0, 1) or half-normal |N(0, 1)| entries.
    sparsity : float in [0, 1)
        Probability that a coefficient is zero (at least one stays nonzero per task).
    """
    check_positive(n_tasks, "n_tasks", integer=True)
    check_positive(n_primitives, "n_primitives", integer=True)
    if kind not in COEFFICIENT_KINDS:
        raise ValidationError(f"kind must be one of {COEFFICIENT_KINDS}; got {kind!r}")
    if not (isinstance(sparsity, (int, float)) and 0.0 <= sparsity < 1.0):
        raise ValidationError(f"sparsity must be a probability in [0, 1); got {sparsity!r}")
    rng = as_rng(rng)
    H = rng.standard_normal((n_tasks, n_primitives))
    if kind == "nonneg":
        H = np.abs(H)
    if sparsity > 0:
        zero = rng.random((n_tasks, n_primitives)) < sparsity
        keep = rng.integers(0, n_primitives, size=n_tasks)
        zero[np.arange(n_tasks), keep] = False
        H[zero] = 0.0
    return H


def task_rewards(dictionary, coefficients, n_states, n_actions):
    """Rewards ``R_i = D h_i`` as (n, S, A) from D (S*A, k) and H (n, k)."""
    D = np.asarray(dictionary, dtype=np.float64)
    H = np.asarray(coefficients, dtype=np.float64)
    if D.ndim != 2 or D.shape[0] != n_states * n_actions:
        raise ValidationError(f"dictionary must have shape (S*A, k) = ({n_states * n_actions}, k); got {D.shape}")
    if H.ndim != 2 or H.shape[1] != D.shape[1]:
        raise ValidationError(f"coefficients must have shape (n, {D.shape[1]}); got {H.shape}")
    return (H @ D.T).reshape(-1, n_states, n_actions)
