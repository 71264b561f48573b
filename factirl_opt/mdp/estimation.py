"""Models estimated from logged transitions: Dirichlet posterior means, and held-out scores.

When the dynamics are not given, :func:`estimate_mdp` builds a sparse :class:`TabularMDP` from
logged transitions ``(s, a, s')``: the posterior mean of ``P(. | s, a)`` under a Dirichlet
prior, row by row (the model's layout is that of docs/maths.md §1: a (S*A, S) CSR matrix, row
``s * A + a``). :func:`transition_log_likelihood` scores held-out transitions under a model,
to compare estimates (or choose a prior) on data they were not built from. Also here:
:func:`transition_counts` (the sparse counts themselves) and :func:`sample_transitions`
(exploration data drawn from a known model, for experiments on model error).

Layouts of logged data
----------------------
Every function here reads ``data`` through :func:`as_transitions`. Accepted:

- an int array of shape (N, 3): one transition ``(s, a, s')`` per row;
- a list of episodes, or an int array of shape (m, L, 2) or (m, L, 3) (m episodes of equal
  length), each episode being

  - an (L, 3) array of transitions ``(s_t, a_t, s_{t+1})``: all L are used (L = 0 too, so
    extra transitions, e.g. ``sample_transitions(mdp, M)`` with M >= 0, can be appended to
    the list);
  - an (L, 2) array of (state, action) steps, the library's episode layout: consecutive
    steps give the L - 1 transitions ``(s_t, a_t, s_{t+1})``; the last action's outcome was
    not logged, so that action is not counted;
  - a pair ``(episode, final_state)``, a tuple or list of an (L, 2) array and an integer:
    the state reached after the last action completes the L-th transition.

  A 3-d array in the list stands for its episodes, so the library's demonstrations (one
  (m, L, 2) array per task) are accepted as they are; messages number the episodes in order
  (the m episodes of a 3-d array count as m).

Logged episodes read by :func:`~factirl_opt.adapters.read_minari` (any object with a ``transitions()``
method returning one of these layouts) are accepted as they are.

Values must be integers (floats holding whole numbers are accepted); states in [0, S) and
actions in [0, A) when ``n_states``, ``n_actions`` are known. An (N, 2) array is refused: it
holds (state, action) steps without next states or episode boundaries. Data that gives no
transition at all (e.g. only episodes of length 1 without their final state) is refused.

The prior, and (s, a) pairs never tried
----------------------------------------
With ``n(s, a, s')`` the counts, ``n(s, a)`` their row sums, ``m(s' | s, a)`` the prior mean
and ``c`` the pseudo-count (the Dirichlet concentration of each row, summed over ``s'``),

    P(s' | s, a) = (n(s, a, s') + c m(s' | s, a)) / (n(s, a) + c).

A pair never tried (``n(s, a) = 0``) gets the prior mean. With ``c = 0`` the tried rows are the
maximum-likelihood frequencies and only untried rows come from the prior. Prior means:

- ``"self-loop"`` (default): ``m = e_s``, the agent stays where it is (the pseudo-counts all
  on staying put). Rows keep the data's support plus at most the entry ``s' = s``; untried
  actions of states never left (terminal states of an episodic task) become absorbing, the
  convention of :func:`~factirl_opt.adapters.from_gymnasium`.
- ``"uniform"``: ``m = 1/S`` (a symmetric Dirichlet, ``c / S`` per next state). Every row the
  prior touches is dense: with ``c > 0`` the whole (S*A, S) matrix; with ``c = 0`` the untried
  rows only. Refused when those rows would hold more than :data:`UNIFORM_ENTRY_LIMIT` entries.
- a :class:`TabularMDP` with the same S and A: its rows are the prior means (e.g. a model of
  the intended dynamics, or one estimated from other data); its ``gamma`` is not used.
"""

from __future__ import annotations

import numbers
import os
from typing import Any, Literal

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike, NDArray

