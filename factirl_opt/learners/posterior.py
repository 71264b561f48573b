"""The Laplace posterior of a transferred task: how sure its reward is (docs/maths.md §10).

A new task transferred with the dictionary ``D`` fixed has ``k`` coefficients ``h`` (and, with a
finite ``residual_penalty`` ``lambda``, a residual ``delta`` of ``p`` weights): its reward weights
are ``w = D h + delta`` and its rewards ``R = Phi w``. With ``x = [h, delta]`` (d = k, or k + p)
and the task's demonstration loss ``J(x)`` (eq. 5 or the MCE likelihood), the posterior is

    -log p(x | demos) = s J(x) + 1/2 (h - m)^T P (h - m) + s lambda ||delta||^2 + const,

- ``s`` the likelihood's scaling (:func:`~factirl_opt.learners.transfer_likelihood.likelihood_scaling`): ``N`` for MCE (``J`` is the mean
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
from .._validation import as_rng, check_bool, check_int
from ..exceptions import ValidationError
from ..mdp.tabular import TabularMDP
from ..planning import get_planner, plan
from ..planning.engine import greedy_values
from ..tasks.basis import as_basis
from .noise_levels import noise_ratios, noise_reference
from .transfer import coefficient_prior
from .transfer_likelihood import (TransferProblem, _basis, _evaluate, _evaluate_lowrank, _pad_rows, likelihood_scaling,
                                  repeated_problem, tasks_problem, transfer_problem)

__all__ = ["LaplacePosterior", "laplace_posteriors", "transfer_posterior", "cached_transfer_posterior", "keep_transfer",
           "TransferState", "has_prior", "model_posteriors", "member_posteriors",
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
#: (member, task) pairs of a dictionary ensemble's posteriors iterated together at most (:func:`member_posteriors`:
#: whole members per batch, at least one); larger batches save the per-call overhead of few tasks but no
#: planning, and cost more than they save beyond about this many
MEMBER_BATCH_ROWS = 64


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
        The likelihood's scaling ``s`` (:func:`~factirl_opt.learners.transfer_likelihood.likelihood_scaling`).
    n_pairs : float
        ``N``, the demonstrated pairs the posterior is conditioned on (``scaling / n_pairs`` is
        the likelihood's weight of one demonstrated pair).
    members : tuple of LaplacePosterior, default=()
        The same task's posteriors under the other dictionaries of the model's dictionary
        ensemble (``FactIRL(posterior=PosteriorSettings(n_dictionaries=B))``, :mod:`~factirl_opt.learners.dictionary_ensemble`),
        each in its own dictionary's coordinates. :meth:`sample_rewards` and
        :meth:`sample_regrets` marginalise over the ``1 + B`` dictionaries (an equal-weight
        mixture, docs/maths.md §10); ``mean`` and ``covariance`` stay this dictionary's
        (conditional) ones. Empty: the conditional posterior.

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
    members: tuple = ()

    @property
    def n_dictionaries(self) -> int:
        """The dictionaries the posterior marginalises over: its own, and one per member."""
        return 1 + len(self.members)

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

    def member_counts(self, n: int) -> list[int]:
        """How many of ``n`` marginal draws each dictionary gives: ``n`` split evenly over the
        ``1 + len(members)`` dictionaries, the remainder to the first ones (stratified)."""
        n = check_int(n, "n", minimum=1)
        base, extra = divmod(n, self.n_dictionaries)
        return [base + (j < extra) for j in range(self.n_dictionaries)]

    def sample_rewards(self, n: int, rng: Any = None, *, marginal: bool = True) -> NDArray[np.float64]:
        """``n`` rewards (n, S, A) drawn from the posterior, in the layout of one task of ``transfer_rewards_``.

        Parameters
        ----------
        n : int
        rng : numpy.random.Generator or int or None
        marginal : bool, default=True
            Marginalise over the dictionary ensemble (``members``): ``R = Phi (D_b h + delta)``
            with ``b`` the dictionary and ``[h, delta] ~ N(x_b, Lambda_b^-1)`` its posterior,
            :meth:`member_counts` draws from each ``b`` in turn (own dictionary first), one
            generator for all. False: this dictionary's (conditional) posterior only. Without
            members both are the same draws.

        Returns
        -------
        ndarray, shape (n, S, A)
        """
        check_bool(marginal, "marginal")
        if not marginal or not self.members:
            return self.rewards(self.sample(n, rng))
        gen = as_rng(rng)
        posts = (self, *self.members)
        return np.concatenate([posts[b].rewards(posts[b].sample(c, gen))
                               for b, c in enumerate(self.member_counts(n)) if c > 0])

    def sample_regrets(self, n: int, rng: Any = None, planner: str = "auto", *, marginal: bool = True) -> NDArray[np.float64]:
        """Regret (n,) of acting greedily on the mean reward, under ``n`` rewards drawn from the posterior.

        For each sampled reward ``R_j`` (:meth:`sample_rewards`, marginal over the dictionary
        ensemble unless ``marginal=False``): ``mean_s V*_{R_j}(s) - mean_s V^{pi_m}_{R_j}(s)`` with
        ``pi_m`` greedy on the ``Q*`` of this posterior's mean reward (the one ``transfer_posterior_``
        acts on), the units of :func:`factirl_opt.deviation` (``deviation(mdp, R_j, mean_rewards())``).
        The samples are planned as one batch. Its mean is the posterior expected regret, its 0.9
        quantile the 90% upper bound.
        """
        R = self.sample_rewards(n, rng, marginal=marginal)
        pl = get_planner(self.mdp, planner)
        best = plan(pl, R).V.mean(axis=1)
        pols = np.repeat(plan(pl, self.mean_rewards()[None]).policy, len(R), axis=0)
        acted = greedy_values(pl, R, pols)[0].mean(axis=1)
        return np.maximum(best - acted, 0.0)

    def basis(self) -> NDArray[np.float64]:
        """``dR/dx`` (S*A, d): ``Phi [D, I]`` (``Phi D`` without residual)."""
        return _basis(self.features, self.dictionary, self.has_residual, self.mdp)


def _cholesky(C):
    C = 0.5 * (C + C.T)
    try:
        return np.linalg.cholesky(C)
    except np.linalg.LinAlgError:  # positive semidefinite to rounding: the symmetric square root
        vals, vecs = np.linalg.eigh(C)
        return vecs * np.sqrt(np.clip(vals, 0.0, None))


def _prior_terms(x, k, m, P, s, lam):
    """Prior value (r,) and gradient (r, d) at x (r, d) on the likelihood's scale ``s`` (r,), each row with its
    own prior mean ``m`` (r, k) and precision ``P`` (r, k, k); its precision, ``blockdiag(P, 2 s lambda I)``,
    is :class:`_Curvature`'s."""
    r, d = x.shape
    dh = x[:, :k] - m
    val = 0.5 * np.einsum("rk,rkl,rl->r", dh, P, dh)
    grad = np.zeros((r, d))
    grad[:, :k] = np.einsum("rk,rkl->rl", dh, P)
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
    model under policy matching), each task with its own prior precision ``P`` (n, k, k): its products, its
    solves, and its damped solves (module docstring)."""

    def __init__(self, G, s, P, lam, k, lowrank):
        self.G, self.s, self.P, self.lam, self.k, self.lowrank = G, s, P, lam, k, lowrank

    def _factors(self, a, mu=None):
        """``(C_h, c_delta, Z)`` of the tasks ``a``, damped by ``mu`` (a,): ``Lambda + mu diag(Lambda)``."""
        k, s = self.k, self.s[a]
        Z = np.sqrt(2.0 * s)[:, None, None] * self.G[a]
        Ch = self.P[a].copy()
        cd = np.broadcast_to((2.0 * s * self.lam)[:, None], (len(a), Z.shape[2] - k)).copy()
        if mu is not None:
            diag = np.einsum("rmd,rmd->rd", Z, Z)
            diag[:, :k] += np.diagonal(self.P[a], axis1=1, axis2=2)
            diag[:, k:] += cd
            Ch[:, np.arange(k), np.arange(k)] += mu[:, None] * diag[:, :k]
            cd = cd + mu[:, None] * diag[:, k:]
        return Ch, cd, Z

    def _dense(self, a):
        s, d = self.s[a], self.G.shape[-1]
        Lam = s[:, None, None] * self.G[a]
        Lam[:, :self.k, :self.k] += self.P[a]
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
        out[:, :self.k] += np.einsum("rkl,rl->rk", self.P[a], v[:, :self.k])
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
                       start: NDArray[np.float64] | None = None, lowrank: bool | None = None,
                       noise_reference: float | None = None) -> list[LaplacePosterior]:
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
    noise_reference : float, optional
        The training tasks' noise level (the median of ``FactIRL.noise_levels_``). Given, each
        task's noise level is scaled by its own misfit at the MAP (policy matching only):
        ``sigma_i^2 <- sigma_i^2 rho_i`` with ``rho_i = max(shat_i^2 / noise_reference, NOISE_RATIO_MIN)``
        and ``shat_i^2`` its :func:`~factirl_opt.learners.noise_levels.misfit_noise_levels` (``d = k``), i.e. ``s_i <- s_i / rho_i``,
        and the covariance is formed at that scale (the mean stays the MAP at the multinomial
        scale): a demonstration the dictionary explains worse than it explains the training
        tasks widens its posterior. None: the multinomial noise level alone.

    Returns
    -------
    list of n LaplacePosterior
    """
    m, P = (np.asarray(v, dtype=np.float64) for v in prior)
    n = problem.n_tasks
    return _laplace_rows(problem, np.broadcast_to(m, (n, *m.shape)), np.broadcast_to(P, (n, *P.shape)), start, lowrank,
                         noise_reference)


