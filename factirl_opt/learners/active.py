"""Active demonstration requests: which start state to ask a demonstration from (docs/maths.md §10).

For a new task with Laplace posterior ``N(x_m, Lambda^-1)`` (:mod:`.posterior`), a demonstration
of ``L`` steps from start ``s`` adds, in expectation under the model's own policy at ``x_m``,
the curvature

    H_s = sum_y occ_s(y) I(y),   occ_s(y) = sum_{t < L} P(s_t = y | s_0 = s),

with ``I(y)`` the likelihood's information of one demonstrated pair in state ``y`` (on the
posterior's scale ``s / N``): ``beta^2 sum_a pi(a|y)^2 E(y, a) E(y, a)^T / sigma^2`` for policy
matching (its Gauss-Newton matrix), ``beta^2 sum_a pi(a|y) E(y, a) E(y, a)^T`` for MCE (its
Fisher information), where ``E = dQ/dx - sum_a pi dQ/dx`` are the centred tangents of the
action values along the posterior's reward basis. The candidates are ranked by the expected
information gain about the coefficients, the D-optimal criterion

    gain(s) = log det(Lambda + H_s) - log det(Lambda),

the entropy reduction of the Gaussian posterior. It needs one plan, ``d`` right-hand sides and
``L`` propagations of the candidates' state distributions per task: no sampling, no MCMC.
``criterion="value"`` ranks by the expected reduction of the values' posterior variance and
``criterion="regret"`` by that of the linearised expected regret (:func:`linearised_regret`);
``demonstrated="skip"`` drops the information of the states already demonstrated.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.linalg.lapack import dpotrf
from scipy.special import ndtr

from .._validation import check_bool, check_int
from ..exceptions import ValidationError
from ..objectives.mce import soft_values
from ..planning import boltzmann_policy, get_planner, plan, tangent
from .fitting import learner_entry
from .posterior import LaplacePosterior, has_prior, model_posteriors, transfer_inputs
from .transfer_likelihood import tasks_problem
from .transfer import transfer_tasks

__all__ = ["request_starts", "information_gains", "information_rows", "value_variance_reductions", "state_information", "start_occupancy",
           "policy_entropy_starts", "model_policy", "CRITERIA", "POLICIES", "demonstrator_policy", "DEMONSTRATED",
           "demonstrated_states", "regret_terms", "linearised_regret", "regret_reductions"]


def model_policy(post: LaplacePosterior, objective: str, beta: float) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
    """The planner, the model's stochastic policy pi (S, A) and the tangents dQ/dx (S, A, d) at the posterior mean.

    Policy matching: the Boltzmann policy of ``Q*`` and ``dQ*/dx`` (greedy policy held fixed);
    MCE: the soft-optimal policy and the soft values' tangents.
    """
    mdp = post.mdp
    S, A = mdp.n_states, mdp.n_actions
    pl = get_planner(mdp)
    R = post.mean_rewards()[None]
    B = post.basis().reshape(1, S, A, -1)
    if objective == "mce":
        _, _, log_pi = soft_values(pl, R, beta)
        pi = np.exp(log_pi)
        system = pl.system(pi)
        dQ = tangent(pl, system, pi, B)
    else:
        res = plan(pl, R)
        pi = boltzmann_policy(res.Q, beta)
        dQ = tangent(pl, res.system, res.policy, B)
    return pl, pi[0], dQ[0]


def state_information(post: LaplacePosterior, objective: str, beta: float) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
    """Per-state information ``I(y)`` (S, d, d) of one demonstrated pair, the planner and the model's policy (S, A)."""
    pl, pi, dQ = model_policy(post, objective, beta)
    E = dQ - np.einsum("sa,sad->sd", pi, dQ)[:, None, :]
    weight = pi if objective == "mce" else pi * pi
    info = beta * beta * np.einsum("sa,sad,sae->sde", weight, E, E)
    per_pair = post.scaling / post.n_pairs
    if objective != "mce":
        per_pair *= 2.0  # s G = (N / (2 sigma^2)) 2 J_r^T J_r: 1 / sigma^2 per pair
    return pl, per_pair * info, pi