from .._validation import as_rng, check_int, check_mdp, check_real
from ..exceptions import ValidationError
from .tabular import TabularMDP

__all__ = [
    "PRIORS",
    "UNIFORM_ENTRY_LIMIT",
    "ROW_BYTES",
    "as_transitions",
    "transition_counts",
    "estimate_mdp",
    "transition_log_likelihood",
    "sample_transitions",
]

#: Bytes :func:`estimate_mdp` needs per (s, a) row whatever the data (row pointers of the counts,
#: the prior and the model, weights and row sums; 98 measured with tracemalloc at S*A = 4e6).
ROW_BYTES = 96
#: The named priors of :func:`estimate_mdp` (a :class:`TabularMDP` is accepted too).
PRIORS = ("self-loop", "uniform")
#: Most entries the dense rows of a ``"uniform"`` prior may hold (about 12 bytes each in CSR).
UNIFORM_ENTRY_LIMIT = 2**25
_COLUMNS = ("state", "action", "next state")
_INT64_LIMIT = 2**63  # states and actions must fit in int64
_LAYOUTS = (
    "an int array (N, 3) of (s, a, s') rows, or a list of episodes: (L, 3) transition arrays, (L, 2) (state, action) "
    "arrays, or (episode, final_state) pairs"
)


def _ndim(value: Any) -> int:
    """``np.ndim``, or -1 for a ragged nested sequence."""
    try:
        return int(np.ndim(value))
    except ValueError:
        return -1


def _is_final_pair(ep: object) -> bool:
    """Whether an episode entry is an ``(episode, final_state)`` pair (second item a scalar)."""
    if not isinstance(ep, (tuple, list)) or len(ep) != 2:
        return False
    final = ep[1]
    return isinstance(final, (numbers.Number, np.generic)) and _ndim(final) == 0 and _ndim(ep[0]) == 2


def _array(value: object, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):  # ragged nested lists
        raise ValidationError(f"{where} must be an array of integers; got a ragged or non-numeric {type(value).__name__}") from None
    if arr.dtype.kind not in "iuf" and not (arr.dtype.kind == "O" and arr.size == 0):
        raise ValidationError(f"{where} must hold integers; got dtype {arr.dtype}")
    return arr


def _episode_transitions(ep: object, j: int) -> np.ndarray:
    """Episode j (any accepted form) as a raw (k, 3) array of transitions, values unchecked."""
    where = f"data, episode {j}"
    if _is_final_pair(ep):
        steps, final = _array(ep[0], f"{where} (the episode of the pair)"), ep[1]  # type: ignore[index]
        if steps.shape[1:] != (2,) or len(steps) == 0:
            raise ValidationError(f"{where} is an (episode, final_state) pair whose episode must have shape (L, 2) with L >= 1; got {steps.shape}")
        nxt = np.append(steps[1:, 0], _array(final, f"{where} (final_state)"))
        return np.column_stack((steps[:, 0], steps[:, 1], nxt))
    arr = _array(ep, where)
    if arr.ndim != 2 or arr.shape[1] not in (2, 3) or (len(arr) == 0 and arr.shape[1] == 2):
        raise ValidationError(f"{where} must be an (L, 3) array of transitions, an (L, 2) array of (state, action) steps "
                              f"with L >= 1, or an (episode, final_state) pair; got shape {arr.shape}")
    if arr.shape[1] == 3:
        return arr
    return np.column_stack((arr[:-1, 0], arr[:-1, 1], arr[1:, 0]))


def _is_block(item: object) -> bool:
    """Whether a list entry is a 3-d array standing for its episodes."""
    return isinstance(item, np.ndarray) and item.ndim == 3


