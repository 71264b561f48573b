"""Boundary checks shared by the whole library (internal; the one home of every validator).

Every public function and estimator validates its arguments with these helpers, so a bad value
gets the same rule and the same message wherever it enters. All raise
:class:`~factirl_opt.exceptions.ValidationError` naming the argument and the bad value.
"""

from __future__ import annotations

import numbers
import sys
import typing

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .exceptions import ValidationError

if typing.TYPE_CHECKING:
    from .mdp.tabular import TabularMDP

#: What ``rng=`` accepts everywhere: a Generator, a seed, a SeedSequence or None (see :func:`as_rng`).
RNGLike = np.random.Generator | int | np.random.SeedSequence | None

#: largest ``|R| / (1 - gamma)`` accepted: values (and their differences) stay finite in float64
REWARD_LIMIT = 1e300

__all__ = [
    "RNGLike",
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
    "check_start",
]


def as_rng(rng: RNGLike) -> np.random.Generator:
    """A ``numpy.random.Generator`` from a Generator, a seed, a SeedSequence or None."""
    if isinstance(rng, np.random.Generator):
        return rng
    if rng is None or isinstance(rng, (numbers.Integral, np.random.SeedSequence)) and not isinstance(rng, bool):
        if isinstance(rng, numbers.Integral) and rng < 0:
            raise ValidationError(f"rng seed must be >= 0; got {rng!r}")
        return np.random.default_rng(rng)
    raise ValidationError(f"rng must be a numpy Generator, a SeedSequence, an int seed or None; got {type(rng).__name__}")


def check_bool(value: object, name: str) -> bool:
    """``value`` as a Python bool, rejecting anything but True, False and numpy bools.

    Raises
    ------
    ValidationError
        Naming ``name`` and the value given.
    """
    if not isinstance(value, (bool, np.bool_)):
        raise ValidationError(f"{name} must be True or False; got {value!r}")
    return bool(value)


def check_int(value: object, name: str, minimum: int | None = None, maximum: int | None = None) -> int:
    """``value`` as a Python int, rejecting bools, floats and values outside [minimum, maximum].

    Raises
    ------
    ValidationError
        Naming ``name``, the rule (e.g. "an integer >= 1") and the value given.
    """
    bounds = [f">= {minimum}"] if minimum is not None else []
    bounds += [f"<= {maximum}"] if maximum is not None else []
    rule = f"{name} must be an integer" + (" " + " and ".join(bounds) if bounds else "")
    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise ValidationError(f"{rule}; got {value!r}")
    number = int(value)
    if (minimum is not None and number < minimum) or (maximum is not None and number > maximum):
        raise ValidationError(f"{rule}; got {value!r}")
    return number


def _interval(low, high, low_open, high_open):
    """'> 0', '>= 1', '< 1' or 'in [0, 1)' for the messages."""
    if high is None and low is not None:
        return f"{'>' if low_open else '>='} {low:g}"
    if low is None and high is not None:
        return f"{'<' if high_open else '<='} {high:g}"
    if low is None:
        return ""
    return f"in {'(' if low_open else '['}{low:g}, {high:g}{')' if high_open else ']'}"


def check_real(value: object, name: str, low: float | None = None, high: float | None = None, low_open: bool = False,
               high_open: bool = False, what: str = "a finite number") -> float:
    """``value`` as a finite float in the interval given (open or closed ends).

    Bools, strings, arrays and non-finite numbers are rejected (``gamma=False`` is an error,
    not 0). ``what`` names the kind of number in the message ("a probability").

    Raises
    ------
    ValidationError
        Naming ``name``, the interval and the value given.
    """
    ok = not isinstance(value, bool) and isinstance(value, numbers.Real)
    v = float(value) if ok else np.nan  # type: ignore[arg-type]  # a numbers.Real
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