def start_occupancy(planner: Any, pi: NDArray[np.float64], starts: NDArray[np.intp], length: int) -> NDArray[np.float64]:
    """Expected visits ``occ[c, y]`` (c, S) of an ``length``-step episode from each start under policy pi (S, A).

    Each step propagates the candidates' state distributions ``X`` (c, S) by ``P_pi``: by the
    planner's pullback of ``pi X`` (c, S*A rows), or, when the candidates' steps outweigh it
    (``c (length - 1) (A - 1) > S A``) and ``P_pi`` is no larger than those rows, as ``X P_pi`` with
    ``P_pi`` (S, S) the pullback of ``S`` rows once: the same visits to round-off.
    """
    S, A = pi.shape
    c = len(starts)
    X = np.zeros((c, S))
    X[np.arange(c), starts] = 1.0
    occ = np.zeros_like(X)
    if c * (length - 1) * (A - 1) > S * A and S <= c * A:
        E = np.zeros((S, S, A))
        E[np.arange(S), np.arange(S)] = pi
        P_pi = planner.pullback(E)
        for t in range(length):
            occ += X
            if t + 1 < length:
                X = X @ P_pi
        return occ
    P = np.broadcast_to(pi, (c, *pi.shape))
    for t in range(length):
        occ += X
        if t + 1 < length:
            X = planner.pullback(P * X[:, :, None])
    return occ


#: Policies the demonstrator is assumed to follow from a requested start (``request_starts(policy=...)``).
POLICIES = ("boltzmann", "greedy")


def demonstrator_policy(pi: NDArray[np.float64], policy: str = "boltzmann") -> NDArray[np.float64]:
    """The policy (S, A) whose episodes weight the starts: the model's policy ``pi`` (``"boltzmann"``) or
    its greedy policy, one-hot on ``argmax_a pi[s, a]`` (``"greedy"``, the path a greedy expert takes)."""
    if policy not in POLICIES:
        raise ValidationError(f"policy must be one of {', '.join(POLICIES)}; got {policy!r}")
    if policy == "boltzmann":
        return pi
    greedy = np.zeros_like(pi)
    greedy[np.arange(pi.shape[0]), pi.argmax(axis=1)] = 1.0
    return greedy


