"""Approximate leave-one-task-out validation: one fit per candidate, one Newton step per task left out.

The exact search of :mod:`factirl_opt.learners.adaptive` fits every candidate ``(k, lambda)`` on
the training folds' tasks and transfers the held-out tasks. Here each candidate is fitted once
on all n tasks; for each task t the dictionary the fit would give *without* task t is
approximated by one Gauss-Newton step from the full fit, task t is transferred from its first
demonstrations with that dictionary and scored on its others (the same held-out score). Every
task is then held out (n paired scores per candidate instead of about n / K per fold), for one
fit per candidate, one Jacobian evaluation and n transfers of one task.

The model (docs/maths.md §8, §8a; :mod:`factirl_opt.objectives.residuals`): task i's weights
``w_i = D h_i + delta_i`` and

    J(D, H, Delta) = sum_i f_i,   f_i = J_i(Phi w_i) + lambda ||delta_i||^2,

with ``J_i = ||r_i||^2`` (policy matching, eq. 5: ``r_i = sqrt(mu_i) (pi_i - pi_hat_i)``).
Profiling the task variables out, ``F(D) = sum_i min_(h_i, delta_i) f_i`` is the dictionary's
objective, and leaving task t out minimises ``F_(-t) = F - f_t``. One Newton step from the full
fit ``D^`` (the infinitesimal jackknife / approximate leave-one-out of Beirami et al. 2017 and
Giordano et al. 2019, for a whole block of data, here a task's demonstrations, as in Ghosh et
al. 2020):

    D_(-t) = D^ - K_(-t)^(-1) grad F_(-t)(D^),   grad F_(-t)(D^) = sum_(i != t) g_i h_i^T,

with ``g_i = dJ_i/dw_i = 2 J_i^T r_i`` (``J_i = dr_i/dw_i``, the library's Gauss-Newton Jacobian,
:meth:`~factirl_opt.objectives.contract.TaskObjective.residual_jacobian`) and the gradient
of the remaining tasks at the fit (not ``-g_t h_t^T``: a fit stopped by ``tol`` or ``max_iter``
is not an exact optimum, and the step then also finishes it, as Ghosh et al. do for inexact fits).

**The profiled Gauss-Newton Hessian** ``K_(-t) = sum_(i != t) K_i``. With the Gauss-Newton
Hessian ``G_i = 2 J_i^T J_i`` of ``J_i`` in ``w``, eliminating ``delta_i`` (its Schur
complement) leaves the curvature ``G~_i = G_i (G_i + 2 lambda I)^(-1) 2 lambda`` in ``w``
(``G_i`` for ``lambda = inf``; 0 for ``lambda = 0``, where the dictionary plays no part);
eliminating ``h_i`` (``w_i = D h_i``, a second Schur complement) leaves

    K_i[dD] = (dD h_i)^T P_i (dD h_i),   P_i = G~_i - G~_i D (D^T G~_i D)^+ D^T G~_i,

i.e. ``K_i = (h_i h_i^T) kron P_i`` on ``vec(D)``. With ``G~_i = L_i L_i^T`` (``L_i`` from the
thin SVD of ``J_i``'s rows of visited states) ``P_i = M_i M_i^T``, ``M_i = L_i Q_i`` with ``Q_i``
an orthonormal basis of the complement of ``range(L_i^T D)``: each task's curvature is a
low-rank factor, and ``K_(-t) X = sum_(i != t) M_i M_i^T X h_i h_i^T`` costs ``O(n p r)``. The
Newton systems of all the tasks left out are solved together by conjugate gradients, damped
by ``damping * trace(K) / (p k)`` (Levenberg-Marquardt). The Gauss-Newton step leaves out the
bilinear term ``g_i^T dD dh_i`` of the exact Hessian (``K`` stays positive semi-definite).

**The default: the infinitesimal jackknife, damped.** ``K_(-t)`` is nearly singular in the
directions that only task t constrains (p k unknowns against n tasks: the high-dimensional regime
of Stephenson & Broderick 2020), and an inexact fit's own gradient is common to every step. On the
paper's grid the undamped Newton step moved the dictionary by 80-300% of its norm; the default step
(``curvature="full"``: every task's curvature ``K``, as the infinitesimal jackknife of Giordano et
al. 2019; ``inexact=False``: task t's gradient ``-g_t h_t^T`` alone; ``damping=0.1``) by a few per cent.

**The gauge.** ``F(D M) = F(D)`` for any invertible k x k ``M`` (``h_i`` absorbs ``M^(-1)``):
``K`` vanishes on ``{D M}`` (``P_i D = 0``). Those directions change no reward; the right-hand
sides are projected off them (``X - D D^+ X``), and the step stays off them.

**Measured: it does not rank the candidates well.** On the paper's grid at 20 tasks (seed 2, 13
candidates; ``results/which-learner/rank_approx.py``) the Spearman correlation of the approximate
scores with the candidates' test deviations is -0.60 for the default step and 0.16-0.43 for the
undamped Newton steps and jackknife, against 0.69 for the exact 3-fold scores and 0.61 for the naive
in-sample scores (the full fit's dictionary, no step); with the exact 3-fold scores -0.32 to 0.01. One
task moves the dictionary far: refits without it from the PCA start land 36-50% (gauge-invariant
distance) from the full fit, and its held-out score is 1.3 against 0.6-0.8 in sample, a change no
local step reproduces (a refit started from the full fit moves it 3%, and the default step
predicts that refit's score: 0.84, 1.15, 0.62 against 0.82, 1.15, 0.61 at k = 2). At k = 8 every
task is fitted exactly (in-sample score 0) and the step moves the dictionary by 33-50%: its error
grows with k, which biases the ranking toward small k. The route costs about one fit per candidate
(26.1x the factorial fit at seed 0, ``results/which-learner/routes.py``).

What is supported: the policy-matching objective (any least-squares objective), tasks on one
MDP with tabular, state or shared feature rewards, an unconstrained H-solver and a free
dictionary; anything else raises :class:`~factirl_opt.exceptions.ValidationError`
(:func:`check_approximate_cv`).

References
----------
Beirami, Razaviyayn, Shahrampour, Tarokh (2017). On optimal generalizability in parametric
learning. NeurIPS.
Giordano, Stephenson, Liu, Jordan, Broderick (2019). A swiss army infinitesimal jackknife.
AISTATS.
Ghosh, Stephenson, Nguyen, Deshpande, Broderick (2020). Approximate cross-validation for
structured models. NeurIPS.
Stephenson, Broderick (2020). Approximate cross-validation in high dimensions with guarantees.
AISTATS (accuracy degrades in high dimension unless the solution is sparse).
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._validation import check_int, check_real
from ..exceptions import ValidationError
from ..objectives.problems import as_problem_basis, weights_problem
from ..objectives.residuals import residual_weights
from ..tasks.task_set import task_set
from .estimator import clone
from .fitting import resolve_step_solver, task_objective
from .solver_settings import estimator_solvers

__all__ = ["leave_task_out_dictionaries", "leave_task_out_scores", "check_approximate_cv", "task_curvature_factors",
           "DAMPING", "CG_TOL", "CG_MAX_ITER", "CURVATURES"]

#: Levenberg-Marquardt damping of the Newton systems, relative to the mean curvature ``trace(K) / (p k)``: on
#: the paper's grid (p k = 500 k unknowns, 20 tasks) a damping of 1e-3 moved the dictionary by 70-300% of its norm
#: and the transfers with it predicted no better than the uniform policy; 0.1 moves it by 1-5%
DAMPING = 0.1
#: conjugate gradients stop when a system's residual norm is below this fraction of its right-hand side's
CG_TOL = 1e-6
#: most conjugate-gradient iterations of the Newton systems
CG_MAX_ITER = 500
#: the curvature of the step: the other tasks' (``"leave-out"``, the Newton step of Beirami et al.) or
#: every task's (``"full"``, the infinitesimal jackknife of Giordano et al.)
CURVATURES = ("leave-out", "full")


def check_approximate_cv(learner: Any, tasks: Any) -> None:
    """Refuse what the approximate leave-task-out scores do not support.

    Parameters
    ----------
    learner : FactIRL
    tasks : TaskSet
        The tasks of the search (:func:`~factirl_opt.tasks.task_set.task_set`).

    Raises
    ------
    ValidationError
        Fewer than 3 tasks; an objective that is not least squares (e.g. ``"mce"``); tasks in
        several environments or per-task features; a constrained H-solver; a constrained
        dictionary. The message names the value.
    """
    if tasks.n_tasks < 3:
        raise ValidationError(f"the approximate leave-task-out route needs at least 3 tasks (each left out in turn); "
                              f"got {tasks.n_tasks}")
    if learner.objective != "policy-matching":
        raise ValidationError(f"the approximate leave-task-out route needs the 'policy-matching' objective (its "
                              f"Gauss-Newton Jacobians); got objective={learner.objective!r}: use another route")
    if not tasks.shared:
        raise ValidationError("the approximate leave-task-out route needs tasks on one MDP with tabular, state or shared "
                              "feature rewards; got tasks in several environments or per-task features: use another route")
    h_name, h_options, _, _ = estimator_solvers(learner)
    constraint = resolve_step_solver(h_name, h_options, learner.objective, "solver").constraint
    if constraint != "none":
        raise ValidationError(f"the approximate leave-task-out route needs an unconstrained H-solver (its Newton step "
                              f"profiles the coefficients out freely); got a {constraint!r} one ({h_name!r})")
    if getattr(learner, "dictionary_constraint", None) is not None:
        raise ValidationError(f"the approximate leave-task-out route needs a free dictionary; got "
                              f"dictionary_constraint={learner.dictionary_constraint!r}")


def task_curvature_factors(jacobians: NDArray[np.float64], dictionary: NDArray[np.float64],
                           residual_penalty: float) -> NDArray[np.float64]:
    """Low-rank factors ``M_i`` of each task's profiled Gauss-Newton curvature ``P_i = M_i M_i^T``.

    Parameters
    ----------
    jacobians : ndarray, shape (n, m, p)
        ``J_i = dr_i/dw_i`` of each task's residuals (rows of unvisited states are zero).
    dictionary : ndarray, shape (p, k)
    residual_penalty : float
        ``lambda`` (np.inf: no residuals; > 0).

    Returns
    -------
    ndarray, shape (n, p, r)
        ``M_i`` (module docstring), zero-padded to the largest rank ``r`` over the tasks:
        ``P_i = G~_i - G~_i D (D^T G~_i D)^+ D^T G~_i`` with ``G~_i = 2 J_i^T J_i`` for
        ``lambda = inf`` and ``2 J_i^T J_i (J_i^T J_i + lambda I)^(-1) lambda`` otherwise.
    """
    n, _, p = jacobians.shape
    factors = []
    for J in jacobians:
        J = J[np.any(J != 0.0, axis=1)]  # the visited states' rows
        if J.shape[0] == 0:
            factors.append(np.zeros((p, 0)))
            continue
        s2, U = np.linalg.eigh(J @ J.T)  # J J^T = U s^2 U^T, J^T U = V s
        keep = s2 > s2.max() * 1e-12 if s2.max() > 0 else np.zeros(s2.shape, dtype=bool)
        s2, U = s2[keep], U[:, keep]
        V = (J.T @ U) / np.sqrt(s2)
        c = 2.0 * s2 if np.isinf(residual_penalty) else 2.0 * s2 * residual_penalty / (s2 + residual_penalty)
        L = V * np.sqrt(c)  # G~_i = L L^T
        Y = L.T @ dictionary  # (r, k): P_i = L (I - Y Y^+) L^T
        Q, sv, _ = np.linalg.svd(Y, full_matrices=True)
        rank = int(np.sum(sv > sv.max() * 1e-10)) if sv.size and sv.max() > 0 else 0
        factors.append(L @ Q[:, rank:])
    r = max(f.shape[1] for f in factors)
    out = np.zeros((n, p, r))
    for i, f in enumerate(factors):
        out[i, :, :f.shape[1]] = f
    return out


def _batched_cg(apply: Callable[[NDArray[np.float64]], NDArray[np.float64]], B: NDArray[np.float64], tol: float,
                max_iter: int) -> NDArray[np.float64]:
    """Solve ``apply(X)[t] = B[t]`` for every t at once by conjugate gradients (each system symmetric
    positive definite on the span of its right-hand side); ``B`` (m, p, k)."""
    X = np.zeros_like(B)
    R = B.copy()
    P = R.copy()
    rs = np.einsum("tpk,tpk->t", R, R)
    bound = (tol ** 2) * rs
    for _ in range(max_iter):
        active = rs > bound
        if not active.any():
            break
        AP = apply(P)
        pap = np.einsum("tpk,tpk->t", P, AP)
        alpha = np.where(active & (pap > 0), rs / np.where(pap > 0, pap, 1.0), 0.0)
        X += alpha[:, None, None] * P
        R -= alpha[:, None, None] * AP
        new = np.einsum("tpk,tpk->t", R, R)
        beta = np.where(active & (rs > 0), new / np.where(rs > 0, rs, 1.0), 0.0)
        P = R + beta[:, None, None] * P
        rs = np.where(active, new, rs)
    return X


def leave_task_out_dictionaries(objective: Any, basis: Any, dictionary: Any, coefficients: Any, residuals: Any = None,
                                residual_penalty: float = np.inf, *, tasks: Sequence[int] | None = None,
                                damping: float = DAMPING, tol: float = CG_TOL, max_iter: int = CG_MAX_ITER,
                                inexact: bool = False, curvature: str = "full") -> NDArray[np.float64]:
    """The dictionaries the fit would give without each task, by one Gauss-Newton step from the full fit.

    By default the infinitesimal jackknife ``D_(-t) = D^ + (K + mu I)^(-1) Pi(g_t h_t^T)`` (module
    docstring): ``K`` the profiled Gauss-Newton Hessian of every task, ``mu = damping * trace(K) / (p k)``,
    ``Pi`` the projection off the gauge directions ``{D M}``; ``curvature="leave-out"`` takes ``K_(-t)``
    (the Newton step) and ``inexact=True`` the gradient ``sum_(i != t) g_i h_i^T`` of the other tasks.

    Parameters
    ----------
    objective : TaskObjective
        Least squares (policy matching), over the n tasks of the fit.
    basis : RewardBasis
        The fit's basis ``Phi`` (:attr:`~factirl_opt.tasks.task_set.TaskSet.basis`).
    dictionary : array_like, shape (p, k)
        ``D^``, the full fit's.
    coefficients : array_like, shape (n, k)
        ``H``.
    residuals : array_like, shape (n, p), optional
        ``Delta`` of a fit with a finite ``residual_penalty`` (None: zeros).
    residual_penalty : float, default=np.inf
        ``lambda``; with 0 the dictionary plays no part and ``D^`` is returned for every task.
    tasks : sequence of int, optional
        The tasks left out (default all), in the order returned.
    damping : float, default=DAMPING
        Relative Levenberg-Marquardt damping (> 0).
    tol : float, default=CG_TOL
        Relative residual at which each task's conjugate gradients stop.
    max_iter : int, default=CG_MAX_ITER
        Most conjugate-gradient iterations.
    inexact : bool, default=False
        The gradient of the other tasks at the fit, ``sum_(i != t) g_i h_i^T`` (the step also
        finishes an inexact fit, Ghosh et al. 2020); False: ``-g_t h_t^T`` alone, as at an exact
        optimum (``sum_i g_i h_i^T = 0``), so that every task's step is its own influence.
    curvature : {"leave-out", "full"}, default="full"
        :data:`CURVATURES`: ``K_(-t)``, the other tasks' curvature (the Newton step), or ``K``,
        every task's (the infinitesimal jackknife: one system matrix for every task, never
        singular in a direction only task t constrains).

    Returns
    -------
    ndarray, shape (len(tasks), p, k)

    Raises
    ------
    ValidationError
        The objective is not least squares; shapes that disagree (named); ``damping`` not > 0.
    """
    if not objective.least_squares:
        raise ValidationError(f"leave_task_out_dictionaries needs a least-squares objective (its Gauss-Newton "
                              f"Jacobians); got {objective.name!r}")
    D = np.asarray(dictionary, dtype=np.float64)
    H = np.asarray(coefficients, dtype=np.float64)
    if D.ndim != 2 or H.ndim != 2 or H.shape[1] != D.shape[1]:
        raise ValidationError(f"dictionary (p, k) and coefficients (n, k) must have equal k; got {D.shape} and {H.shape}")
    n, k = H.shape
    p = D.shape[0]
    if n != objective.n_tasks:
        raise ValidationError(f"coefficients describe {n} tasks but the objective {objective.n_tasks}")
    basis = as_problem_basis(objective, basis)
    if basis.n_params != p:
        raise ValidationError(f"the dictionary has p = {p} rows but the basis {basis.n_params} parameters")
    Delta = None if residuals is None else np.asarray(residuals, dtype=np.float64)
    if Delta is not None and Delta.shape != (n, p):
        raise ValidationError(f"residuals must have shape (n, p) = ({n}, {p}); got {Delta.shape}")
    lam = float(residual_penalty)
    if not lam >= 0.0:
        raise ValidationError(f"residual_penalty must be >= 0 (np.inf: no residuals); got {residual_penalty!r}")
    damping = check_real(damping, "damping")
    if not damping > 0.0:
        raise ValidationError(f"damping must be > 0; got {damping!r}")
    max_iter = check_int(max_iter, "max_iter", minimum=1)
    left = np.arange(n) if tasks is None else np.asarray(tasks, dtype=np.int64)
    if left.ndim != 1 or (left.size and (left.min() < 0 or left.max() >= n)):
        raise ValidationError(f"tasks must be indices in [0, {n}); got {tasks!r:.80}")
    if lam == 0.0:
        return np.broadcast_to(D, (left.size, p, k)).copy()

    flat = weights_problem(objective, basis)
    if flat.residual_jacobian is None:
        raise ValidationError(f"the {objective.name!r} objective gives no residual Jacobian")
    _, r, J = flat.residual_jacobian(residual_weights(D, H, Delta), np.arange(n))
    J = np.asarray(J, dtype=np.float64)
    g = 2.0 * np.einsum("imp,im->ip", J, r)  # dJ_i/dw_i
    M = task_curvature_factors(J, D, lam)  # (n, p, r)
    Mt = M.transpose(0, 2, 1)
    mu = damping * max(float(np.sum(np.sum(H * H, axis=1) * np.sum(M * M, axis=(1, 2)))), np.finfo(float).tiny) / (p * k)
    pinv_D = np.linalg.pinv(D)

    def off_gauge(X):  # X - D D^+ X: no component along {D M}
        return X - D @ (pinv_D @ X)

    if curvature not in CURVATURES:
        raise ValidationError(f"curvature must be one of {CURVATURES}; got {curvature!r}")
    mask = np.ones((left.size, n))
    if curvature == "leave-out":
        mask[np.arange(left.size), left] = 0.0

    def apply(X):  # (K_(-t) + mu I) X_t for every t: sum_(i != t) M_i M_i^T X_t h_i h_i^T
        A = np.einsum("tpk,ik->itp", X, H)  # X_t h_i
        Y = np.matmul(np.matmul(A, M), Mt)  # (n, m, p): P_i X_t h_i
        return off_gauge(np.einsum("itp,ti,ik->tpk", Y, mask, H)) + mu * X

    total = g.T @ H if inexact else np.zeros((p, k))  # sum_i g_i h_i^T (p, k); 0 at an exact optimum
    B = -off_gauge(total[None] - np.einsum("tp,tk->tpk", g[left], H[left]))
    return D[None] + _batched_cg(apply, B, tol, max_iter)


def leave_task_out_scores(learner: Any, mdp: Any, demos_per_task: Any, flat_rewards: Any,
                          candidates: Sequence[tuple[int, float]],
                          score_tasks: Callable[[Any, NDArray[np.intp]], NDArray[np.float64]], *,
                          candidate_max_iter: int | None = None, progress: Any = None, damping: float = DAMPING,
                          tol: float = CG_TOL, max_iter: int = CG_MAX_ITER) -> dict:
    """Approximate leave-one-task-out scores of ``candidates``: one fit each on every task.

    For each candidate ``(k, lambda)``, a clone of ``learner`` with those values is fitted on
    all n tasks (from ``flat_rewards``' PCA start); for each task t, a copy of the fit whose
    ``dictionary_`` is :func:`leave_task_out_dictionaries`' ``D_(-t)`` is scored on task t
    by ``score_tasks(model, [t])`` (which transfers it from its first demonstrations and scores
    the others: :func:`factirl_opt.learners.adaptive.search_sharing` passes the held-out score).
    ``lambda = 0`` (the flat model: its transfer uses no dictionary) is exact and needs no step:
    it takes the last fitted candidate, or a fit of its own when it is the only candidate.

    Parameters
    ----------
    learner : FactIRL
        Its other hyper-parameters are used by every candidate fit.
    mdp, demos_per_task
        As in ``FactIRL.fit`` (checked by :func:`check_approximate_cv`).
    flat_rewards : optional
        Every task's flat rewards, the PCA start of every candidate.
    candidates : sequence of (k, lambda)
    score_tasks : callable
        ``score_tasks(model, idx) -> array`` of the held-out scores of tasks ``idx``.
    candidate_max_iter : int or None
        Outer iterations of each candidate fit, at most the learner's ``max_iter`` (None: that).
    progress : SearchProgress, optional
        Scores appended to ``progress.scores`` and fits recorded as soon as they are computed.
    damping, tol, max_iter
        Of :func:`leave_task_out_dictionaries`.

    Returns
    -------
    dict
        ``{(k, lambda): [array of n per-task scores]}`` (one "fold" holding every task out).

    Raises
    ------
    ValidationError
        What :func:`check_approximate_cv` refuses.
    """
    tasks = task_set(mdp, demos_per_task, learner.features, learner.reward)
    check_approximate_cv(learner, tasks)
    n = tasks.n_tasks
    every = np.arange(n)
    budget = learner.max_iter if candidate_max_iter is None else min(candidate_max_iter, learner.max_iter)
    scores: dict = {}
    last = None
    for k, lam in candidates:
        if lam == 0.0 and last is not None:  # the flat model: the dictionary plays no part, no fit
            model = copy.copy(last)
            model.residual_penalty = model.residual_penalty_ = 0.0
            values = np.asarray(score_tasks(model, every), dtype=np.float64)
        else:
            quiet = dataclasses.replace(learner._group("execution"), verbose=False, callback=None)
            model = clone(learner).set_params(n_primitives=k, residual_penalty=lam, execution=quiet, max_iter=budget)
            if progress is not None:
                progress.last = ((k, lam), model, every)
            model.fit(mdp, demos_per_task, flat_rewards=flat_rewards)
            if progress is not None:
                progress.fits[k, lam], progress.train_tasks[k, lam] = model, every
            last = model
            if lam == 0.0:
                values = np.asarray(score_tasks(model, every), dtype=np.float64)
            else:
                objective = task_objective(tasks, model.beta, model.objective, model._group("execution").planner)
                dictionaries = leave_task_out_dictionaries(
                    objective, tasks.basis, model.dictionary_, model.coefficients_,
                    None if np.isinf(model.residual_penalty_) else model.residuals_, model.residual_penalty_,
                    damping=damping, tol=tol, max_iter=max_iter)
                values = np.empty(n)
                for t in range(n):
                    one = copy.copy(model)
                    one.dictionary_ = dictionaries[t]
                    values[t] = np.asarray(score_tasks(one, np.array([t])), dtype=np.float64)[0]
        scores[k, lam] = [values]
        if progress is not None:
            progress.scores.setdefault((k, lam), []).append(values)
    return scores
