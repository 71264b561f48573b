"""Bring your own MDP from Gymnasium: toy-text environments as :class:`TabularMDP`.

Gymnasium's toy-text environments (FrozenLake, CliffWalking, Taxi) publish their dynamics in
``env.unwrapped.P``, a dict of dicts: ``P[s][a]`` is a list of transitions
``(probability, next_state, reward, terminated)``. :func:`from_gymnasium` turns it into a
:class:`TabularMDP`; :func:`gymnasium_rewards` gives the environment's own reward as an
(S, A) array, for use as a ground truth or for comparison with learnt rewards.

Terminal transitions. A :class:`TabularMDP` has no terminal states, so with
``terminal="absorbing"`` (the default) every state that some transition enters with
``terminated=True`` is made absorbing: all its actions loop back to it with probability 1,
and :func:`gymnasium_rewards` gives it reward 0. With these two conventions, the discounted
value of a policy in the :class:`TabularMDP` equals the expected discounted return of the
episodic environment (the episode ends on entering such a state; the environment's reward
for the terminating step is kept, as part of the expected reward of the step that enters
it). This is exact when the states entered by terminating transitions are entered only that
way, or only from each other, as in FrozenLake (holes and goal), CliffWalking (goal) and Taxi
(passenger delivered; those states are entered otherwise only by moving around among
themselves, which an episode never does). ``terminal="ignore"`` keeps the listed dynamics
as they are and drops the flag.

The reward listed in ``P`` is not part of a :class:`TabularMDP`: in inverse reinforcement
learning rewards are learnt, or given separately (e.g. from :func:`task_rewards`).

The dynamics are read into a sparse (S * A, S) CSR matrix, row ``s * A + a`` (toy-text
environments list a few outcomes per state and action), before they become a
:class:`TabularMDP`.

Gymnasium is an optional dependency: ``pip install "gymnasium>=0.29"``, or from a clone of
factirl-opt ``pip install -e ".[gymnasium]"``. It is only imported to create an environment
from its id; an environment object is read by duck typing (anything whose ``unwrapped`` has
such a ``P``).
"""

from __future__ import annotations

import importlib
import typing

import numpy as np
import scipy.sparse as sp
from numpy.typing import NDArray

from .._validation import check_real
from ..exceptions import MissingDependencyError, ValidationError
from ..mdp.tabular import TabularMDP

__all__ = ["from_gymnasium", "gymnasium_rewards", "TERMINAL_MODES"]

#: How transitions flagged ``terminated`` are handled (see the module docstring).
TERMINAL_MODES = ("absorbing", "ignore")


#: The install hint of the ``gymnasium`` extra: works for any install of factirl-opt, and from a clone.
INSTALL_HINT = 'pip install "gymnasium>=0.29" (or, in a clone of factirl-opt: pip install -e ".[gymnasium]")'


def _import_gymnasium():
    try:
        return importlib.import_module("gymnasium")
    except ImportError as exc:
        raise MissingDependencyError(
            f"creating an environment from its id needs gymnasium, which is not installed: {INSTALL_HINT}"
        ) from exc


def _tabular_model(env, terminal, make_kwargs):
    """Read ``env.unwrapped.P`` into arrays.

    Returns
    -------
    P : scipy.sparse.csr_matrix, shape (S * A, S)
        Next-state probabilities, row ``s * A + a``; duplicates merged by summing.
    R : ndarray, shape (S, A)
        Expected immediate reward.
    absorbing : ndarray of bool, shape (S,)
        States made absorbing (all False with ``terminal="ignore"``).
    """
    if terminal not in TERMINAL_MODES:
        raise ValidationError(f"terminal must be one of {TERMINAL_MODES}; got {terminal!r}")
    if isinstance(env, str):
        env = _import_gymnasium().make(env, **make_kwargs)
        try:
            return _read_model(env, terminal)
        finally:
            env.close()
    if make_kwargs:
        raise ValidationError(
            f"keyword arguments {sorted(make_kwargs)} are passed to gymnasium.make and need an environment id, "
            f"not an environment object ({type(env).__name__})"
        )
    return _read_model(env, terminal)


def _space_size(space, name):
    n = getattr(space, "n", None)
    if n is None:
        return None
    start = int(getattr(space, "start", 0))
    if start != 0:
        raise ValidationError(f"the {name} space must be Discrete starting at 0; got start={start}")
    return int(n)


def _outcome(item, s, a, S):
    """One listed outcome ``(probability, next_state, reward, terminated)``, checked."""
    if not isinstance(item, (list, tuple)) or len(item) != 4:
        raise ValidationError(f"P[{s}][{a}] holds {item!r:.100}; expected (probability, next_state, reward, terminated)")
    prob, nxt, reward, done = item
    if isinstance(nxt, (bool, np.bool_)) or not isinstance(nxt, (int, np.integer)) or not 0 <= nxt < S:
        raise ValidationError(f"P[{s}][{a}] has next_state {nxt!r}; expected an integer in [0, {S})")
    prob = check_real(prob, f"the probability in P[{s}][{a}]", low=0.0)
    reward = check_real(reward, f"the reward in P[{s}][{a}]")
    return prob, int(nxt), reward, bool(done)