def _demonstration_curvature(post: LaplacePosterior, objective: str, beta: float, candidates: NDArray[np.intp],
                             length: int, policy: str, known: NDArray[np.bool_] | None
                             ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(Lambda, H)``: the posterior precision (d, d), symmetrised, and the expected curvature
    (c, d, d) a ``length``-step demonstration from each candidate start adds (the episode's expected
    visits under :func:`demonstrator_policy` times each state's information; none where ``known``)."""
    pl, info, pi = state_information(post, objective, beta)
    if known is not None:
        info = np.where(known[:, None, None], 0.0, info)
    occ = start_occupancy(pl, demonstrator_policy(pi, policy), candidates, length)
    Lam = np.linalg.inv(post.covariance)
    return 0.5 * (Lam + Lam.T), np.einsum("cy,yde->cde", occ, info)


def information_rows(post: LaplacePosterior, objective: str, beta: float) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
    """The planner, rows ``V`` (S, A, d) with ``I(y) = sum_a V[y, a] V[y, a]^T`` (:func:`state_information`'s
    per-state information as a sum of outer products) and the model's policy (S, A)."""
    pl, pi, dQ = model_policy(post, objective, beta)
    E = dQ - np.einsum("sa,sad->sd", pi, dQ)[:, None, :]
    weight = pi if objective == "mce" else pi * pi
    per_pair = post.scaling / post.n_pairs * (1.0 if objective == "mce" else 2.0)
    return pl, np.sqrt(per_pair * beta * beta * weight)[:, :, None] * E, pi


def _row_space(post: LaplacePosterior) -> bool:
    """Whether the gains are cheaper over the demonstrated rows (S*A) than over the parameters (d):
    a residual model's posterior, d = k + p."""
    S, A = post.mdp.n_states, post.mdp.n_actions
    return 2 * post.mean.shape[0] > S * A


def information_gains(post: LaplacePosterior, objective: str, beta: float, candidates: NDArray[np.intp],
                      length: int, policy: str = "boltzmann", known: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """``log det(Lambda + H_s) - log det(Lambda)`` (c,) of a ``length``-step demonstration from each candidate start,
    the episode's expected visits under :func:`demonstrator_policy` (``policy``); states where ``known`` (S,) is
    true add no information (:func:`demonstrated_states`).

    With ``H_s = V^T O_s V`` (:func:`information_rows`, ``O_s`` the expected visits on each
    state's A rows) the gain is also ``log det(I + O_s^1/2 V Sigma V^T O_s^1/2)`` over the rows
    of the states the episode can visit (Sylvester's identity): for a residual model's posterior
    (d = k + p parameters, more than half the S*A rows) the gains are computed so, from one
    (S*A, S*A) product ``V Sigma V^T`` per task and one Cholesky factorisation per candidate of its
    visited rows (of ``K_vv + O_s^-1``, in place), instead of a (d, d) determinant per candidate;
    the same gains to round-off (docs/maths.md §10).
    """
    if not _row_space(post):
        Lam, H = _demonstration_curvature(post, objective, beta, candidates, length, policy, known)
        base = np.linalg.slogdet(Lam)[1]
        return np.linalg.slogdet(Lam[None] + H)[1] - base
    return _visited_log_determinants(*_row_terms(post, objective, beta, candidates, length, policy, known))


def _row_terms(post: LaplacePosterior, objective: str, beta: float, candidates: NDArray[np.intp], length: int,
               policy: str, known: NDArray[np.bool_] | None) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """``(K, occ)`` of :func:`information_gains` over the rows: ``V Sigma V^T`` (S, r, S, r) in blocks of the
    ``r = A - 1`` rows of each state, symmetrised, and the candidates' expected visits (c, S), none where ``known``."""
    pl, V, pi = information_rows(post, objective, beta)
    V = _drop_null_row(V, pi, objective)
    S, r, d = V.shape
    occ = start_occupancy(pl, demonstrator_policy(pi, policy), candidates, length)
    if known is not None:
        occ = np.where(known[None, :], 0.0, occ)
    Vf = V.reshape(S * r, d)
    K = Vf @ post.covariance @ Vf.T
    return (0.5 * (K + K.T)).reshape(S, r, S, r), occ


#: expected visits at or below this (the smallest normal double) count as none: such a state's rows
#: add at most ``occ tr(K_yy)`` to a gain, and ``1 / occ`` would overflow
_OCC_MIN = float(np.finfo(np.float64).tiny)


def _visited_log_determinants(K: NDArray[np.float64], occ: NDArray[np.float64]) -> NDArray[np.float64]:
    """``log det(I + O_c^1/2 K O_c^1/2)`` (c,) of each candidate's expected visits, over the rows of the states it visits.

    With ``W = O_c^1/2`` restricted to the visited states' rows (``occ[c, y] > 0``, in practice
    above the smallest normal double; the others add identity rows), ``I + W K W = W (O_c^-1 + K) W``:
    one Cholesky factorisation ``L L^T = K_vv + O_c^-1`` of the visited block gives
    ``I + W K W = (W L)(W L)^T`` with ``W L`` triangular, so the log determinant is
    ``2 sum_i log(L_ii w_i)`` (no cancellation between large terms). The block is copied by whole
    states (``r`` contiguous rows each) into buffers reused by every candidate and factorised there
    in place, in Fortran order, its diagonal shifted by ``1 / occ`` instead of the block scaled by
    ``w w^T``: the same ``n^3 / 3`` flops of the factorisation, without allocations, Fortran-order
    copies and the scaling pass (docs/maths.md §10).

    Parameters
    ----------
    K : ndarray, shape (S, r, S, r)
        Symmetric positive semidefinite, in blocks of ``r`` rows per state (``V Sigma V^T`` of
        :func:`information_gains`).
    occ : ndarray, shape (c, S)
        Expected visits of each candidate's episode, ``>= 0``.

    Returns
    -------
    ndarray, shape (c,)
    """
    S, r = K.shape[:2]
    live = occ > _OCC_MIN
    most = int(live.sum(axis=1).max(initial=0))
    rows_buffer, block_buffer = np.empty(most * r * S * r), np.empty((most * r) ** 2)  # reused by every candidate
    gains = np.zeros(occ.shape[0])
    for c in range(occ.shape[0]):
        states = np.flatnonzero(live[c])
        m, n = states.size, states.size * r
        if n == 0:
            continue
        rows = rows_buffer[:n * S * r].reshape(m, r, S, r)
        np.take(K, states, axis=0, out=rows, mode="clip")  # "clip": no bounds check, so no buffered copy
        block = block_buffer[:n * n].reshape(m, r, m, r)
        np.take(rows, states, axis=2, out=block, mode="clip")
        M = block.reshape(n, n)
        o = np.repeat(occ[c, states], r)
        M.flat[::n + 1] += 1.0 / o
        L, info = dpotrf(M.T, lower=1, clean=0, overwrite_a=1)  # M symmetric: M.T is it, Fortran-ordered
        if info != 0:
            raise np.linalg.LinAlgError(f"the visited block of candidate {c} is not positive definite (dpotrf info {info})")
        gains[c] = 2.0 * np.sum(np.log(np.diagonal(L) * np.sqrt(o)))
    return gains


#: the slack (nats) of the upper bounds of :func:`_gain_bounds` that :func:`_best_starts` uses
_GAIN_BOUND_SLACK = 0.3


def _gain_bounds(K: NDArray[np.float64], occ: NDArray[np.float64],
                 slack: float = _GAIN_BOUND_SLACK) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Lower and upper bounds (c,), (c,) of :func:`_visited_log_determinants`, at most ``slack`` apart.

    Each candidate's visited states split into a core and a tail, the tail the states of smallest
    ``occ(y) tr(K_yy)`` whose sum ``tau`` is at most ``slack``. With ``A = W K W`` in that split,
    ``log det(I + A) = log det(I + A_cc) + log det(I + A_tt - A_tc (I + A_cc)^-1 A_ct)``, and the
    second term lies between 0 and ``log det(I + A_tt) <= tr A_tt = tau``: the bounds are the
    core's log determinant and it plus ``tau``, at the cost of the core's factorisation.
    """
    trace = np.einsum("yiyi->y", K)
    contrib = occ * trace
    order = np.argsort(contrib, axis=1, kind="stable")
    tail = np.cumsum(np.take_along_axis(contrib, order, axis=1), axis=1) <= slack
    in_tail = np.zeros(occ.shape, dtype=bool)
    np.put_along_axis(in_tail, order, tail, axis=1)
    lower = _visited_log_determinants(K, np.where(in_tail, 0.0, occ))
    return lower, lower + np.where(in_tail, contrib, 0.0).sum(axis=1)


def _best_starts(terms: list[tuple[NDArray[np.float64], NDArray[np.float64]]], n: int,
                 slack: float = _GAIN_BOUND_SLACK) -> NDArray[np.intp]:
    """The positions (min(n, c),) of the ``n`` candidates of largest mean gain over ``terms``, best first, ties to
    the earlier one: the first ``n`` of ``argsort(-gains, kind="stable")`` with ``gains`` the mean over the
    ``(K, occ)`` of ``terms`` (:func:`_row_terms`) of :func:`_visited_log_determinants`, without every gain.

    The gains' bounds (:func:`_gain_bounds`, averaged over ``terms``) leave out every candidate
    whose upper bound is below the ``n``-th best lower bound (less a margin for round-off): its
    gain is below the ``n``-th best gain, so it is not among the ``n`` best. The others' gains
    are computed as :func:`_visited_log_determinants` computes them for every candidate: the same
    starts, in the same order.
    """
    bounds = [_gain_bounds(K, occ, slack) for K, occ in terms]
    lower = np.mean([b[0] for b in bounds], axis=0)
    upper = np.mean([b[1] for b in bounds], axis=0)
    nth = np.sort(lower)[-min(n, lower.size)]
    keep = np.flatnonzero(upper >= nth - 1e-9 * max(1.0, abs(nth)))
    gains = np.full(lower.size, -np.inf)
    gains[keep] = np.mean([_visited_log_determinants(K, occ[keep]) for K, occ in terms], axis=0)
    return np.argsort(-gains, kind="stable")[:n]


def _drop_null_row(V: NDArray[np.float64], pi: NDArray[np.float64], objective: str) -> NDArray[np.float64]:
    """Each state's A rows (S, A, d) as A - 1 rows (S, A - 1, d) with the same sum of outer products.

    The centred tangents satisfy ``sum_a pi(a|y) E(y, a) = 0``, so ``u^T V[y] = 0`` with ``u_a =
    pi_a / sqrt(weight_a)`` (1 for policy matching, ``sqrt(pi_a)`` for MCE): the Householder
    reflection taking ``u / |u|`` to the first axis leaves that row zero (to round-off), and the
    other A - 1 rows carry ``V[y]^T V[y]``.
    """
    S, A, _ = V.shape
    u = np.ones((S, A)) if objective != "mce" else np.sqrt(pi)
    u = u / np.linalg.norm(u, axis=1, keepdims=True)
    v = u.copy()
    v[:, 0] -= 1.0
    vv = np.einsum("sa,sa->s", v, v)
    scale = np.where(vv > 0, 2.0 / np.where(vv > 0, vv, 1.0), 0.0)
    HV = V - (scale[:, None] * v)[:, :, None] * np.einsum("sa,sad->sd", v, V)[:, None, :]
    return HV[:, 1:]


def value_variance_reductions(post: LaplacePosterior, objective: str, beta: float, candidates: NDArray[np.intp],
                              length: int, policy: str = "boltzmann",
                              known: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """``trace(M (Sigma - (Lambda + H_s)^-1))`` (c,): the expected reduction of the posterior variance of
    the state values, linearised, ``M = mean_s dV(s)/dx dV(s)/dx^T`` with ``dV = sum_a pi dQ/dx``; the
    episode's expected visits under :func:`demonstrator_policy` (``policy``)."""
    pl, pi, dQ = model_policy(post, objective, beta)
    E = dQ - np.einsum("sa,sad->sd", pi, dQ)[:, None, :]
    weight = pi if objective == "mce" else pi * pi
    per_pair = post.scaling / post.n_pairs * (1.0 if objective == "mce" else 2.0)
    info = per_pair * beta * beta * np.einsum("sa,sad,sae->sde", weight, E, E)
    if known is not None:
        info = np.where(known[:, None, None], 0.0, info)
    dV = np.einsum("sa,sad->sd", pi, dQ)
    M = dV.T @ dV / dV.shape[0]
    occ = start_occupancy(pl, demonstrator_policy(pi, policy), candidates, length)
    Lam = np.linalg.inv(post.covariance)
    Lam = 0.5 * (Lam + Lam.T)
    H = np.einsum("cy,yde->cde", occ, info)
    after = np.linalg.inv(Lam[None] + H)
    return np.einsum("de,ed->", M, post.covariance) - np.einsum("de,ced->c", M, after)


def regret_terms(post: LaplacePosterior) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """What the regret of acting on the posterior mean depends on, to first order (docs/maths.md §10).

    With ``pi_m`` greedy on the ``Q*`` of the mean reward: the gaps ``g(y, a) = Q(y, pi_m(y)) -
    Q(y, a)`` (S, A), ``>= 0``; their tangents ``e(y, a) = dQ(y, a)/dx - dQ(y, pi_m(y))/dx`` (S, A, d),
    ``pi_m`` held fixed (exact for ``Q^{pi_m}``); and ``rho`` (S,), the discounted visits of the
    states by ``pi_m`` from a uniform start, ``(I - gamma P_{pi_m})^-T 1 / S``.
    """
    mdp = post.mdp
    S, A = mdp.n_states, mdp.n_actions
    pl = get_planner(mdp)
    res = plan(pl, post.mean_rewards()[None])
    pol = res.policy[0]
    dQ = tangent(pl, res.system, res.policy, post.basis().reshape(1, S, A, -1))[0]
    rows = np.arange(S)
    Q = res.Q[0]
    gaps = np.maximum(Q[rows, pol][:, None] - Q, 0.0)
    E = dQ - dQ[rows, pol][:, None, :]
    rho = res.system.solve_transpose(np.full((1, S), 1.0 / S))[0]
    return gaps, E, rho


def linearised_regret(gaps: NDArray[np.float64], E: NDArray[np.float64], rho: NDArray[np.float64],
                      covariance: NDArray[np.float64]) -> NDArray[np.float64]:
    """``sum_y rho(y) sum_a EI(g(y, a), sd(y, a))`` for covariances (..., d, d): the expected regret, linearised.

    ``sd(y, a)^2 = e(y, a)^T Sigma e(y, a)``, ``EI(g, sd) = E[max(0, -g + sd z)] = sd phi(g/sd) - g Phi(-g/sd)``
    (0 where ``sd = 0``): each action's expected loss when it overtakes the mean's greedy one, summed
    over the actions (a bound of the state's loss) and weighted by the visits (:func:`regret_terms`).
    """
    var = np.einsum("yad,...de,yae->...ya", E, covariance, E)
    sd = np.sqrt(np.maximum(var, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        u = np.where(sd > 0, gaps / np.where(sd > 0, sd, 1.0), np.inf)
    ei = np.where(sd > 0, sd * np.exp(-0.5 * u * u) / np.sqrt(2.0 * np.pi) - gaps * ndtr(-u), 0.0)
    return np.einsum("y,...ya->...", rho, np.maximum(ei, 0.0))


def regret_reductions(post: LaplacePosterior, objective: str, beta: float, candidates: NDArray[np.intp],
                      length: int, policy: str = "boltzmann", known: NDArray[np.bool_] | None = None) -> NDArray[np.float64]:
    """The expected reduction (c,) of the linearised regret (:func:`linearised_regret`) by a ``length``-step
    demonstration from each candidate start: its value at ``Sigma`` minus its value at ``(Lambda + H_s)^-1``,
    ``H_s`` the expected curvature of :func:`information_gains` (the same ``policy`` and ``known``)."""
    Lam, H = _demonstration_curvature(post, objective, beta, candidates, length, policy, known)
    after = np.linalg.inv(Lam[None] + H).astype(np.float64, copy=False)
    gaps, E, rho = regret_terms(post)
    return linearised_regret(gaps, E, rho, post.covariance) - linearised_regret(gaps, E, rho, 0.5 * (after + np.swapaxes(after, 1, 2)))


def _candidates(candidates: Any, n: int, mdps: list) -> list[NDArray[np.intp]]:
    if candidates is None:
        return [np.arange(m.n_states) for m in mdps]
    if isinstance(candidates, np.ndarray):  # (c,): shared; (n_new, c): one row per task
        per_task = candidates.ndim == 2
    else:  # a sequence of states (shared), or of per-task arrays, possibly of different lengths
        per_task = isinstance(candidates, (list, tuple)) and any(not np.isscalar(c) for c in candidates)
    if per_task and len(candidates) != n:
        raise ValidationError(f"candidates per task must be a sequence of n_new = {n} arrays of state indices, one per "
                              f"task; got {len(candidates)}")
    lists = list(candidates) if per_task else [candidates] * n
    out = []
    for i, (c, m) in enumerate(zip(lists, mdps)):
        arr = np.asarray(c)
        if arr.ndim != 1 or arr.size == 0 or not np.issubdtype(arr.dtype, np.integer):
            raise ValidationError(f"candidates of task {i} must be a non-empty 1-d array of state indices; got {c!r:.80}")
        if arr.min() < 0 or arr.max() >= m.n_states:
            raise ValidationError(f"candidates of task {i} must be states in [0, {m.n_states}); got {arr.min()}..{arr.max()}")
        out.append(arr.astype(np.intp))
    return out


def _episode_length(n_pairs: float, task_demos: Any) -> int:
    return max(1, int(round(n_pairs / max(1, len(task_demos)))))


def _posteriors(model: Any, mdp: Any, demos_per_task: Any, features: Any) -> tuple[list, Any]:
    """The posteriors and the task set of these tasks: the model's last transfer's when they are its tasks, else built here."""
    inputs = transfer_inputs(model)
    if inputs is not None and inputs[0] is mdp and inputs[1] is demos_per_task and inputs[2] is features:
        posts, tasks = model.transfer_posterior_, model._transfer.tasks
    else:
        tasks, D = transfer_tasks(mdp, demos_per_task, features, model)
        posts = model_posteriors(model, tasks_problem(model, tasks, D)) if has_prior(model) else None
    if posts is None:
        raise ValidationError("request_starts needs the tasks' posterior, which is undefined for this model: it needs "
                              "at least 2 training tasks' coefficients_ and a residual_penalty_ other than 0")
    return posts, tasks


CRITERIA = {"information": information_gains, "value": value_variance_reductions, "regret": regret_reductions}

#: How a requested demonstration's pairs in states already demonstrated count (``request_starts(demonstrated=...)``).
DEMONSTRATED = ("count", "skip")


def demonstrated_states(mdp: Any, task_demos: Any, task: int = 0) -> NDArray[np.bool_]:
    """Which states (S,) one task's demonstrations visit (a greedy expert's action there is already known)."""
    from ..tasks.trajectories import task_steps

    return _visited_states(mdp.n_states, task_steps(mdp, task_demos, task))


def _visited_states(n_states: int, steps: NDArray[np.intp]) -> NDArray[np.bool_]:
    """The states (n_states,) of parsed demonstration steps (m, 2) of (state, action)."""
    known = np.zeros(n_states, dtype=bool)
    known[steps[:, 0]] = True
    return known


@learner_entry
def request_starts(model: Any, mdp: Any, demos_per_task: Any, n_requests: int = 1, candidates: Any = None, *,
                   features: Any = None, criterion: str = "information",
                   policy: str = "boltzmann", demonstrated: str = "count", marginal: bool = False) -> list[NDArray[np.intp]]:
    """Candidate start states per new task, best first, by expected information gain (module docstring).

    Parameters
    ----------
    model : FactIRL
        Fitted (its ``coefficients_`` give the prior).
    mdp, demos_per_task, features
        The new tasks, as in ``FactIRL.transfer``; the posterior is the model's
        ``transfer_posterior_`` when these are the objects of its last transfer, else the
        posterior of these tasks (MAP from the prior mean).
    n_requests : int, default=1
    candidates : array_like of int (c,), or sequence of n_new such arrays, optional
        Default: every state of each task's MDP.
    criterion : {"information", "value", "regret"}, default="information"
        The expected information gain about the coefficients (:func:`information_gains`,
        D-optimal), the expected reduction of the posterior variance of the state values
        (:func:`value_variance_reductions`), or the expected reduction of the linearised regret
        of acting on the posterior mean (:func:`regret_reductions`). For a residual model's
        posterior and fewer requests than candidates, the information gain of only the
        candidates that bounds on the gains cannot exclude from the ``n_requests`` best is
        computed (docs/maths.md §10): the same starts as the full ranking's first.
    policy : {"boltzmann", "greedy"}, default="boltzmann"
        The policy a demonstration from a start is assumed to follow (:func:`demonstrator_policy`):
        the model's stochastic policy at the posterior mean, or its greedy policy.
    demonstrated : {"count", "skip"}, default="count"
        How the pairs of a requested demonstration in states the task's demonstrations already
        visit count: as the model's likelihood counts them (``"count"``), or not at all
        (``"skip"``: a deterministic expert repeats its known action there, docs/maths.md §10).
    marginal : bool, default=False
        Rank by the criterion averaged over the posterior's dictionaries (its own and its
        ``members``, a model fitted with ``posterior.n_dictionaries``): the expected gain when the
        dictionary itself is uncertain, ``mean_b crit_b(s)`` with ``crit_b`` the criterion of the
        task's posterior under dictionary ``b`` (docs/maths.md §10); ``1 + B`` times the ranking's
        cost. Without members the same ranking as False.

    Returns
    -------
    list of n_new int arrays, each (min(n_requests, c),)

    Raises
    ------
    ValidationError
        For ``n_requests`` < 1, candidates out of range, an unknown ``criterion``, ``policy`` or
        ``demonstrated``, or a
        model whose posterior is undefined.
    """
    n_requests = check_int(n_requests, "n_requests", minimum=1)
    marginal = check_bool(marginal, "marginal")
    if criterion not in CRITERIA:
        raise ValidationError(f"criterion must be one of {', '.join(CRITERIA)}; got {criterion!r}")
    if policy not in POLICIES:
        raise ValidationError(f"policy must be one of {', '.join(POLICIES)}; got {policy!r}")
    if demonstrated not in DEMONSTRATED:
        raise ValidationError(f"demonstrated must be one of {', '.join(DEMONSTRATED)}; got {demonstrated!r}")
    posts, tasks = _posteriors(model, mdp, demos_per_task, features)
    n = len(posts)
    cands = _candidates(candidates, n, [p.mdp for p in posts])
    objective = model.objective if isinstance(model.objective, str) else getattr(model.objective, "name", "")
    out = []
    for i, post in enumerate(posts):
        known = _visited_states(post.mdp.n_states, tasks.demonstrations[i].steps) if demonstrated == "skip" else None
        length = _episode_length(post.n_pairs, demos_per_task[i])
        averaged = [post, *post.members] if marginal else [post]
        if criterion == "information" and n_requests < cands[i].size and all(_row_space(q) for q in averaged):
            # a residual posterior's gains over the rows: the n best without every gain (_best_starts)
            terms = [_row_terms(q, objective, model.beta, cands[i], length, policy, known) for q in averaged]
            out.append(cands[i][_best_starts(terms, n_requests)])
            continue
        gains = CRITERIA[criterion](post, objective, model.beta, cands[i], length, policy, known)
        if marginal and post.members:
            gains = np.mean([gains] + [CRITERIA[criterion](m, objective, model.beta, cands[i], length, policy, known)
                                       for m in post.members], axis=0)
        order = np.argsort(-gains, kind="stable")
        out.append(cands[i][order[:n_requests]])
    return out


def policy_entropy_starts(posts: list[LaplacePosterior], objective: str, beta: float, n_requests: int = 1,
                          candidates: Any = None) -> list[NDArray[np.intp]]:
    """The baseline of Lopes et al. (2009): per task, the candidates where the model's policy at the
    posterior mean has the highest entropy, best first."""
    n_requests = check_int(n_requests, "n_requests", minimum=1)
    cands = _candidates(candidates, len(posts), [p.mdp for p in posts])
    out = []
    for post, c in zip(posts, cands):
        pi = model_policy(post, objective, beta)[1]
        ent = -np.sum(np.where(pi > 0, pi * np.log(np.where(pi > 0, pi, 1.0)), 0.0), axis=1)
        order = np.argsort(-ent[c], kind="stable")
        out.append(c[order[:n_requests]])
    return out