def _list_transitions(data: list | tuple) -> np.ndarray:
    """The raw transitions of a list of episodes (and 3-d arrays of episodes), in order."""
    parts, j = [], 0
    for item in data:
        if not _is_block(item):
            parts.append(_episode_transitions(item, j))
            j += 1
            continue
        where = f"data, episodes {j} to {j + len(item) - 1}"
        block = _array(item, where)
        if block.shape[2] not in (2, 3):
            raise ValidationError(f"{where}: a 3-d array of episodes must have shape (m, L, 2) or (m, L, 3); got {block.shape}")
        if block.shape[2] == 2:  # consecutive steps, vectorised over the m episodes
            block = np.concatenate((block[:, :-1], block[:, 1:, :1]), axis=2)
        parts.append(block.reshape(-1, 3))
        j += len(item)
    if sum(len(p) for p in parts) == 0:
        raise ValidationError(
            "data holds no transitions: an episode of (state, action) steps gives one transition per pair of "
            "consecutive steps, and these episodes all have length 1; give (episode, final_state) pairs or (L, 3) episodes"
        )
    return np.concatenate(parts)


def _raw_transitions(data: object) -> tuple[np.ndarray, str]:
    """The transitions of ``data`` as a raw (N, 3) array, and how to name a row in messages."""
    if callable(getattr(data, "transitions", None)):  # LoggedEpisodes from read_minari
        data = data.transitions()  # type: ignore[attr-defined]
    if _is_block(data):
        data = [data]
    if _is_final_pair(data):
        raise ValidationError("data is a single (episode, final_state) pair: give a list of episodes, [(episode, final_state)]")
    if isinstance(data, (list, tuple)):
        if len(data) == 0:
            raise ValidationError(f"data is empty: give {_LAYOUTS}")
        if all(_is_final_pair(ep) or _is_block(ep) or _ndim(ep) == 2 for ep in data):
            return _list_transitions(data), "transition"
        data = _array(data, "data")
        if data.ndim != 2:
            raise ValidationError(f"data must be {_LAYOUTS}; got a list that is neither")
    arr = _array(data, "data")
    if arr.ndim == 2 and arr.shape[1] == 2:
        raise ValidationError(
            f"data of shape {arr.shape} holds (state, action) steps without next states: give (N, 3) rows (s, a, s'), "
            "or a list of episodes ((L, 2) arrays give their transitions from consecutive steps)"
        )
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValidationError(f"data must be {_LAYOUTS}; got an array of shape {arr.shape}")
    if len(arr) == 0:
        raise ValidationError("data holds no transitions (shape (0, 3))")
    return arr, "row"


def as_transitions(data: ArrayLike | list, n_states: int | None = None, n_actions: int | None = None) -> NDArray[np.int64]:
    """Logged data in any accepted layout as an (N, 3) array of transitions ``(s, a, s')``.

    Parameters
    ----------
    data : ndarray (N, 3), ndarray (m, L, 2) or (m, L, 3), or list of episodes
        See "Layouts of logged data" in the module docstring.
    n_states, n_actions : int, optional
        When given, states and next states must lie in [0, n_states), actions in [0, n_actions).

    Returns
    -------
    transitions : ndarray of int64, shape (N, 3)
        Row ``k`` is ``(s, a, s')``; episodes contribute in order, each in step order.

    Raises
    ------
    ValidationError
        A layout that is none of the accepted ones (an (N, 2) array: next states missing), no
        transition at all, or a value that is not an integer or out of range (the message
        names the transition and the column).
    """
    arr, unit = _raw_transitions(data)
    if arr.dtype.kind == "f":
        bad = ~np.isfinite(arr)
        bad[~bad] = arr[~bad] != np.round(arr[~bad])
        if bad.any():
            k, col = (int(i) for i in np.argwhere(bad)[0])
            raise ValidationError(f"data, {unit} {k}: {_COLUMNS[col]} {arr[k, col].item()!r} is not an integer")
    bounds = (n_states, n_actions, n_states)
    for col, hi in enumerate(bounds):
        values = arr[:, col]
        bad = (values < 0) | (values >= (_INT64_LIMIT if hi is None else hi))
        if np.any(bad):
            k = int(np.argmax(bad))
            rule = f"out of range [0, {hi})" if hi is not None else "not a valid index (states and actions are integers in [0, 2**63))"
            raise ValidationError(f"data, {unit} {k}: {_COLUMNS[col]} {values[k].item()!r} is {rule}")
    return arr.astype(np.int64)