def _laplace_rows(problem, m, P, start=None, lowrank=None, noise_reference=None):
    """:func:`laplace_posteriors` with a prior per task: means ``m`` (n, k), precisions ``P`` (n, k, k)."""
    D = problem.dictionary
    k = D.shape[1]
    n = problem.n_tasks
    if noise_reference is not None:
        if not problem.objective.least_squares:
            raise ValidationError("noise_reference scales a least-squares likelihood (policy matching); this objective "
                                  "has no noise level to scale")
        if not (np.isfinite(noise_reference) and noise_reference > 0):
            raise ValidationError(f"noise_reference must be a finite positive float; got {noise_reference!r}")
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
        _, pg = _prior_terms(x[a], k, m[a], P[a], s[a], lam)
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
        ft = s[a] * lt + _prior_terms(xt, k, m[a], P[a], s[a], lam)[0]
        ok = np.isfinite(ft) & (f[a] - ft >= 1e-4 * predicted)
        acc = a[ok]
        if lowrank:
            G, Gt = _pad_rows(G, Gt), _pad_rows(Gt, G)
        x[acc], f[acc] = xt[ok], ft[ok]
        loss[acc], grad[acc], G[acc] = lt[ok], gt[ok], Gt[ok]
        mu[acc] /= 3.0
        mu[a[~ok]] *= 10.0
    if noise_reference is not None:
        s = s / noise_ratios(problem, loss, k, float(noise_reference))
    curv = _Curvature(G, s, P, lam, k, lowrank)
    out = []
    for i in range(n):
        out.append(LaplacePosterior(x[i].copy(), curv.covariance(i), problem.dictionary_of(i), problem.features[i],
                                    problem.mdps[i], float(s[i]), float(problem.n_pairs[i])))
    return out


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
    return model_posteriors(model, problem, start)


