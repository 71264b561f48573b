"""Boundary checks shared by the public functions (internal)."""

import numpy as np

from .exceptions import ValidationError
from .mdp import TabularMDP


def check_mdp(mdp):
    if not isinstance(mdp, TabularMDP):
        raise ValidationError(f"mdp must be a TabularMDP; got {type(mdp).__name__}")
    return mdp


def check_rewards(mdp, rewards, name="rewards"):
    """Return rewards as float64 (n, S, A) and whether a single (S, A) reward was given."""
    try:
        R = np.asarray(rewards, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValidationError(f"{name} must be a numeric array: {exc}") from None
    S, A = mdp.n_states, mdp.n_actions
    single = R.ndim == 2
    if single:
        R = R[None]
    if R.ndim != 3 or R.shape[1:] != (S, A):
        raise ValidationError(f"{name} must have shape (S, A) = ({S}, {A}) or (n, {S}, {A}); got {np.shape(rewards)}")
    if not np.all(np.isfinite(R)):
        raise ValidationError(f"{name} must be finite; found {float(R[~np.isfinite(R)][0])!r}")
    return R, single


def check_policy(mdp, policy, n, name="policy"):
    """Deterministic policies as int (n, S) actions, or None."""
    if policy is None:
        return None
    pol = np.asarray(policy)
    if pol.ndim == 1:
        pol = pol[None]
    S, A = mdp.n_states, mdp.n_actions
    if pol.shape != (n, S):
        raise ValidationError(f"{name} must have shape ({n}, {S}) (one action per state and task); got {np.shape(policy)}")
    if not np.issubdtype(pol.dtype, np.integer) or np.any((pol < 0) | (pol >= A)):
        raise ValidationError(f"{name} must hold integer actions in [0, {A}); got {pol!r}")
    return pol.astype(np.intp, copy=False)


def check_positive(value, name, allow_zero=False, integer=False):
    ok_type = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    if isinstance(value, bool) or not isinstance(value, ok_type) or not np.isfinite(value):
        kind = "an integer" if integer else "a finite number"
        raise ValidationError(f"{name} must be {kind}; got {value!r}")
    if value < 0 or (value == 0 and not allow_zero):
        raise ValidationError(f"{name} must be {'>= 0' if allow_zero else '> 0'}; got {value!r}")
    return value


def check_statistics(mdp, mu_hat, pi_hat, n=None):
    """Empirical statistics as float64 mu (n, S) and pi (n, S, A)."""
    S, A = mdp.n_states, mdp.n_actions
    mu = np.asarray(mu_hat, dtype=np.float64)
    pi = np.asarray(pi_hat, dtype=np.float64)
    if mu.ndim == 1:
        mu = mu[None]
    if pi.ndim == 2:
        pi = pi[None]
    if mu.ndim != 2 or mu.shape[1] != S:
        raise ValidationError(f"mu_hat must have shape (n, {S}); got {np.shape(mu_hat)}")
    if pi.shape != (mu.shape[0], S, A):
        raise ValidationError(f"pi_hat must have shape ({mu.shape[0]}, {S}, {A}) to match mu_hat {mu.shape}; got {np.shape(pi_hat)}")
    if n is not None and mu.shape[0] != n:
        raise ValidationError(f"mu_hat and pi_hat describe {mu.shape[0]} tasks but rewards describe {n}")
    if not (np.all(np.isfinite(mu)) and np.all(np.isfinite(pi))):
        raise ValidationError("mu_hat and pi_hat must be finite")
    if np.any(mu < 0) or np.any(pi < 0):
        raise ValidationError("mu_hat and pi_hat must be nonnegative")
    return mu, pi
