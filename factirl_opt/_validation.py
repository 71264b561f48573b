"""Boundary checks shared by the whole library (internal; the one home of every validator).

Every public function and estimator validates its arguments with these helpers, so a bad value
gets the same rule and the same message wherever it enters. All raise
:class:`~factirl_opt.exceptions.ValidationError` naming the argument and the bad value.
"""

import numbers
import sys

import numpy as np

from .exceptions import ValidationError

#: largest ``|R| / (1 - gamma)`` accepted: values (and their differences) stay finite in float64
REWARD_LIMIT = 1e300

__all__ = [
    "as_rng",
    "check_int",
    "check_real",
    "check_beta",
    "check_probability",
    "check_tol",
    "check_array",
    "check_real_dtype",
    "check_mdp",
    "check_rewards",
    "check_policy",
    "check_statistics",
    "check_features",
    "check_stochastic_policy",
]


def as_rng(rng):
    """A ``numpy.random.Generator`` from a Generator, a seed, a SeedSequence or None."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (numbers.Integral, np.random.SeedSequence)) and not isinstance(rng, bool):
        if isinstance(rng, numbers.Integral) and rng < 0:
            raise ValidationError(f"rng seed must be >= 0; got {rng!r}")
        return np.random.default_rng(rng)
    raise ValidationError(f"rng must be a numpy Generator, a SeedSequence, an int seed or None; got {type(rng).__name__}")


def check_bool(value, name):
    """``value`` as a Python bool, rejecting anything but True, False and numpy bools."""
    if not isinstance(value, (bool, np.bool_)):
        raise ValidationError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def check_int(value, name, minimum=None, maximum=None):
    """``value`` as a Python int, rejecting bools, floats and values outside [minimum, maximum]."""
    bounds = [f">= {minimum}"] if minimum is not None else []
    bounds += [f"<= {maximum}"] if maximum is not None else []
    rule = f"{name} must be an integer" + (" " + " and ".join(bounds) if bounds else "")
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValidationError(f"{rule}; got {value!r}")
    if (minimum is not None and value < minimum) or (maximum is not None and value > maximum):
        raise ValidationError(f"{rule}; got {value!r}")
    return int(value)


def _interval(low, high, low_open, high_open):
    """'> 0', '>= 1', '< 1' or 'in [0, 1)' for the messages."""
    if high is None and low is not None:
        return f"{'>' if low_open else '>='} {low:g}"
    if low is None and high is not None:
        return f"{'<' if high_open else '<='} {high:g}"
    if low is None:
        return ""
    return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


def check_real(value, name, low=None, high=None, low_open=False, high_open=False, what="a finite number"):
    """``value`` as a finite float in the interval given (open or closed ends).

    Bools, strings, arrays and non-finite numbers are rejected (``gamma=False`` is an error,
    not 0). ``what`` names the kind of number in the message ("a probability").
    """
    ok = not isinstance(value, bool) and isinstance(value, numbers.Real)
    v = float(value) if ok else np.nan
    ok = ok and bool(np.isfinite(v))
    if ok and low is not None:
        ok = v > low if low_open else v >= low
    if ok and high is not None:
        ok = v < high if high_open else v <= high
    if not ok:
        raise ValidationError(f"{name} must be {' '.join(filter(None, (what, _interval(low, high, low_open, high_open))))}; got {value!r}")
    return v


def check_beta(beta):
    """The Boltzmann inverse temperature: a finite number > 0 (one rule everywhere)."""
    return check_real(beta, "beta", low=0.0, low_open=True)


def check_probability(value, name):
    """A probability in [0, 1]."""
    return check_real(value, name, 0.0, 1.0, what="a probability")


def check_tol(value, name="tol"):
    """A stopping tolerance: a finite number >= 0."""
    return check_real(value, name, low=0.0)


def check_real_dtype(raw):
    """Raise TypeError for complex, string and non-numeric object arrays (numpy would cast or warn)."""
    if raw.dtype.kind in "cSUV":
        raise TypeError(f"got an array of dtype {raw.dtype}")
    if raw.dtype.kind == "O":
        bad = next((v for v in raw.flat if not isinstance(v, numbers.Real)), None)
        if bad is not None:
            raise TypeError(f"got an object array holding {type(bad).__name__} {bad!r}")


def check_array(value, name, ndim=None, dtype=np.float64):
    """``value`` as a finite numeric array (float64 by default) of the given ndim.

    The message names the first non-finite entry and its index.
    """
    try:
        raw = np.asarray(value)
        check_real_dtype(raw)
        arr = np.asarray(raw, dtype=dtype)
    except (TypeError, ValueError, OverflowError) as exc:
        raise ValidationError(f"{name} must be a real numeric array: {exc}") from None
    if ndim is not None and arr.ndim != ndim:
        raise ValidationError(f"{name} must be a {ndim}-d array; got shape {arr.shape}")
    if arr.dtype.kind == "f" and not np.all(np.isfinite(arr)):
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
        raise ValidationError(f"{name} must be finite; found {float(arr[bad])!r} at index {bad}")
    return arr


def check_mdp(mdp):
    """``mdp`` if it is a :class:`~factirl_opt.mdp.TabularMDP` (or a subclass), else raise.

    The class is looked up among the loaded modules, not imported: this module is a leaf that
    the model module imports (no import cycle), and no model can exist before its module loads.
    """
    models = sys.modules.get(__name__.rpartition(".")[0] + ".mdp")
    if models is None or not isinstance(mdp, models.TabularMDP):
        raise ValidationError(f"mdp must be a TabularMDP; got {type(mdp).__name__}")
    return mdp


def check_rewards(mdp, rewards, name="rewards"):
    """Return rewards as float64 (n, S, A) and whether a single (S, A) reward was given."""
    R = check_array(rewards, name)
    S, A = mdp.n_states, mdp.n_actions
    single = R.ndim == 2
    if single:
        R = R[None]
    if R.ndim != 3 or R.shape[1:] != (S, A):
        raise ValidationError(f"{name} must have shape (S, A) = ({S}, {A}) or (n, {S}, {A}); got {np.shape(rewards)}")
    if R.size and np.max(np.abs(R)) > REWARD_LIMIT * (1.0 - mdp.gamma):
        raise ValidationError(
            f"{name} reach {np.max(np.abs(R)):.3g}: values beyond {REWARD_LIMIT:.0e} * (1 - gamma) overflow the "
            "Bellman equation in float64; rescale the rewards"
        )
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


def check_statistics(mdp, mu_hat, pi_hat, n=None, atol=1e-6):
    """Empirical statistics as float64 mu (n, S) and pi (n, S, A).

    ``mu_hat`` rows must be distributions; ``pi_hat`` rows of visited states (``mu_hat > 0``)
    must sum to 1 (within ``atol``).
    """
    S, A = mdp.n_states, mdp.n_actions
    mu = check_array(mu_hat, "mu_hat")
    pi = check_array(pi_hat, "pi_hat")
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
    if np.any(mu < 0) or np.any(pi < 0):
        raise ValidationError("mu_hat and pi_hat must be nonnegative")
    mu_sums = mu.sum(axis=1)
    if np.any(np.abs(mu_sums - 1.0) > atol):
        i = int(np.argmax(np.abs(mu_sums - 1.0)))
        raise ValidationError(f"each row of mu_hat must sum to 1; task {i} sums to {mu_sums[i]!r}")
    pi_err = np.where(mu > 0, np.abs(pi.sum(axis=2) - 1.0), 0.0)
    if np.any(pi_err > atol):
        i, s = np.unravel_index(np.argmax(pi_err), pi_err.shape)
        raise ValidationError(
            f"pi_hat(.|s) must sum to 1 in every visited state; task {i}, state {s} sums to {float(pi[i, s].sum())!r}"
        )
    return mu, pi


def check_features(features, n_params, n_states=None, name="features", min_columns=1):
    """Reward features as float64 (S*A, p); state features (S, p) are repeated over actions.

    Parameters
    ----------
    features : array_like, shape (S*A, p) or (S, p)
    n_params : int
        ``S * A``.
    n_states : int, optional
        ``S``: when given, (S, p) state features are accepted and broadcast over the actions
        (row ``s * A + a`` of the result is row ``s`` of the input).
    min_columns : int
        Smallest accepted p.
    """
    F = check_array(features, name, ndim=2)
    given = F.shape
    if n_states is not None and F.shape[0] == n_states and n_states != n_params:
        F = np.repeat(F, n_params // n_states, axis=0)
    if F.shape[0] != n_params or F.shape[1] < min_columns:
        rows = f"S*A = {n_params}" + (f" or S = {n_states}" if n_states is not None else "")
        raise ValidationError(f"{name} must have shape ({rows}, p) with p >= {min_columns}; got {given}")
    return F


def check_stochastic_policy(mdp, policy, n):
    """Stochastic policies as float64 (n, S, A): finite, nonnegative, each pi(.|s) summing to 1."""
    pi = check_array(policy, "policy")
    if pi.ndim == 2:
        pi = pi[None]
    S, A = mdp.n_states, mdp.n_actions
    if pi.shape != (n, S, A):
        raise ValidationError(f"a stochastic policy must have shape ({n}, {S}, {A}); got {np.shape(policy)}")
    if not np.all(np.isfinite(pi)) or np.any(pi < 0) or np.any(np.abs(pi.sum(axis=2) - 1.0) > 1e-9):
        raise ValidationError("a stochastic policy must be finite, nonnegative, and each pi(.|s) must sum to 1")
    return pi
