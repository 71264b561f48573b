"""The Laplace posterior of a transferred task: how sure its reward is (docs/maths.md §10).

A new task transferred with the dictionary ``D`` fixed has ``k`` coefficients ``h`` (and, with a
finite ``residual_penalty`` ``lambda``, a residual ``delta`` of ``p`` weights): its reward weights
are ``w = D h + delta`` and its rewards ``R = Phi w``. With ``x = [h, delta]`` (d = k, or k + p)
and the task's demonstration loss ``J(x)`` (eq. 5 or the MCE likelihood), the posterior is

    -log p(x | demos) = s J(x) + 1/2 (h - m)^T P (h - m) + s lambda ||delta||^2 + const,

- ``s`` the likelihood's scaling (:func:`likelihood_scaling`): ``N`` for MCE (``J`` is the mean
  negative log-likelihood of the ``N`` demonstrated pairs), ``N / (2 sigma^2)`` for policy
  matching (``J`` is a sum of squares whose residuals have variance ``sigma^2 / N`` per
  component under the Boltzmann policy's multinomial draws);
- ``(m, P^-1)`` a Gaussian fitted to the training tasks' coefficients (:func:`~factirl_opt.learners.transfer.coefficient_prior`);
- the residual's prior the transfer's own penalty, on the scale of the likelihood.

:func:`laplace_posteriors` finds the maximum a posteriori ``x`` by damped Newton steps on this
objective, with the demonstration loss's curvature ``G`` (Gauss-Newton ``2 J_r^T J_r`` for policy
matching, the Fisher information, the Gauss-Newton part of :meth:`MCEObjective.hessian`, for MCE)
and returns, per task, a :class:`LaplacePosterior` with that mean and the covariance
``(s G + blockdiag(P, 2 s lambda I))^-1`` at it. The transfer's own coefficients are left as they
are (``FactIRL.transfer_coefficients_``): the posterior's mean is the MAP, which the prior keeps
away from the saturated region where one demonstration is matched by unbounded coefficients.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._deprecation import moved_names
from .._validation import as_rng, check_array, check_int
from ..exceptions import NotFittedError, ValidationError
from ..mdp.tabular import TabularMDP
from ..planning import get_planner, plan
from ..tasks.basis import as_basis
from .transfer import coefficient_prior, transfer_tasks

__all__ = ["LaplacePosterior", "likelihood_scaling", "laplace_posteriors",
           "transfer_posterior", "transfer_problem", "demonstration_curvature", "TransferProblem", "cached_transfer_posterior", "keep_transfer",
           "TransferState", "tasks_problem", "has_prior",
           "set_transfer_posterior", "transfer_inputs", "has_transfer_posterior", "lowrank_solve"]

#: damped Newton steps of the MAP at most, and the stopping rule on the Newton decrement
#: ``g^T Lambda^-1 g`` (nats of log-posterior: the mean is then within ``sqrt(2 MAP_TOL)`` posterior
#: standard deviations of the MAP along every direction)
MAP_MAX_ITER = 100
MAP_TOL = 1e-3
#: Levenberg-Marquardt damping of the MAP's first step (relative to the curvature's diagonal), and
#: the damping at which a task stops: no step of a thousandth of the Newton step's length decreases its
#: objective (a kink of the loss, where the greedy policy of ``Q*`` changes, or rounding)
MAP_DAMPING = 1.0
MAP_MAX_DAMPING = 1e3
#: tasks whose feature tangents (r, S*A, d) are formed at once, at most this many bytes
CHUNK_BYTES = 64 * 2**20


@dataclasses.dataclass(eq=False)
class LaplacePosterior:
    """A Gaussian posterior over one transferred task's coefficients (and residual).

    Parameters
    ----------
    mean : ndarray, shape (d,)
        ``x = [h, delta]``: the k coefficients, then the p residual weights when the transfer
        has a finite ``residual_penalty`` (d = k + p), else d = k.
    covariance : ndarray, shape (d, d)
    dictionary : ndarray, shape (p, k)
    features : ndarray, shape (S*A, p), or None
        The task's base features ``Phi`` (state-action rows ``s * A + a``); None: tabular
        (p = S*A).
    mdp : TabularMDP
        The task's MDP, where sampled rewards are planned.
    scaling : float
        The likelihood's scaling ``s`` (:func:`likelihood_scaling`).
    n_pairs : float
        ``N``, the demonstrated pairs the posterior is conditioned on (``scaling / n_pairs`` is
        the likelihood's weight of one demonstrated pair).

    Attributes
    ----------
    n_primitives : int
    has_residual : bool
    """

    mean: NDArray[np.float64]
    covariance: NDArray[np.float64]
    dictionary: NDArray[np.float64]
    features: NDArray[np.float64] | None
    mdp: TabularMDP
    scaling: float = 1.0
    n_pairs: float = 1.0

    @property
    def n_primitives(self) -> int:
        return int(self.dictionary.shape[1])

    @property
    def has_residual(self) -> bool:
        return self.mean.shape[0] > self.n_primitives

    def weights(self, x: ArrayLike) -> NDArray[np.float64]:
        """Reward weights ``D h + delta`` (n, p) of points ``x`` (n, d)."""
        X = np.atleast_2d(np.asarray(x, dtype=np.float64))
        k = self.n_primitives
        W = X[:, :k] @ self.dictionary.T
        return W + X[:, k:] if self.has_residual else W

    def rewards(self, x: ArrayLike) -> NDArray[np.float64]:
        """Rewards (n, S, A) of points ``x`` (n, d)."""
        W = self.weights(x)
        S, A = self.mdp.n_states, self.mdp.n_actions
        return np.asarray(as_basis(self.features, S, A).rewards(W)).reshape(-1, S, A)

    def mean_rewards(self) -> NDArray[np.float64]:
        """The rewards (S, A) of the posterior mean."""
        return self.rewards(self.mean[None])[0]

    def sample(self, n: int, rng: Any = None) -> NDArray[np.float64]:
        """``n`` draws of ``x`` (n, d) from the Gaussian."""
        n = check_int(n, "n", minimum=1)
        L = _cholesky(self.covariance)
        z = as_rng(rng).standard_normal((n, self.mean.shape[0]))
        return self.mean + z @ L.T

    def sample_rewards(self, n: int, rng: Any = None) -> NDArray[np.float64]:
        """``n`` rewards (n, S, A) drawn from the posterior, in the layout of one task of ``transfer_rewards_``."""
        return self.rewards(self.sample(n, rng))

    def sample_regrets(self, n: int, rng: Any = None, planner: str = "auto") -> NDArray[np.float64]:
        """Regret (n,) of acting greedily on the mean reward, under ``n`` rewards drawn from the posterior.

        For each sampled reward ``R_j``: ``mean_s V*_{R_j}(s) - mean_s V^{pi_m}_{R_j}(s)`` with
        ``pi_m`` greedy on the ``Q*`` of the mean reward, the units of :func:`factirl_opt.deviation`
        (``deviation(mdp, R_j, mean_rewards())``). The samples are planned as one batch. Its
        mean is the posterior expected regret, its 0.9 quantile the 90% upper bound.
        """
        R = self.sample_rewards(n, rng)
        pl = get_planner(self.mdp, planner)
        best = plan(pl, R).V.mean(axis=1)
        pol = plan(pl, self.mean_rewards()[None]).policy
        pols = np.repeat(pol, len(R), axis=0)
        R_pi = np.take_along_axis(R, pols[:, :, None], axis=2)[:, :, 0]
        acted = pl.system(pols).solve(R_pi).mean(axis=1)
        return np.maximum(best - acted, 0.0)

    def basis(self) -> NDArray[np.float64]:
        """``dR/dx`` (S*A, d): ``Phi [D, I]`` (``Phi D`` without residual)."""
        return _basis(self.features, self.dictionary, self.has_residual, self.mdp)


def _basis(features, D, residual, mdp):
    """``Phi [D, I]`` (S*A, d) of a task's features (None: tabular) on ``mdp`` (``Phi D`` without residual)."""
    base = as_basis(features, mdp.n_states, mdp.n_actions)
    B = base.compose(D).jacobian_features()
    if residual:
        B = np.concatenate([B, base.jacobian_features()], axis=1)
    return np.ascontiguousarray(B)


def _cholesky(C):
    C = 0.5 * (C + C.T)
    try:
        return np.linalg.cholesky(C)
    except np.linalg.LinAlgError:  # positive semidefinite to rounding: the symmetric square root
        vals, vecs = np.linalg.eigh(C)
        return vecs * np.sqrt(np.clip(vals, 0.0, None))


def likelihood_scaling(objective_name: str, n_pairs: ArrayLike, mu: Any = None, pi: Any = None) -> NDArray[np.float64]:
    """The scaling ``s`` that makes ``s J`` each task's negative log-likelihood (docs/maths.md §10).

    Parameters
    ----------
    objective_name : str
        ``"mce"``: ``s = N``; otherwise (policy matching) ``s = N / (2 sigma^2)`` with
        ``sigma^2 = sum_s mu(s) (1 - ||pi(.|s)||^2) / (A - 1)``, the multinomial variance per
        component of one visit's action indicator under the policy ``pi``, averaged over the
        demonstrated states.
    n_pairs : array_like, shape (n,)
        ``N``: demonstrated (state, action) pairs of each task.
    mu : sequence of n arrays (S_i,), optional
        Demonstrated state frequencies (policy matching).
    pi : sequence of n arrays (S_i, A), optional
        The policy the noise level is evaluated at (policy matching).

    Returns
    -------
    ndarray, shape (n,)
    """
    N = np.asarray(n_pairs, dtype=np.float64)
    if objective_name == "mce":
        return N
    sig = np.empty(len(N))
    for i in range(len(N)):
        p = np.asarray(pi[i])
        A = p.shape[1]
        sig[i] = float(np.sum(np.asarray(mu[i]) * (1.0 - np.sum(p * p, axis=1)))) / max(A - 1, 1)
    return N / (2.0 * np.maximum(sig, 1e-12))


@dataclasses.dataclass
class TransferProblem:
    """New tasks' objective and reward bases, as the posterior and the requests see them.

    Attributes
    ----------
    objective : Objective or MultiEnvironmentObjective
        Over the new tasks (not sharded).
    mdps : list of n TabularMDP
    features : list of n arrays (S_i*A, p) or None
        Each task's dense base features (None: tabular).
    dictionary : ndarray, shape (p, k)
    residual_penalty : float
        ``lambda``; np.inf: coefficients only.
    n_pairs : ndarray, shape (n,)
        Demonstrated pairs per task.
    """

    objective: Any
    mdps: list
    features: list
    dictionary: NDArray[np.float64]
    residual_penalty: float
    n_pairs: NDArray[np.float64]

    @property
    def residual(self) -> bool:
        return bool(np.isfinite(self.residual_penalty))

    @property
    def n_tasks(self) -> int:
        return len(self.mdps)

    def groups(self) -> list[tuple[Any, NDArray[np.intp], NDArray[np.intp]]]:
        """``(objective, tasks, local rows)`` per MDP group (one group for a one-MDP objective)."""
        return self.objective.environment_groups()

    def basis(self, task: int) -> NDArray[np.float64]:
        return _basis(self.features[task], self.dictionary, self.residual, self.mdps[task])

    def statistics(self, task: int) -> tuple[Any, NDArray[np.float64], NDArray[np.float64]]:
        """``(objective of the task's group, mu (S,), pi_hat (S, A))``."""
        for sub, tasks, local in self.groups():
            hit = np.flatnonzero(tasks == task)
            if hit.size:
                j = int(local[hit[0]])
                return sub, sub.mu[j], sub.pi_hat[j]
        raise ValidationError(f"task {task} is not one of the {self.n_tasks} new tasks")


def _shared(problem, tasks):
    """The one basis of these tasks when they share their features (None otherwise)."""
    first = problem.features[tasks[0]]
    return all(problem.features[t] is first for t in tasks)


def demonstration_curvature(problem: TransferProblem, x: ArrayLike,
                            tasks: ArrayLike | None = None) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Each task's demonstration loss ``J`` (r,), its gradient in ``x`` (r, d) and its curvature ``G`` (r, d, d).

    ``G`` is the Gauss-Newton matrix ``2 J_r^T J_r`` of policy matching (eq. 5 is ``||r||^2``), or
    the Fisher information of MCE (the Gauss-Newton part of :meth:`MCEObjective.hessian`); both
    equal the Hessian of ``J`` where the model's policy reproduces the demonstrations'
    statistics exactly.

    Parameters
    ----------
    problem : TransferProblem
    x : array_like, shape (r, d)
        ``[h, delta]`` of each task.
    tasks : array_like of int, shape (r,), optional
        Which tasks (default: all, r = n).
    """
    tasks = np.arange(problem.n_tasks) if tasks is None else np.asarray(tasks, dtype=np.intp)
    X = np.asarray(x, dtype=np.float64)
    k = problem.dictionary.shape[1]
    d = k + (problem.dictionary.shape[0] if problem.residual else 0)
    if X.shape != (len(tasks), d):
        raise ValidationError(f"x must have shape (r, d) = ({len(tasks)}, {d}); got {X.shape}")
    loss, grad, G, _ = _evaluate(problem, X, tasks, True)
    return loss, grad, G


def _evaluate(problem: TransferProblem, x: NDArray[np.float64], tasks: NDArray[np.intp], curvature: bool):
    """Loss (r,) and, if ``curvature``, the gradient in x (r, d), the curvature G (r, d, d) and each
    task's policy at x (list of (S_i, A) arrays, policy matching only) of ``tasks`` at points ``x`` (r, d)."""
    r, d = x.shape
    loss, grad = np.empty(r), np.empty((r, d))
    G = np.empty((r, d, d) if curvature else (0, d, d))
    pis: list = [None] * r
    where = {int(t): j for j, t in enumerate(tasks)}
    for sub, gtasks, glocal in problem.groups():
        sel = np.array([j for j, t in enumerate(gtasks) if int(t) in where], dtype=np.intp)
        if sel.size == 0:
            continue
        mdp = sub.mdp
        S, A = mdp.n_states, mdp.n_actions
        size = max(1, CHUNK_BYTES // (8 * S * A * d)) if curvature else len(sel)
        for lo in range(0, sel.size, size):
            part = sel[lo:lo + size]
            pos = np.array([where[int(gtasks[j])] for j in part], dtype=np.intp)
            local = glocal[part]
            ts = gtasks[part]
            if _shared(problem, ts):
                B = np.broadcast_to(problem.basis(int(ts[0])), (len(ts), S * A, d))
            else:
                B = np.stack([problem.basis(int(t)) for t in ts])
            R = np.einsum("rmd,rd->rm", B, x[pos]).reshape(len(ts), S, A)
            if sub.least_squares:  # eq. 5 is ||r||^2: loss, gradient 2 J_r^T r and curvature from one linearisation
                lin = sub.linearize(R, local)
                loss[pos] = lin.loss
                if not curvature:
                    continue
                Jr = lin.jvp(np.ascontiguousarray(B).reshape(len(ts), S, A, d))
                grad[pos] = 2.0 * np.einsum("rmd,rm->rd", Jr, lin.residual)
                G[pos] = 2.0 * np.einsum("rmd,rme->rde", Jr, Jr)
                mu = sub.mu[local]
                with np.errstate(divide="ignore", invalid="ignore"):
                    pi = sub.pi_hat[local] + lin.residual.reshape(len(ts), S, A) / np.sqrt(mu)[:, :, None]
                pi = np.where(mu[:, :, None] > 0, pi, 1.0 / A)
                for j, p in zip(pos, pi):
                    pis[j] = p
                continue
            lo_, y = sub.loss_and_grad(R, local)
            loss[pos], grad[pos] = lo_, np.einsum("rmd,rm->rd", B, y.reshape(len(ts), S * A))
            if curvature:
                G[pos] = sub.hessian(R, local, np.ascontiguousarray(B), kind="gauss-newton")
    return loss, grad, G, pis


def _prior_terms(x, k, m, P, s, lam):
    """Prior value (r,) and gradient (r, d) at x (r, d) on the likelihood's scale ``s`` (r,); its precision,
    ``blockdiag(P, 2 s lambda I)``, is :class:`_Curvature`'s."""
    r, d = x.shape
    dh = x[:, :k] - m
    val = 0.5 * np.einsum("rk,kl,rl->r", dh, P, dh)
    grad = np.zeros((r, d))
    grad[:, :k] = dh @ P
    if d > k:
        val = val + s * lam * np.sum(x[:, k:] ** 2, axis=1)
        grad[:, k:] = 2.0 * (s * lam)[:, None] * x[:, k:]
    return val, grad


def _block_inverse(Ch, cd, V):
    """``blockdiag(Ch, diag(cd))^-1 V`` for a batch: Ch (a, k, k), cd (a, p), V (a, k + p, q)."""
    k = Ch.shape[1]
    return np.concatenate([np.linalg.solve(Ch, V[:, :k]), V[:, k:] / cd[:, :, None]], axis=1)


def lowrank_solve(Ch: NDArray[np.float64], cd: NDArray[np.float64], Z: NDArray[np.float64],
                  b: NDArray[np.float64]) -> NDArray[np.float64]:
    """``(blockdiag(Ch, diag(cd)) + Z^T Z)^-1 b`` by the Woodbury identity, for a batch: never a (d, d) solve.

    ``C^-1 b - C^-1 Z^T (I + Z C^-1 Z^T)^-1 Z C^-1 b``, ``C = blockdiag(Ch, diag(cd))``: solves of
    size k and m only (the residual model's posterior: d = k + p, its ridge block diagonal, Z the
    m live rows of the scaled residuals' Jacobian, m << p).

    Parameters
    ----------
    Ch : ndarray, shape (a, k, k)
    cd : ndarray, shape (a, p)
        Positive.
    Z : ndarray, shape (a, m, d)
    b : ndarray, shape (a, d) or (a, d, q)

    Returns
    -------
    ndarray, the shape of ``b``
    """
    B = b[..., None] if b.ndim == 2 else b
    Y = _block_inverse(Ch, cd, np.swapaxes(Z, 1, 2))  # C^-1 Z^T (a, d, m)
    K = np.eye(Z.shape[1]) + Z @ Y
    u = _block_inverse(Ch, cd, B)
    out = u - Y @ np.linalg.solve(K, Z @ u)
    return out[..., 0] if b.ndim == 2 else out


class _Curvature:
    """The precision ``Lambda = s G + blockdiag(P, 2 s lambda I)`` of a batch of tasks, dense (``G`` (r, d, d))
    or low rank (``G = 2 Z^T Z``, ``Z`` (r, m, d) the live rows of the residuals' Jacobian; the residual
    model under policy matching): its products, its solves, and its damped solves (module docstring)."""

    def __init__(self, G, s, P, lam, k, lowrank):
        self.G, self.s, self.P, self.lam, self.k, self.lowrank = G, s, P, lam, k, lowrank

    def _factors(self, a, mu=None):
        """``(C_h, c_delta, Z)`` of the tasks ``a``, damped by ``mu`` (a,): ``Lambda + mu diag(Lambda)``."""
        k, s = self.k, self.s[a]
        Z = np.sqrt(2.0 * s)[:, None, None] * self.G[a]
        Ch = np.broadcast_to(self.P, (len(a), k, k)).copy()
        cd = np.broadcast_to((2.0 * s * self.lam)[:, None], (len(a), Z.shape[2] - k)).copy()
        if mu is not None:
            diag = np.einsum("rmd,rmd->rd", Z, Z)
            diag[:, :k] += np.diagonal(self.P)
            diag[:, k:] += cd
            Ch[:, np.arange(k), np.arange(k)] += mu[:, None] * diag[:, :k]
            cd = cd + mu[:, None] * diag[:, k:]
        return Ch, cd, Z

    def _dense(self, a):
        s, d = self.s[a], self.G.shape[-1]
        Lam = s[:, None, None] * self.G[a]
        Lam[:, :self.k, :self.k] += self.P
        if d > self.k:
            idx = np.arange(self.k, d)
            Lam[:, idx, idx] += 2.0 * (s * self.lam)[:, None]
        return Lam

    def solve(self, a, g, mu=None):
        """``(Lambda + mu diag(Lambda))^-1 g`` (r, d) for the tasks ``a`` (mu None: undamped)."""
        if self.lowrank:
            return lowrank_solve(*self._factors(a, mu), g)
        Lam = self._dense(a)
        if mu is not None:
            diag = np.einsum("rdd->rd", Lam)
            Lam = Lam + mu[:, None, None] * np.einsum("rd,de->rde", diag, np.eye(Lam.shape[1]))
        return np.linalg.solve(Lam, g[:, :, None])[:, :, 0]

    def apply(self, a, v):
        """``Lambda v`` (r, d) for the tasks ``a``."""
        if not self.lowrank:
            return np.einsum("rde,re->rd", self._dense(a), v)
        Ch, cd, Z = self._factors(a)
        out = np.einsum("rmd,rm->rd", Z, np.einsum("rmd,rd->rm", Z, v))
        out[:, :self.k] += v[:, :self.k] @ self.P.T
        out[:, self.k:] += cd * v[:, self.k:]
        return out

    def covariance(self, i):
        """``Lambda^-1`` (d, d) of task ``i``."""
        a = np.array([i])
        if self.lowrank:
            C = lowrank_solve(*self._factors(a), np.eye(self.G.shape[2])[None])[0]
        else:
            Lam = self._dense(a)[0]
            C = np.linalg.inv(0.5 * (Lam + Lam.T))
        return 0.5 * (C + C.T)


def laplace_posteriors(problem: TransferProblem, prior: tuple[NDArray[np.float64], NDArray[np.float64]],
                       start: NDArray[np.float64] | None = None, lowrank: bool | None = None) -> list[LaplacePosterior]:
    """Each new task's Laplace posterior: MAP by damped Newton steps, covariance the inverse curvature there.

    Parameters
    ----------
    problem : TransferProblem
    prior : (mean (k,), precision (k, k))
        :func:`~factirl_opt.learners.transfer.coefficient_prior` of the training tasks' coefficients.
    start : ndarray, shape (n, d), optional
        Another start (e.g. the transfer's values): each task starts from whichever of it and
        the prior mean (zero residual) has the lower posterior objective.
    lowrank : bool, optional
        Carry the residual model's curvature as its ridge block plus the live rows of the
        residuals' Jacobian, ``G = 2 Z^T Z`` with ``Z`` (m, k + p) and m the demonstrated rows
        (reverse-mode Jacobians, Woodbury solves of size m; no (k + p, k + p) solve), instead of
        dense. The same results to round-off. Default: for a residual model under a least-squares
        objective (policy matching), where it applies.

    Returns
    -------
    list of n LaplacePosterior
    """
    m, P = prior
    D = problem.dictionary
    k = D.shape[1]
    n = problem.n_tasks
    lam = problem.residual_penalty if problem.residual else 0.0
    d = k + (D.shape[0] if problem.residual else 0)
    applies = problem.residual and problem.objective.least_squares
    if lowrank is None:
        lowrank = applies
    elif lowrank and not applies:
        raise ValidationError("lowrank needs a residual model (a finite residual_penalty) and a least-squares objective")
    evaluate = _evaluate_lowrank if lowrank else _evaluate
    tasks = np.arange(n)
    x = np.zeros((n, d))
    x[:, :k] = m
    loss, grad, G, pis = evaluate(problem, x, tasks, True)
    # the likelihood's scaling: policy matching's noise level at the prior mean's policy
    if problem.objective.least_squares:
        mus = [problem.statistics(int(t))[1] for t in tasks]
        s = likelihood_scaling("policy-matching", problem.n_pairs, mus, pis)
    else:
        s = likelihood_scaling("mce", problem.n_pairs)
    if start is not None:
        x1 = np.asarray(start, dtype=np.float64)
        l1, g1, G1, _ = evaluate(problem, x1, tasks, True)
        better = s * l1 + _prior_terms(x1, k, m, P, s, lam)[0] < s * loss + _prior_terms(x, k, m, P, s, lam)[0]
        G = _pad_rows(G, G1) if lowrank else G
        G1 = _pad_rows(G1, G) if lowrank else G1
        x[better], loss[better], grad[better], G[better] = x1[better], l1[better], g1[better], G1[better]
    f = s * loss + _prior_terms(x, k, m, P, s, lam)[0]
    # Levenberg-Marquardt steps: (Lambda + mu diag(Lambda)) dx = -g, mu per task, shrunk after a
    # step that decreases the objective as the quadratic model predicts, grown after one that does not
    mu = np.full(n, MAP_DAMPING)
    active = np.ones(n, dtype=bool)
    for _ in range(MAP_MAX_ITER):
        a = np.flatnonzero(active)
        if a.size == 0:
            break
        curv = _Curvature(G, s, P, lam, k, lowrank)
        _, pg = _prior_terms(x[a], k, m, P, s[a], lam)
        g = s[a, None] * grad[a] + pg
        dec = np.einsum("rd,rd->r", g, curv.solve(a, g))
        done = (dec <= MAP_TOL) | (mu[a] > MAP_MAX_DAMPING)
        active[a[done]] = False
        a, g = a[~done], g[~done]
        if a.size == 0:
            break
        step = -curv.solve(a, g, mu[a])
        predicted = -(np.einsum("rd,rd->r", g, step) + 0.5 * np.einsum("rd,rd->r", step, curv.apply(a, step)))
        xt = x[a] + step
        # the trial point's curvature with its loss: one linearisation per step, kept if the step is
        lt, gt, Gt, _ = evaluate(problem, xt, a, True)
        ft = s[a] * lt + _prior_terms(xt, k, m, P, s[a], lam)[0]
        ok = np.isfinite(ft) & (f[a] - ft >= 1e-4 * predicted)
        acc = a[ok]
        if lowrank:
            G, Gt = _pad_rows(G, Gt), _pad_rows(Gt, G)
        x[acc], f[acc] = xt[ok], ft[ok]
        loss[acc], grad[acc], G[acc] = lt[ok], gt[ok], Gt[ok]
        mu[acc] /= 3.0
        mu[a[~ok]] *= 10.0
    curv = _Curvature(G, s, P, lam, k, lowrank)
    out = []
    for i in range(n):
        out.append(LaplacePosterior(x[i].copy(), curv.covariance(i), D, problem.features[i], problem.mdps[i], float(s[i]),
                                    float(problem.n_pairs[i])))
    return out


def _pad_rows(Z, other):
    """``Z`` (r, m, d) with zero rows appended up to ``other``'s m (a no-op when it has as many)."""
    extra = other.shape[1] - Z.shape[1]
    if extra <= 0:
        return Z
    return np.concatenate([Z, np.zeros((Z.shape[0], extra, Z.shape[2]))], axis=1)


def _evaluate_lowrank(problem: TransferProblem, x: NDArray[np.float64], tasks: NDArray[np.intp], curvature: bool = True):
    """:func:`_evaluate` of a residual model under a least-squares objective with the curvature as its factor:
    loss (r,), gradient (r, d), ``Z`` (r, m, d) the live rows of the residuals' Jacobian in x (``G = 2 Z^T Z``;
    zero rows pad the tasks with fewer), and each task's policy at x.

    The Jacobian with respect to the reward weights ``w`` comes from the objective's
    ``residual_jacobian`` (reverse mode: one adjoint right-hand side per demonstrated row), then
    ``[J D, J]`` on its live rows only: no (S*A, k + p) tangent and no (d, d) product.
    """
    r, d = x.shape
    D = problem.dictionary
    k = D.shape[1]
    loss, grad = np.empty(r), np.empty((r, d))
    factors: list = [None] * r
    pis: list = [None] * r
    where = {int(t): j for j, t in enumerate(tasks)}
    W = x[:, :k] @ D.T + x[:, k:]  # (r, p)
    for sub, gtasks, glocal in problem.groups():
        sel = np.array([j for j, t in enumerate(gtasks) if int(t) in where], dtype=np.intp)
        if sel.size == 0:
            continue
        S, A = sub.mdp.n_states, sub.mdp.n_actions
        ts = gtasks[sel]
        shared = _shared(problem, ts)
        batches = [sel] if shared else [sel[i:i + 1] for i in range(sel.size)]
        for part in batches:
            pos = np.array([where[int(gtasks[j])] for j in part], dtype=np.intp)
            feats = problem.features[int(gtasks[part[0]])]
            F = np.eye(S * A) if feats is None else np.asarray(feats, dtype=np.float64)
            R = (W[pos] @ F.T).reshape(len(pos), S, A)
            lo, res, J = sub.residual_jacobian(R, glocal[part], F)
            loss[pos] = lo
            for j, q in enumerate(pos):
                live = np.flatnonzero(np.any(J[j] != 0.0, axis=1))
                Jl = J[j][live]
                Z = np.concatenate([Jl @ D, Jl], axis=1)
                grad[q] = 2.0 * Z.T @ res[j][live]
                factors[q] = Z
            mu = sub.mu[glocal[part]]
            with np.errstate(divide="ignore", invalid="ignore"):
                pi = sub.pi_hat[glocal[part]] + res.reshape(len(pos), S, A) / np.sqrt(mu)[:, :, None]
            pi = np.where(mu[:, :, None] > 0, pi, 1.0 / A)
            for q, p_ in zip(pos, pi):
                pis[q] = p_
    m = max(1, max(z.shape[0] for z in factors))
    Z = np.zeros((r, m, d))
    for q, z in enumerate(factors):
        Z[q, :z.shape[0]] = z
    return loss, grad, Z, pis


def transfer_problem(model: Any, mdp: Any, demos_per_task: Any, features: Any = None) -> TransferProblem:
    """The :class:`TransferProblem` of new tasks for a fitted :class:`FactIRL` (as ``transfer`` sets them up).

    Raises
    ------
    NotFittedError
        The model has no dictionary.
    ValidationError
        As ``FactIRL.transfer`` does for these arguments.
    """

    if not hasattr(model, "dictionary_"):
        raise NotFittedError("this FactIRL has no dictionary_: call fit first")
    return tasks_problem(model, *transfer_tasks(mdp, demos_per_task, features, model))


def tasks_problem(model: Any, tasks: Any, D: Any) -> TransferProblem:
    """The :class:`TransferProblem` of a transfer's task set ``tasks`` and dictionary ``D`` (p, k)."""
    from ..tasks.trajectories import task_steps
    from .fitting import task_objective

    obj = task_objective(tasks, model.beta, model.objective, model._group("execution").planner)
    lam = float(getattr(model, "residual_penalty_", np.inf))
    rows = np.arange(tasks.n_tasks)
    one = tasks.mdp
    mdps = list(tasks.mdps or []) if one is None else [one] * tasks.n_tasks
    feats = tasks.basis.recorded_features(rows)
    demos = tasks.demos_per_task
    n_pairs = np.array([task_steps(mdps[i], demos[i], i).shape[0] for i in range(len(mdps))], dtype=np.float64)
    return TransferProblem(obj, mdps, feats, np.asarray(D, dtype=np.float64), lam, n_pairs)


def transfer_posterior(model: Any, mdp: Any, demos_per_task: Any, features: Any = None) -> list[LaplacePosterior] | None:
    """``FactIRL.transfer_posterior_``: each new task's :class:`LaplacePosterior` after ``transfer``.

    Started from the transfer's values (``transfer_coefficients_``, ``transfer_residuals_``).
    None when the posterior is undefined: a model with fewer than 2 training tasks'
    ``coefficients_`` (no prior to fit) or the flat model (``residual_penalty_ = 0``, whose
    coefficients the demonstrations do not determine).
    """
    if not has_prior(model):
        return None
    return _posterior_of(model, transfer_problem(model, mdp, demos_per_task, features))


def has_prior(model: Any) -> bool:
    """Whether the model's coefficient prior is defined: 2 or more training tasks, and not the flat model."""
    H = getattr(model, "coefficients_", None)
    return H is not None and np.shape(H)[0] >= 2 and float(getattr(model, "residual_penalty_", np.inf)) != 0.0


def _posterior_of(model: Any, problem: TransferProblem) -> list[LaplacePosterior]:
    start = np.asarray(model.transfer_coefficients_, dtype=np.float64)
    if problem.residual:
        start = np.concatenate([start, np.asarray(model.transfer_residuals_, dtype=np.float64)], axis=1)
    return laplace_posteriors(problem, coefficient_prior(model.coefficients_), start)


@dataclasses.dataclass(eq=False)
class TransferState:
    """What an estimator keeps of its last ``transfer`` (its private ``_transfer``): it pickles with
    the estimator and a refit drops it.

    Attributes
    ----------
    inputs : tuple (mdp, demos_per_task, features) or None
        The arguments of the transfer (:func:`factirl_opt.learners.active.request_starts` reuses
        the posterior when it is given the same objects); None for a loaded posterior.
    tasks : TaskSet or None
        The transfer's tasks, from which the posterior is built when first read (it costs about
        one transfer, which a transfer that nobody asks the posterior of does not pay).
    dictionary : ndarray, shape (p, k), or None
    posterior : list of LaplacePosterior or None
        Once built or loaded (``built`` tells which None it is).
    """

    inputs: tuple | None = None
    tasks: Any = None
    dictionary: Any = None
    posterior: list[LaplacePosterior] | None = None
    built: bool = False


def keep_transfer(model: Any, inputs: tuple, tasks: Any, D: Any) -> None:
    """Record on ``model`` the task set of its last transfer (its posterior is built from it when first read)."""
    model._transfer = TransferState(inputs, tasks, D)


def transfer_inputs(model: Any) -> tuple | None:
    """The ``(mdp, demos_per_task, features)`` of ``model``'s last transfer, or None."""
    state = vars(model).get("_transfer")
    return None if state is None else state.inputs


def has_transfer_posterior(model: Any) -> bool:
    """Whether ``model.transfer_posterior_`` is defined (built, loaded, or buildable from a transfer)."""
    return vars(model).get("_transfer") is not None


def cached_transfer_posterior(model: Any) -> list[LaplacePosterior] | None:
    """``model.transfer_posterior_``: built from the last transfer's task set on first use, then kept.

    Raises
    ------
    AttributeError
        The model has transferred no tasks since its last fit (and loaded no posterior).
    """
    state = vars(model).get("_transfer")
    if state is None:
        raise AttributeError("transfer_posterior_: this FactIRL has transferred no tasks since its fit; call transfer first")
    if not state.built:
        state.posterior = _posterior_of(model, tasks_problem(model, state.tasks, state.dictionary)) if has_prior(model) else None
        state.built = True
    return state.posterior


def set_transfer_posterior(model: Any, posteriors: list[LaplacePosterior] | None) -> None:
    """Give ``model`` these posteriors as its ``transfer_posterior_`` (``load_model``)."""
    model._transfer = TransferState(posterior=posteriors, built=True)


#: the prior-scale fitting moved beside the transfer's prior (:mod:`~factirl_opt.learners.transfer`); resolved here for one release
moved_names(__name__, dict.fromkeys(("fit_prior_scale", "choose_prior_scale", "leave_one_out_priors", "PRIOR_SCALES",
                                     "PRIOR_HELD_OUT", "PRIOR_RIDGE"), "factirl_opt.learners.transfer"))