def check_probability(value: object, name: str) -> float:
    """A probability in [0, 1], as a float (:func:`check_real` with ``low=0``, ``high=1``)."""
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
    """``mdp`` if it is a :class:`~factirl_opt.mdp.tabular.TabularMDP` (or a subclass), else raise.

    The class is looked up among the loaded modules, not imported: this module is a leaf that
    the model module imports (no import cycle), and no model can exist before its module loads.
    """
    models = sys.modules.get(__name__.rpartition(".")[0] + ".mdp")
    if models is None or not isinstance(mdp, models.TabularMDP):
        raise ValidationError(f"mdp must be a TabularMDP; got {type(mdp).__name__}")
    return mdp


def check_rewards(mdp: TabularMDP, rewards: ArrayLike, name: str = "rewards") -> tuple[NDArray[np.float64], bool]:
    """Rewards as float64 (n, S, A), and whether one task's reward was given.

    The one home of the reward layouts: every public function that takes rewards validates
    them here, so each accepts the same four layouts.

    ======================  ==============================  =============================
    shape of ``rewards``    meaning                         ``R[i, s, a]``
    ======================  ==============================  =============================
    (n, S, A)               n state-action rewards          ``rewards[i, s, a]``
    (S, A)                  one state-action reward         ``rewards[s, a]``, n = 1
    (n, S), not (S, A)      n state rewards                 ``rewards[i, s]``
    (S,)                    one state reward                ``rewards[s]``, n = 1
    ======================  ==============================  =============================

    State rewards are broadcast over the actions (``R(s, a) = r(s)``, docs/maths.md §1),
    as :func:`~factirl_opt.datasets.objectworld.multitask_rewards` returns them. A 2-d array is read
    as (S, A) whenever its shape is (S, A): when ``A == S``, an (S, S) array is one
    state-action reward, never S state rewards; pass n == S state rewards over S actions as
    (n, S, A) (e.g. ``state_action_rewards(r, A)``). A 2-d array of another shape whose last
    axis has length S is read as (n, S).

    Returns
    -------
    R : ndarray of float64, shape (n, S, A)
        A new array when state rewards were given.
    single : bool
        True for the (S, A) and (S,) layouts (callers then drop the task axis of results).

    Raises
    ------
    ValidationError
        Naming ``name``, the shape given and the accepted shapes; or the largest reward when
        ``|R| / (1 - gamma)`` would overflow float64.
    """
    R = check_array(rewards, name)
    S, A = mdp.n_states, mdp.n_actions
    single = R.ndim == 1 or (R.ndim == 2 and R.shape == (S, A))
    if R.ndim in (1, 2) and R.shape[-1] == S and R.shape != (S, A):
        R = np.repeat(R.reshape(-1, S)[:, :, None], A, axis=2)  # state rewards over the actions
    elif single:
        R = R[None]
    if R.ndim != 3 or R.shape[1:] != (S, A):
        raise ValidationError(
            f"{name} must have shape (S, A) = ({S}, {A}) or (n, {S}, {A}); got {np.shape(rewards)} (state rewards of "
            f"shape (S,) = ({S},) or (n, S) = (n, {S}) are accepted too, repeated over the actions)"
        )
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
    if not np.issubdtype(pol.dtype, np.integer):
        raise ValidationError(f"{name} must hold integer actions in [0, {A}); got an array of dtype {pol.dtype}")
    bad = (pol < 0) | (pol >= A)
    if np.any(bad):
        i, s = (int(v) for v in np.argwhere(bad)[0])
        raise ValidationError(f"{name} must hold integer actions in [0, {A}); got {int(pol[i, s])} for task {i}, state {s}")
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
    for label, arr in (("mu_hat", mu), ("pi_hat", pi)):
        if np.any(arr < 0):
            index = tuple(int(v) for v in np.argwhere(arr < 0)[0])
            raise ValidationError(f"{label} must be nonnegative; found {float(arr[index])!r} at index {index} (task {index[0]})")
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
    if np.any(pi < 0):
        i, s, a = (int(v) for v in np.argwhere(pi < 0)[0])
        raise ValidationError(f"a stochastic policy must be nonnegative; pi(a={a}|s={s}) of task {i} is {float(pi[i, s, a])!r}")
    err = np.abs(pi.sum(axis=2) - 1.0)
    if np.any(err > 1e-9):
        i, s = (int(v) for v in np.unravel_index(np.argmax(err), err.shape))
        raise ValidationError(f"each pi(.|s) of a stochastic policy must sum to 1; task {i}, state {s} sums to {float(pi[i, s].sum())!r}")
    return pi