def model_posteriors(model: Any, problem: TransferProblem, start: NDArray[np.float64] | None = None) -> list[LaplacePosterior]:
    """The posteriors of ``problem``'s tasks under a fitted model's prior and settings (:func:`has_prior` holds).

    :func:`laplace_posteriors` with the prior of ``coefficients_``, the noise reference of
    ``posterior.noise`` and, for a model with a ``dictionary_ensemble_``, each task's posteriors
    under the other dictionaries as its ``members``
    (:func:`~factirl_opt.learners.dictionary_ensemble.member_posteriors`).
    """
    reference = noise_reference(model)
    posts = laplace_posteriors(problem, coefficient_prior(model.coefficients_), start, noise_reference=reference)
    return member_posteriors(model, problem, posts, reference)


def member_posteriors(model: Any, problem: TransferProblem, posts: list[LaplacePosterior],
                      reference: float | None = None, *, batched: bool = True) -> list[LaplacePosterior]:
    """Attach to each of ``posts`` its posteriors under the model's ``dictionary_ensemble_`` (``members``); returns ``posts``.

    Each member ``b`` is :func:`~factirl_opt.learners.posterior.laplace_posteriors` of the same
    tasks with ``D_b`` and the prior ``(m_b, P_b)``, started from the better of its prior mean
    and the least-squares coefficients of the conditional posterior's mean weights on ``D_b``
    (the residual kept), with the same ``noise_reference``. A model without an ensemble leaves
    ``posts`` as they are.

    Parameters
    ----------
    batched : bool, default=True
        Run the ``B`` members' damped Newton iterations together, over the ``B n`` (member, task)
        pairs of one problem (:func:`~factirl_opt.learners.transfer_likelihood.repeated_problem`:
        one planner call per step for every member), each pair with its own prior, start,
        damping and stopping: the same iterations as one member at a time (False), to round-off.
        Used where ``problem`` has its task set (:func:`~factirl_opt.learners.transfer_likelihood.tasks_problem`).
    """
    batched = check_bool(batched, "batched")
    Ds = getattr(model, "dictionary_ensemble_", None)
    if Ds is None or len(Ds) == 0 or not posts:
        return posts
    k = problem.dictionary.shape[1]
    n = problem.n_tasks
    X = np.stack([p.mean for p in posts])
    W = X[:, :k] @ problem.dictionary.T
    means, precisions = model.ensemble_prior_means_, model.ensemble_prior_precisions_
    starts = [np.concatenate([np.linalg.lstsq(D, W.T, rcond=None)[0].T, X[:, k:]], axis=1) for D in Ds]
    if batched and problem.tasks is not None:
        members = []
        size = max(1, MEMBER_BATCH_ROWS // n)
        for lo in range(0, len(Ds), size):
            group = range(lo, min(lo + size, len(Ds)))
            stacked = repeated_problem(model, problem, [Ds[b] for b in group])
            m = np.repeat(np.asarray([means[b] for b in group], dtype=np.float64), n, axis=0)
            P = np.repeat(np.asarray([precisions[b] for b in group], dtype=np.float64), n, axis=0)
            flat = _laplace_rows(stacked, m, P, np.concatenate([starts[b] for b in group]), noise_reference=reference)
            members += [flat[j * n:(j + 1) * n] for j in range(len(group))]
    else:
        members = [laplace_posteriors(dataclasses.replace(problem, dictionary=np.asarray(D)), (mb, Pb), start,
                                      noise_reference=reference)
                   for D, mb, Pb, start in zip(Ds, means, precisions, starts)]
    for i, p in enumerate(posts):
        p.members = tuple(mp[i] for mp in members)
    return posts


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


def keep_transfer(model: Any, inputs: tuple | None, tasks: Any, D: Any) -> None:
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


#: names that moved beside the transfer's prior (:mod:`~factirl_opt.learners.transfer`) and its likelihood
#: (:mod:`~factirl_opt.learners.transfer_likelihood`), resolved here for one release
moved_names(__name__, dict.fromkeys(("fit_prior_scale", "choose_prior_scale", "leave_one_out_priors", "PRIOR_SCALES",
                                     "PRIOR_HELD_OUT", "PRIOR_RIDGE"), "factirl_opt.learners.transfer"))
moved_names(__name__, dict.fromkeys(("demonstration_curvature", "CHUNK_BYTES"), "factirl_opt.learners.transfer_likelihood"))