def _memory_bytes() -> int | None:
    """This machine's physical memory, or None where the platform does not say."""
    try:
        return int(os.sysconf("SC_PHYS_PAGES")) * int(os.sysconf("SC_PAGE_SIZE"))
    except (AttributeError, ValueError, OSError):
        return None


def check_model_size(n_states: int, n_actions: int) -> tuple[int, int]:
    """Validate S and A, and refuse a model of S*A rows that cannot fit in this machine's memory
    (:data:`ROW_BYTES` per row) before anything of that size is allocated."""
    S = check_int(n_states, "n_states", minimum=1)
    A = check_int(n_actions, "n_actions", minimum=1)
    need, have = S * A * ROW_BYTES, _memory_bytes()
    if have is not None and need > have:
        raise ValidationError(
            f"n_states x n_actions = {S} x {A} = {S * A} (s, a) rows: the model needs about {need / 2**30:.3g} GiB whatever "
            f"the data, more than this machine's {have / 2**30:.3g} GiB of memory; n_states and n_actions are the model's "
            "sizes (the largest state or action index + 1), not the data's"
        )
    return S, A


def transition_counts(data: ArrayLike | list, n_states: int, n_actions: int) -> sp.csr_matrix:
    """Counts ``n(s, a, s')`` of logged transitions, as a sparse (S*A, S) matrix.

    Parameters
    ----------
    data : ndarray (N, 3), or list of episodes
        See "Layouts of logged data" in the module docstring.
    n_states, n_actions : int
        S and A.

    Returns
    -------
    counts : scipy.sparse.csr_matrix of float64, shape (S*A, S)
        Row ``s * A + a`` (docs/maths.md §1) holds the number of times ``a`` taken in ``s``
        led to each next state; sorted indices, no explicit zeros.
    """
    S, A = check_model_size(n_states, n_actions)
    tr = as_transitions(data, S, A)
    rows = tr[:, 0] * A + tr[:, 1]
    counts = sp.coo_matrix((np.ones(len(tr)), (rows, tr[:, 2])), shape=(S * A, S)).tocsr()
    counts.sum_duplicates()
    return counts