#: tolerance on the sum of a start-state distribution
START_SUM_TOL = 1e-9


def check_start(start: int | ArrayLike | None, n: int, n_states: int) -> int | NDArray[np.float64] | None:
    """A start-state specification: None, a state index, or (n, S) start-state distributions.

    Parameters
    ----------
    start : None, int, or array_like of shape (S,) or (n, S)
        None (uniform), one state for every episode, one distribution for every task, or one
        distribution per task. Distributions must be finite, nonnegative and sum to 1 (within
        :data:`START_SUM_TOL`).
    n : int
        Number of tasks.
    n_states : int
        ``S``.

    Returns
    -------
    None, int, or ndarray of float64, shape (n, S)
        Distributions are returned one row per task (an (S,) vector repeated n times).
    """
    if start is None:
        return None
    if isinstance(start, (numbers.Integral, np.bool_)):
        return check_int(start, "start", minimum=0, maximum=n_states - 1)
    p = check_array(start, "start")
    if p.shape not in ((n_states,), (n, n_states)):
        raise ValidationError(
            f"start must be None, a state index in [0, {n_states}), a distribution over the states of shape "
            f"(S,) = ({n_states},) or one per task of shape (n, S) = ({n}, {n_states}); got "
            f"{type(start).__name__} of shape {p.shape}"
        )
    rows = p.reshape(-1, n_states)
    label = (lambda i: "start") if p.ndim == 1 else (lambda i: f"start[{i}]")
    if np.any(rows < 0):
        i, s = (int(v) for v in np.argwhere(rows < 0)[0])
        raise ValidationError(f"start must hold nonnegative probabilities; {label(i)} has {float(rows[i, s])!r} at state {s}")
    sums = rows.sum(axis=1)
    err = np.abs(sums - 1.0)
    if np.any(err > START_SUM_TOL):
        i = int(np.argmax(err))
        raise ValidationError(f"start probabilities must sum to 1 (within {START_SUM_TOL:g}); {label(i)} sums to {float(sums[i])!r}")
    return np.array(np.broadcast_to(rows, (n, n_states)), dtype=np.float64)


#: the estimators' iteration budgets (an integer >= 0) and inner steps (>= 1), checked by
#: :func:`check_fit_parameters`; ``start__flat_max_iter`` is the field of the start group
_BUDGET_PARAMETERS = {"max_iter": 0, "start__flat_max_iter": 0, "transfer_max_iter": 0, "inner_steps": 1}


def check_fit_parameters(estimator: typing.Any) -> None:
    """Check, when ``fit`` starts, the parameters of ``estimator`` that only some paths of the fit read.

    Every iteration budget (``max_iter``, ``start__flat_max_iter``, ``transfer_max_iter``:
    integers >= 0; ``inner_steps`` >= 1) the estimator has, whether or not this fit's path reads
    it: a bad ``transfer_max_iter`` is refused by ``fit``, not by a later ``transfer``; a bad flat
    budget by a fit with ``init="random"``. The step solvers need no check here: every fit reads
    ``solver``, and a ``SolverSettings`` checks its fields when it is made.

    Raises
    ------
    ValidationError
        Naming the parameter and the value.
    """
    params = dict(vars(estimator))  # the stored parameters (a subclass may take **kwargs: no signature read)
    for group in getattr(type(estimator), "param_groups", {}):
        params.update({f"{group}__{k}": v for k, v in estimator._group(group).get_params().items()})
    for name, minimum in _BUDGET_PARAMETERS.items():
        if name in params:
            check_int(params[name], name, minimum=minimum)