def _outcomes(table, S, A):
    """Every listed outcome as flat arrays: row ``s * A + a``, next state, probability, reward."""
    rows, cols, probs, rewards = [], [], [], []
    entered_terminal = np.zeros(S, dtype=bool)
    for s in range(S):
        row = table[s]
        if not isinstance(row, dict) or sorted(row) != list(range(A)):
            raise ValidationError(f"P[{s}] must have one entry per action 0..{A - 1}; got {row!r:.200}")
        for a in range(A):
            outcomes = row[a]
            if not isinstance(outcomes, (list, tuple)) or len(outcomes) == 0:
                raise ValidationError(f"P[{s}][{a}] must be a non-empty list of (probability, next_state, reward, terminated); "
                                      f"got {outcomes!r:.100}")
            for item in outcomes:
                prob, nxt, reward, done = _outcome(item, s, a, S)
                rows.append(s * A + a)
                cols.append(nxt)
                probs.append(prob)
                rewards.append(reward)
                entered_terminal[nxt] |= done
    return np.array(rows, dtype=np.int64), np.array(cols, dtype=np.int64), np.array(probs), np.array(rewards), entered_terminal


def _read_model(env, terminal):
    base = getattr(env, "unwrapped", env)
    table = getattr(base, "P", None)
    if not isinstance(table, dict) or not table:
        raise ValidationError(
            f"{type(base).__name__} has no tabular model: expected env.unwrapped.P, a dict with "
            "P[s][a] = [(probability, next_state, reward, terminated), ...] (Gymnasium toy-text)"
        )
    S = _space_size(getattr(base, "observation_space", None), "observation")
    A = _space_size(getattr(base, "action_space", None), "action")
    S = len(table) if S is None else S
    if sorted(table) != list(range(S)):
        raise ValidationError(f"P must have one entry per state 0..{S - 1}; got keys {sorted(table)[:10]}...")
    first = table[0]
    A = len(first) if A is None else A
    rows, cols, probs, rewards, entered_terminal = _outcomes(table, S, A)
    absorbing = entered_terminal if terminal == "absorbing" else np.zeros(S, dtype=bool)
    keep = ~absorbing[rows // A]  # the outcomes of absorbing states are replaced by self-loops
    R = np.bincount(rows[keep], weights=probs[keep] * rewards[keep], minlength=S * A).reshape(S, A)
    loops = np.flatnonzero(absorbing)
    loop_rows = (loops[:, None] * A + np.arange(A)).ravel()
    P = sp.csr_matrix(
        (np.concatenate([probs[keep], np.ones(loop_rows.size)]),
         (np.concatenate([rows[keep], loop_rows]), np.concatenate([cols[keep], np.repeat(loops, A)]))),
        shape=(S * A, S),
    )  # duplicates (several outcomes leading to the same state) are summed
    return P, R, absorbing


def from_gymnasium(env: typing.Any, gamma: float = 0.9, terminal: str = "absorbing", **make_kwargs: typing.Any) -> TabularMDP:
    """A :class:`TabularMDP` from a Gymnasium toy-text environment's ``env.unwrapped.P``.

    Parameters
    ----------
    env : gymnasium.Env or str
        An environment whose ``unwrapped`` has a tabular model ``P`` (FrozenLake,
        CliffWalking, Taxi, ...), or an environment id such as ``"FrozenLake-v1"``, created
        with ``gymnasium.make(env, **make_kwargs)`` (and closed after reading).
    gamma : float, default=0.9
        Discount factor of the MDP (Gymnasium environments do not define one); 0.9 is the
        paper's grid-world value.
    terminal : {"absorbing", "ignore"}, default="absorbing"
        ``"absorbing"``: every state entered by a transition flagged ``terminated`` loops
        back to itself under every action. ``"ignore"``: the listed dynamics are kept as
        they are. See the module docstring.
    **make_kwargs
        Passed to ``gymnasium.make`` when ``env`` is an id, e.g. ``map_name="8x8"``,
        ``is_slippery=True``.

    Returns
    -------
    mdp : TabularMDP
        States and actions numbered as in the environment: S = number of observations,
        A = number of actions, ``transitions[s, a, s']`` the total probability of all listed
        outcomes leading to ``s'``.

    Raises
    ------
    MissingDependencyError
        ``env`` is an id and gymnasium is not installed.
    ValidationError
        The environment has no tabular model, or it is malformed (the message names it).

    Examples
    --------
    >>> mdp = from_gymnasium("FrozenLake-v1", map_name="4x4", is_slippery=True)  # doctest: +SKIP
    >>> mdp.n_states, mdp.n_actions  # doctest: +SKIP
    (16, 4)
    """
    P, _, _ = _tabular_model(env, terminal, make_kwargs)
    return TabularMDP(P, gamma)  # kept sparse: (S * A, S) CSR, row s * A + a


def gymnasium_rewards(env: typing.Any, terminal: str = "absorbing", **make_kwargs: typing.Any) -> NDArray[np.float64]:
    """The environment's own reward as an (S, A) array of expected immediate rewards.

    ``R[s, a] = sum_k p_k r_k`` over the outcomes ``(p_k, s'_k, r_k, done_k)`` listed in
    ``P[s][a]``. With ``terminal="absorbing"`` the absorbing states get reward 0, so values
    computed on ``from_gymnasium(env, gamma, terminal="absorbing")`` are the episodic
    environment's expected discounted returns.

    Parameters
    ----------
    env : gymnasium.Env or str
    terminal : {"absorbing", "ignore"}, default="absorbing"
        Must match the one given to :func:`from_gymnasium`.
    **make_kwargs
        Passed to ``gymnasium.make`` when ``env`` is an id.

    Returns
    -------
    rewards : ndarray of float64, shape (S, A)
    """
    _, R, _ = _tabular_model(env, terminal, make_kwargs)
    return R