def _prior_part(prior: str | TabularMDP, weights: np.ndarray, S: int, A: int) -> sp.csr_matrix:
    """``diag(weights) M``, the prior's pseudo-counts: row ``r`` is ``weights[r]`` times the prior mean."""
    tried = np.flatnonzero(weights)
    if isinstance(prior, TabularMDP):
        M = prior.csr()[tried]
        rows = np.repeat(tried, np.diff(M.indptr))
        return sp.csr_matrix((M.data * weights[rows], (rows, M.indices)), shape=(S * A, S))
    if prior == "self-loop":
        return sp.csr_matrix((weights[tried], (tried, tried // A)), shape=(S * A, S))
    n_entries = len(tried) * S
    if n_entries > UNIFORM_ENTRY_LIMIT:
        raise ValidationError(
            f"prior='uniform' makes every row it touches dense: here {len(tried)} rows x {S} states = {n_entries} entries, "
            f"over the limit of {UNIFORM_ENTRY_LIMIT}; use prior='self-loop', pseudo_count=0 (the prior on untried rows only), "
            "or a sparse prior TabularMDP"
        )
    indptr = np.zeros(S * A + 1, dtype=np.int64)
    indptr[tried + 1] = S
    np.cumsum(indptr, out=indptr)
    indices = np.tile(np.arange(S, dtype=np.int32), len(tried))
    return sp.csr_matrix((np.repeat(weights[tried] / S, S), indices, indptr), shape=(S * A, S))


def _check_prior(prior: object, S: int, A: int) -> str | TabularMDP:
    if isinstance(prior, TabularMDP):
        if (prior.n_states, prior.n_actions) != (S, A):
            raise ValidationError(
                f"the prior model has {prior.n_states} states and {prior.n_actions} actions; the data's model has {S} and {A}"
            )
        return prior
    if isinstance(prior, str) and prior in PRIORS:
        return prior
    raise ValidationError(f"prior must be one of {PRIORS} or a TabularMDP with the same states and actions; got {prior!r}")


def estimate_mdp(
    data: ArrayLike | list,
    n_states: int,
    n_actions: int,
    gamma: float,
    prior: Literal["self-loop", "uniform"] | TabularMDP = "self-loop",
    pseudo_count: float = 1.0,
) -> TabularMDP:
    """A sparse :class:`TabularMDP` estimated from logged transitions (Dirichlet posterior mean).

    ``P(s' | s, a) = (n(s, a, s') + c m(s' | s, a)) / (n(s, a) + c)``, with ``n`` the counts of
    the logged transitions, ``m`` the prior mean and ``c = pseudo_count``; pairs ``(s, a)``
    never tried get ``m(. | s, a)``. Built from sparse counts in time linear in the number of
    transitions (plus the prior's entries); see the module docstring for the priors' sparsity.

    Parameters
    ----------
    data : ndarray (N, 3), or list of episodes
        Logged transitions; see "Layouts of logged data" in the module docstring.
    n_states, n_actions : int
        S and A of the model; every state, next state and action of ``data`` must lie in range.
    gamma : float
        Discount factor of the model, ``0 <= gamma < 1``.
    prior : {"self-loop", "uniform"} or TabularMDP, default="self-loop"
        The Dirichlet prior's mean ``m`` (module docstring): stay in place, uniform over the
        S states, or the rows of a given model with the same S and A.
    pseudo_count : float, default=1.0
        ``c >= 0``, the prior's weight in observations per (s, a) row. ``0`` gives the
        maximum-likelihood frequencies on tried rows and the prior mean on untried ones.

    Returns
    -------
    mdp : TabularMDP
        Sparse: ``mdp.transition_matrix`` is a CSR (S*A, S) matrix, row ``s * A + a``, each row
        summing to 1.

    Raises
    ------
    ValidationError
        Bad data (see :func:`as_transitions`), sizes, gamma, prior or pseudo-count, a
        ``"uniform"`` prior whose dense rows would exceed :data:`UNIFORM_ENTRY_LIMIT` entries, or
        sizes whose S*A rows (:data:`ROW_BYTES` each) exceed this machine's memory.

    Examples
    --------
    >>> import numpy as np, factirl_opt as fo
    >>> mdp = fo.estimate_mdp(np.array([[0, 1, 1], [0, 1, 1], [0, 1, 0]]), 2, 2, gamma=0.9)
    >>> mdp.transitions[0, 1]  # counts (1, 2), plus one pseudo-count on staying in state 0
    array([0.5, 0.5])
    """
    S, A = check_model_size(n_states, n_actions)
    check_real(gamma, "gamma", 0.0, 1.0, high_open=True)
    prior_mean = _check_prior(prior, S, A)
    c = check_real(pseudo_count, "pseudo_count", low=0.0)
    counts = transition_counts(data, S, A)
    untried = np.diff(counts.indptr) == 0
    weights = np.full(S * A, c) if c > 0 else untried.astype(np.float64)
    P = (counts + _prior_part(prior_mean, weights, S, A)).tocsr()
    sums = np.asarray(P.sum(axis=1)).ravel()  # n(s, a) + c (> 0 on every row), up to round-off
    P.data /= np.repeat(sums, np.diff(P.indptr))
    return TabularMDP(P, gamma)


def transition_log_likelihood(
    mdp: TabularMDP, transitions: ArrayLike | list, reduction: Literal["sum", "mean", "none"] = "sum"
) -> float | NDArray[np.float64]:
    """Log-likelihood of logged transitions under a model: ``sum_k log P(s'_k | s_k, a_k)``.

    Parameters
    ----------
    mdp : TabularMDP
        The model scored (dense or sparse).
    transitions : ndarray (N, 3), or list of episodes
        Held-out data, in any layout of the module docstring.
    reduction : {"sum", "mean", "none"}, default="sum"
        The total log-likelihood (natural log), its mean per transition (comparable across
        data sets of different sizes), or the (N,) array of each transition's log-probability.

    Returns
    -------
    log_likelihood : float, or ndarray of float64 of shape (N,) with ``reduction="none"``
        A transition the model gives probability 0 contributes ``-inf`` (so the total is
        ``-inf``): the model rules out what was observed. ``reduction="none"`` shows which
        transitions they are; a prior with a pseudo-count > 0 avoids them in estimates.

    Raises
    ------
    ValidationError
        A bad ``mdp``, ``reduction``, or data (see :func:`as_transitions`).
    """
    check_mdp(mdp)
    if reduction not in ("sum", "mean", "none"):
        raise ValidationError(f"reduction must be 'sum', 'mean' or 'none'; got {reduction!r}")
    S, A = mdp.n_states, mdp.n_actions
    tr = as_transitions(transitions, S, A)
    rows = tr[:, 0] * A + tr[:, 1]
    if mdp.is_sparse:
        P = mdp.csr()  # canonical: sorted indices, no duplicates, so keys are increasing
        keys = np.repeat(np.arange(S * A, dtype=np.int64), np.diff(P.indptr)) * S + P.indices
        query = rows * S + tr[:, 2]
        pos = np.minimum(np.searchsorted(keys, query), len(keys) - 1)
        probs = np.where(keys[pos] == query, P.data[pos], 0.0) if len(keys) else np.zeros(len(tr))
    else:
        probs = mdp.transition_matrix[rows, tr[:, 2]]
    with np.errstate(divide="ignore"):
        logp = np.log(probs)
    if reduction == "none":
        return logp
    return float(logp.sum() if reduction == "sum" else logp.mean())


def sample_transitions(
    mdp: TabularMDP, n_transitions: int, rng: np.random.Generator | np.random.SeedSequence | int | None = None
) -> NDArray[np.int64]:
    """Exploration data: ``n_transitions`` transitions with ``(s, a)`` uniform and ``s' ~ P(.|s, a)``.

    Parameters
    ----------
    mdp : TabularMDP
        The true model (dense or sparse).
    n_transitions : int
        N >= 0.
    rng : numpy Generator, int seed, SeedSequence or None

    Returns
    -------
    transitions : ndarray of int64, shape (N, 3)
        Rows ``(s, a, s')``, independent draws; the (N, 3) layout of :func:`estimate_mdp`.
    """
    check_mdp(mdp)
    n = check_int(n_transitions, "n_transitions", minimum=0)
    gen: np.random.Generator = as_rng(rng)
    S, A = mdp.n_states, mdp.n_actions
    P = mdp.csr()
    rows = gen.integers(S * A, size=n)
    u = gen.random(n)
    # cumulative probabilities within each row, offset by the row index: increasing overall
    nnz = np.diff(P.indptr)
    within = np.cumsum(P.data) - np.repeat(np.concatenate(([0.0], np.cumsum(P.data)[P.indptr[1:-1] - 1])), nnz)
    keys = np.repeat(np.arange(S * A, dtype=np.float64), nnz) + within
    pos = np.searchsorted(keys, rows + u, side="right")
    pos = np.clip(pos, P.indptr[rows], P.indptr[rows + 1] - 1)  # round-off at a row's end
    out = np.empty((n, 3), dtype=np.int64)
    np.divmod(rows, A, out=(out[:, 0], out[:, 1]))
    out[:, 2] = P.indices[pos]
    return out
