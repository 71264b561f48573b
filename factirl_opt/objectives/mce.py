"""The maximum causal entropy likelihood: soft values, the loss and its adjoint gradient.

Infinite-horizon, discounted maximum causal entropy IRL (Ziebart et al. 2008, 2010), fitted by
maximum likelihood of the demonstrated pairs (MLIRL, Babes-Vroman et al. 2011; docs/maths.md
§6). Batched over tasks on the leading axis, rewards ``R`` (n, S, A):

- soft Bellman equation ``Q = R + gamma P V``, ``V(s) = (1/beta) log sum_a exp(beta Q(s, a))``
  (the fixed point ``V = T V`` of the soft Bellman operator ``T``), soft-optimal policy
  ``pi(a|s) = exp(beta (Q(s, a) - V(s)))``; ``log pi`` is computed as ``beta (Q - V)`` with the
  maximum over actions subtracted first (log-sum-exp), never as ``log(exp(.))``;
- loss per task, the mean negative log-likelihood of the demonstrated (state, action) pairs,
  ``J = -sum_{s,a} c(s, a) log pi(a|s)`` with pair frequencies ``c(s, a) = mu_hat(s) pi_hat(a|s)``.

Soft values by Newton's method (soft policy iteration). ``T`` is differentiable with
``dT/dV = gamma P_pi``, where ``P_pi[s, s'] = sum_a pi(a|s) P(s'|s, a)`` and ``pi`` is the
soft-greedy policy of ``V`` (the gradient of log-sum-exp is the softmax). The Newton step on
``F(V) = V - T V = 0`` is ``(I - gamma P_pi)(V_new - V) = T V - V``. Since
``T V = sum_a pi (Q - (1/beta) log pi)`` (average ``Q - (1/beta) log pi = T V`` over ``pi``),
``T V - gamma P_pi V = sum_a pi (R - (1/beta) log pi)``, and the step reads

    (I - gamma P_pi) V_new = sum_a pi(a|s) (R(s, a) - (1/beta) log pi(a|s)),

i.e. ``V_new`` is the soft value (reward plus entropy bonus) of the policy ``pi``: one solve
with the stochastic policy's system per step (:meth:`factirl_opt.planning.Planner.system`).
The soft value of any policy is a sub-solution (``T V >= V``) below ``V*``, and from a
sub-solution the iterates rise monotonically to ``V*`` with the error contracting at least by
``gamma`` per step (quadratically near the solution): from a cold or warm start, 2-12 steps on
the 10x10 grid at gamma 0.9 and 0.99, beta up to 1e3, rewards up to 1e3. The residual
``||T V - V||`` is *not* monotone along these iterates (guarding on its decrease, measured,
replaced up to 4800 Newton steps by value-iteration sweeps and took 20x more iterations at
gamma 0.99), so the guard checks what Newton guarantees instead: the new iterate must be
finite, a sub-solution (``T V_new >= V_new - eps``), and, when the current iterate is one,
not below it (``V_new >= V - eps``), with ``eps = 1e-9 max(1, ||V||_inf)``. A task whose step
fails these (a failed solve) takes the value-iteration sweep ``V <- T V`` instead, which keeps
a sub-solution one and contracts the error by ``gamma``. Stop when
``||T V - V||_inf <= 1e-12 max(1, ||V||_inf)`` per task; warm-started from the last values.

Gradient by one adjoint solve per task. With ``g = dlogL/dQ = beta (c - c(s) pi)``
(``c(s) = sum_a c(s, a)``) and ``dV(s) = sum_a pi(a|s) dQ(s, a)`` on the soft Bellman equation,
``dQ = (I - gamma P Pi)^-1 dR``, so ``dlogL/dR = g + gamma pi(a|s) z(s)`` with
``(I - gamma P_pi^T) z = P^T g`` (:func:`factirl_opt.planning.adjoint` with the stochastic
policy); ``dJ/dR = -(that)``.

Reused factorisations (:class:`MCEObjective`, with a planner whose systems expose per-task
solvers: the sparse LU; ``results/mce-speed``). A factorisation of
``I - gamma P_pi`` costs 2 ms at S = 1024, 20 solves' worth. Each task keeps the factorisation
``K`` of its last Newton step, between evaluations too (:class:`MCEObjective`), and tries the
*chord step* ``V + K^-1 (T V - V)`` first: Newton's step with an earlier policy's system. It is
accepted when it shrinks the residual ``||T V - V||_inf`` at least by :data:`CHORD_MAX_RATIO`
(else the guarded Newton step above is taken, and its factorisation kept); one that shrinks it
by less than :data:`CHORD_REFACTOR_RATIO` makes the next step a Newton step. The stopping rule
is the same; a task within it goes on with chord steps down to :data:`POLISH_TOL` (so the loss
stays smooth in the rewards far below the tolerance) or until one is refused. The adjoint is
solved by iterative refinement on the kept factorisation (:func:`refined_adjoint_solve`, from
the task's last adjoint solution), to a relative residual :data:`ADJOINT_TOL`, or with a new
factorisation where the refinement does not contract. The
public :func:`soft_values` (scores, EM) and :func:`mce_loss` keep plain guarded Newton and a
fresh adjoint factorisation: their results agree between planners to the bound the guide states,
``max(1e-13 / (1 - gamma), 1e-15 / (1 - gamma)^2)`` (tests/test_audit_planners.py; both planners
stop on the same iterate, so the error of stopping at :data:`SOFT_TOL` cancels between them: up to
2e-10 relative against the exact loss at gamma 0.99, results/planners/accuracy.json); the objective's agree with them to the stopping tolerances
above (measured along 8 evaluations on 5x5-6x6 grids, relative to the largest entry: losses
5e-13 at gamma 0.9-0.99 and 3e-11 at 0.999, gradients 1e-12 to 7e-11), which a fit of many
evaluations does not resolve.

Potential shaping ``R + gamma P phi - phi`` shifts ``Q`` and ``V`` by ``-phi(s)`` and leaves
``pi``, hence the loss, unchanged. The objective is not a least-squares one: the Gauss-Newton
step solvers do not apply, gradient solvers (``armijo``, ``armijo-nonneg``, ``lbfgs``) do.
"""

import numpy as np
from scipy.special import entr

from .._threads import blas_limited
from .._validation import check_beta, check_int, check_mdp, check_rewards, check_statistics, check_stochastic_policy
from ..exceptions import FactIRLError, ValidationError
from ..planning import adjoint, get_planner
from ._base import Objective
from ..tasks.basis import features_matrix

__all__ = ["MCEObjective", "mce_loss", "soft_values", "refined_adjoint_solve", "mce_hessian", "HESSIAN_KINDS"]

#: numpy sums at most this many terms in order (pairwise beyond): :func:`soft_backup` reduces over
#: the actions one by one up to it, the same values as numpy's reduction
SEQUENTIAL_SUM_MAX_ACTIONS = 7
#: relative tolerance of the soft values: ``||T V - V||_inf <= SOFT_TOL * max(1, ||V||_inf)``
SOFT_TOL = 1e-12
#: Newton (or guard) iterations allowed before :class:`FactIRLError`
SOFT_MAX_ITER = 1000
#: relative slack of the Newton guard's inequalities (far above rounding, far below a failed solve)
GUARD_SLACK = 1e-9
#: a chord step (the Newton step solved with a kept factorisation of an earlier policy) is
#: accepted when it shrinks the task's residual by at least this factor; else a Newton step is taken
CHORD_MAX_RATIO = 0.5
#: ... and when it shrinks it by less than this factor, the task's next step factorises anew (a
#: factorisation costs about as much as 15 chord steps at S = 1024: slower chords lose to Newton)
CHORD_REFACTOR_RATIO = 0.1
#: chord steps refused in one call after which a task takes Newton steps only (plain soft policy iteration)
CHORD_MAX_REFUSALS = 3
#: with chord steps, a task within the tolerance goes on with chord steps (cheap) while they shrink
#: its residual, down to this relative residual, so that losses are smooth in the rewards far
#: below the tolerance (finite differences, line searches; stopping at 1e-12, a finite-difference
#: check of the dictionary gradient failed: 2.6e-6 against 1e-6; 1e-13 and 1e-14 pass, 1e-13 is
#: 5% cheaper on `bench mce`)
POLISH_TOL = 1e-13
#: relative residual ``||b - M^T z||_inf <= ADJOINT_TOL (||b||_inf + ||z||_inf)`` at which the adjoint
#: solved by iterative refinement with a kept factorisation stops (about 100x above rounding)
ADJOINT_TOL = 1e-13
#: what :func:`mce_hessian` returns: the exact Hessian, or its Gauss-Newton (Fisher) part alone
HESSIAN_KINDS = ("exact", "gauss-newton")
#: :func:`mce_hessian` forms the tangents ``dQ`` (r, S, A, p) of at most this many bytes at once
HESSIAN_CHUNK_BYTES = 64 * 2**20
#: refinement sweeps of the adjoint before a task falls back to a new factorisation of its own policy
ADJOINT_MAX_REFINE = 30
#: a refinement sweep must shrink the adjoint's residual by this factor, else the task falls back too
ADJOINT_MIN_CONTRACTION = 0.1


def soft_backup(planner, R, V, beta):
    """One application of the soft Bellman operator, and the soft-greedy policy's logarithm.

    Parameters
    ----------
    planner : Planner
    R : ndarray, shape (n, S, A)
    V : ndarray, shape (n, S)
    beta : float

    Returns
    -------
    Q : ndarray, shape (n, S, A)
        ``R + gamma P V``.
    TV : ndarray, shape (n, S)
        ``(1/beta) log sum_a exp(beta Q)``, with the maximum over actions subtracted first.
    log_pi : ndarray, shape (n, S, A)
        ``beta (Q - TV)``, computed as ``beta (Q - max Q) - log sum_a exp(beta (Q - max Q))``.
    """
    Q = planner.q_from_values(R, V)
    if Q.shape[2] > SEQUENTIAL_SUM_MAX_ACTIONS:
        m = Q.max(axis=2, keepdims=True)
        z = beta * (Q - m)
        lse = np.log(np.exp(z).sum(axis=2, keepdims=True))  # in [0, log A]: the max term is exp(0)
        return Q, (m + lse / beta)[:, :, 0], z - lse
    # over the short action axis by whole-array operations, action by action: the same values,
    # bit for bit, as numpy's reductions along axis 2 (max; a sum of at most 7 terms is in order),
    # on an action-major copy (n, A, S) whose actions are contiguous rows (the same elementwise
    # arithmetic as on (n, S, A), in fewer strided passes), log_pi copied back to (n, S, A)
    A = Q.shape[2]
    z = np.ascontiguousarray(Q.transpose(0, 2, 1))
    m = z[:, 0].copy()
    for a in range(1, A):
        np.maximum(m, z[:, a], out=m)
    z -= m[:, None, :]
    z *= beta
    e = np.exp(z)
    total = e[:, 0].copy()
    for a in range(1, A):
        total += e[:, a]
    lse = np.log(total)  # in [0, log A]: the max term is exp(0)
    z -= lse[:, None, :]
    lse /= beta
    lse += m  # m + lse / beta
    return Q, lse, np.ascontiguousarray(z.transpose(0, 2, 1))


def _scale(V):
    return np.maximum(1.0, np.abs(V).max(axis=1))


def _newton_step(planner, R, V, TV, log_pi, beta):
    """One guarded Newton step for a batch of tasks: new V and its backup (Q, TV, log_pi).

    Newton's iterate is accepted where it is finite, a sub-solution, and not below a current
    sub-solution (module docstring); elsewhere the sweep ``V <- T V`` is taken.
    """
    pi = np.exp(log_pi)
    system = planner.system(pi)
    V_new = system.solve(np.sum(pi * (R - log_pi / beta), axis=2))
    Q, TV_new, lp = soft_backup(planner, R, V_new, beta)
    eps = (GUARD_SLACK * _scale(V))[:, None]
    sub = np.all(TV >= V - eps, axis=1)
    ok = np.all(np.isfinite(TV_new), axis=1) & np.all(TV_new >= V_new - eps, axis=1)
    ok &= ~sub | np.all(V_new >= V - eps, axis=1)
    if not ok.all():
        bad = ~ok
        V_new[bad] = TV[bad]
        Q[bad], TV_new[bad], lp[bad] = soft_backup(planner, R[bad], V_new[bad], beta)
    return V_new, Q, TV_new, lp, getattr(system, "solvers", None)


def _chord_step(planner, R, V, TV, res, solvers, beta):
    """Chord steps for a batch of tasks: ``V + K^-1 (T V - V)`` with ``K`` a kept factorisation of
    an earlier soft policy's system (each task's own, ``solvers``) instead of the current one.

    Returns the mask of accepted steps (finite, residual at most :data:`CHORD_MAX_RATIO` times
    ``res``) and the new V, its backup (Q, TV, log_pi) and residual (meaningful where accepted).
    """
    V_new = V + planner.solver_system(solvers).solve(TV - V)
    Q, TV_new, lp = soft_backup(planner, R, V_new, beta)
    res_new = np.abs(TV_new - V_new).max(axis=1)
    ok = res_new <= CHORD_MAX_RATIO * res  # False for a NaN residual
    return ok, V_new, Q, TV_new, lp, res_new


def soft_values(planner, R, beta, V0=None, tol=SOFT_TOL, max_iter=SOFT_MAX_ITER):
    """Soft values of every task by guarded Newton iteration (soft policy iteration).

    Unvalidated kernel (see the module docstring for the step and the guard).

    Parameters
    ----------
    planner : Planner
    R : ndarray, shape (n, S, A)
    beta : float
    V0 : ndarray, shape (n, S), optional
        Warm start (e.g. the values of a nearby reward); default zeros.
    tol : float
        Relative sup-norm tolerance on the soft Bellman residual.
    max_iter : int
        Iterations allowed; a task not converged by then raises :class:`FactIRLError`.

    Returns
    -------
    Q : ndarray, shape (n, S, A)
        ``R + gamma P V`` at the last iterate ``V``.
    V : ndarray, shape (n, S)
        ``T V`` (one more soft backup of the last iterate).
    log_pi : ndarray, shape (n, S, A)
        ``beta (Q - V)``: the soft-optimal policy's logarithm, exactly normalised against ``Q``.
    """
    Q, V, log_pi, _ = _soft_values(planner, R, beta, V0, tol, max_iter)
    return Q, V, log_pi


def _soft_values(planner, R, beta, V0=None, tol=SOFT_TOL, max_iter=SOFT_MAX_ITER, kept=None):
    """:func:`soft_values`, reusing factorisations when ``kept`` is given (see :class:`MCEObjective`).

    ``kept`` None: plain guarded Newton, as documented in the module docstring. ``kept`` a list
    (n,) of per-task solvers or None (a planner whose systems expose per-task solvers, e.g.
    the sparse LU): a task with a kept factorisation first tries a chord step with it
    (:func:`_chord_step`), and takes the guarded Newton step when the chord step does not
    shrink its residual enough (after :data:`CHORD_MAX_REFUSALS` refusals, Newton steps only);
    every Newton step's factorisation becomes the task's kept one. The stopping rule is the
    same, so the result is the same to the tolerance, and a task within it goes on with chord
    steps down to :data:`POLISH_TOL` or until one is refused (no Newton step then).

    Returns
    -------
    Q, V, log_pi
        As :func:`soft_values`.
    kept : list or None
        Per task, the factorisation of its last Newton step (or the kept one given), or None
        without ``kept``.
    """
    n, S, _ = R.shape
    V = np.zeros((n, S)) if V0 is None else np.array(V0, dtype=np.float64)
    Q, TV, log_pi = soft_backup(planner, R, V, beta)
    res = np.abs(TV - V).max(axis=1)
    refusals = np.zeros(n, dtype=np.intp)
    stalled = np.zeros(n, dtype=bool)  # polishing with chord steps no longer shrinks the residual
    refactor = np.zeros(n, dtype=bool)  # the last chord step contracted slowly: next, a Newton step
    has_kept = np.zeros(n, dtype=bool) if kept is None else np.array([k is not None for k in kept], dtype=bool)

    # The tasks of a step are an increasing subset of range(n): every task (size n) is taken
    # whole, without copies (a single task always is); the arithmetic is the same either way.
    def rows(x, a):
        return x if a.size == n else x[a]

    def chord_ok(a):
        return rows(has_kept, a) & (rows(refusals, a) < CHORD_MAX_REFUSALS) & ~rows(refactor, a)

    def unfinished(a):
        res_a, scale = rows(res, a), _scale(rows(V, a))
        within = res_a <= tol * scale  # False for a NaN residual: stays active
        if not within.any():
            return a
        if kept is None:
            return a[~within]
        polished = (res_a <= POLISH_TOL * scale) | rows(stalled, a) | ~chord_ok(a)
        return a[~(within & polished)]

    active = unfinished(np.arange(n))
    for _ in range(max_iter):
        if active.size == 0:
            break
        a = active
        c = a[chord_ok(a)]
        if c.size:
            ok, *step = _chord_step(planner, rows(R, c), rows(V, c), rows(TV, c), rows(res, c), [kept[i] for i in c], beta)
            if ok.all():
                done, refused = c, c[:0]
                slow = c[step[-1] > CHORD_REFACTOR_RATIO * rows(res, c)]
            else:
                done, refused = c[ok], c[~ok]
                slow = done[step[-1][ok] > CHORD_REFACTOR_RATIO * res[done]]
            if done.size == n:
                V, Q, TV, log_pi, res = step
            elif done.size:
                V[done], Q[done], TV[done], log_pi[done], res[done] = (x[ok] for x in step)
            if refused.size:
                refusals[refused] += 1
                stalled[refused] = res[refused] <= tol * _scale(V[refused])  # converged: no Newton step
            if slow.size:
                refactor[slow] = True  # contracts slowly: the next step factorises anew
            if done.size == a.size:
                a = done[:0]
            else:
                left = ~stalled[a]
                if done.size:
                    left[np.searchsorted(a, done)] = False  # done is a subset of a, both increasing
                a = a[left]
        if a.size:
            step = _newton_step(planner, rows(R, a), rows(V, a), rows(TV, a), rows(log_pi, a), beta)
            res_a = np.abs(step[2] - step[0]).max(axis=1)
            if a.size == n:
                V, Q, TV, log_pi, solvers = step
                res = res_a
            else:
                V[a], Q[a], TV[a], log_pi[a], solvers = step
                res[a] = res_a
            refactor[a] = False
            if kept is not None and solvers is not None:
                for i, solver in zip(a, solvers):
                    kept[i] = solver
                    has_kept[i] = solver is not None
        active = unfinished(active)
    if active.size:
        i = int(active[np.argmax(res[active])])
        raise FactIRLError(
            f"the soft Bellman equation did not converge in {max_iter} iterations: task {i} has residual "
            f"{res[i]:.3g} (tolerance {tol:g} x max(1, |V|)); beta * rewards may be too large to represent"
        )
    if not (np.all(np.isfinite(TV)) and np.all(np.isfinite(log_pi))):
        raise FactIRLError("the soft values are not finite: beta * rewards overflow float64; rescale the rewards")
    return Q, TV, log_pi, kept


class _Point:
    """Forward pass of the MCE likelihood at some rewards (internal)."""

    def __init__(self, Q, V, log_pi, counts, beta, kept=None):
        self.Q, self.V, self.log_pi, self.counts, self.beta, self.kept = Q, V, log_pi, counts, beta, kept
        self.pi = np.exp(log_pi)
        self.loss = -np.einsum("nsa,nsa->n", counts, log_pi)


def _forward(planner, R, mu, pi_hat, beta, V0=None, max_iter=SOFT_MAX_ITER, kept=None):
    Q, V, log_pi, kept = _soft_values(planner, R, beta, V0, max_iter=max_iter, kept=kept)
    return _Point(Q, V, log_pi, mu[:, :, None] * pi_hat, beta, kept)


def refined_adjoint_solve(planner, solvers, pi, B, z0=None):
    """``z`` with ``(I - gamma P_pi)^T z = B`` by iterative refinement on kept factorisations.

    ``K_i`` (``solvers[i]``) factorises an earlier policy's system of task ``i``; each sweep
    computes the residual ``r = B - M^T z`` with the current policy's ``M`` (two sparse
    products, no factorisation) and corrects ``z += K^-T r``. A task stops once
    ``||r||_inf <= ADJOINT_TOL (||B||_inf + ||z||_inf)``; one whose residual does not shrink by
    :data:`ADJOINT_MIN_CONTRACTION` per sweep, or is not done after :data:`ADJOINT_MAX_REFINE`
    sweeps, is not refined further (its ``z`` is then not the solution).

    Parameters
    ----------
    planner : Planner
        Whose systems expose per-task solvers (:meth:`Planner.solver_system`).
    solvers : list of n solvers
    pi : ndarray, shape (n, S, A)
        The stochastic policies of the systems solved.
    B : ndarray, shape (n, S)
    z0 : ndarray, shape (n, S), optional
        Where the refinement starts (e.g. the solution for nearby rewards); default ``K^-T B``.

    Returns
    -------
    z : ndarray, shape (n, S)
    converged : ndarray of bool, shape (n,)
    sweeps : int
        Refinement sweeps taken (0: the start was exact enough for every task).
    """
    n = len(B)
    z = planner.solver_system(solvers).solve_transpose(B) if z0 is None else np.array(z0, dtype=np.float64)
    scale_b = np.abs(B).max(axis=1)
    todo, prev = np.arange(n), np.full(n, np.inf)
    converged = np.zeros(n, dtype=bool)

    def rows(x, t):  # every task (always for one) without copies; the same arithmetic
        return x if t.size == n else x[t]

    for sweep in range(ADJOINT_MAX_REFINE + 1):
        t = todo
        z_t = rows(z, t)
        r = rows(B, t) - (z_t - planner.gamma * planner.pullback(rows(pi, t) * z_t[:, :, None]))
        norm = np.abs(r).max(axis=1)
        done = norm <= ADJOINT_TOL * (rows(scale_b, t) + np.abs(z_t).max(axis=1))
        converged[t[done]] = True
        going = ~done & (norm <= ADJOINT_MIN_CONTRACTION * rows(prev, t))  # False for NaN: stalled
        if t.size == n:
            prev = norm
        else:
            prev[t] = norm
        todo = t[going]
        if todo.size == 0 or sweep == ADJOINT_MAX_REFINE:
            break
        correction = planner.solver_system([solvers[i] for i in todo]).solve_transpose(r if todo.size == n else r[going])
        if todo.size == n:
            z += correction
        else:
            z[todo] += correction
    return z, converged, sweep


def _gradient(planner, point):
    """``dJ/dR`` (n, S, A): one transposed solve per task with the soft-optimal policy's system.

    With kept factorisations (``point.kept``, every task's), the solve is refined on them
    (:func:`refined_adjoint_solve`), from ``point.z0`` if set (the adjoint of the tasks' last
    evaluation); a task where that does not converge gets a new factorisation of its own
    policy, which becomes its kept one. The solution is left in ``point.z``.
    """
    pi, c = point.pi, point.counts
    g = point.beta * (c - c.sum(axis=2, keepdims=True) * pi)  # dlogL/dQ
    kept = point.kept
    if kept is None or any(k is None for k in kept):
        return -adjoint(planner, planner.system(pi), pi, g)
    b = planner.pullback(g)
    z, converged, _ = refined_adjoint_solve(planner, kept, pi, b, getattr(point, "z0", None))
    if not converged.all():
        f = np.flatnonzero(~converged)
        system = planner.system(pi[f])
        z[f] = system.solve_transpose(b[f])
        for i, solver in zip(f, system.solvers or [None] * len(f)):
            kept[i] = solver
    point.z = z
    return -(g + planner.gamma * pi * z[:, :, None])


def mce_hessian(planner, R, log_pi, counts, grad, beta, features, kind="exact", chunk=None):
    """Hessian of every task's MCE loss with respect to linear reward weights ``R_i = F_i w_i``.

    Unvalidated kernel (docs/maths.md §6). With the soft-optimal policy ``pi`` of ``R`` and
    ``M = I - gamma P_pi``, a reward direction ``dR`` moves the soft action values by
    ``dQ = dR + gamma P dV``, ``M dV = sum_a pi dR`` (:func:`factirl_opt.planning.tangent` with
    the stochastic policy), and the loss's second derivative along it is

        d^2 J [dR, dR] = sum_s w(s) Var_{pi(.|s)}(dQ(s, .)),
        w(s) = beta^2 c(s) + gamma beta (P^T y)(s),

    with ``c(s) = sum_a c(s, a)`` the demonstrated state frequencies and ``y = dJ/dR``. The
    first term is the Gauss-Newton (Fisher) part, the curvature of the log-softmax of the
    logits ``beta Q`` (positive semidefinite); the second is the curvature of the soft values
    ``Q(R)`` themselves (``d^2 Q = M_Q^-1 gamma P beta Var_pi(dQ)``) weighted by the adjoint, and
    may make the Hessian indefinite where the demonstrations' state frequencies are not those
    of a soft policy. With the centred tangents ``E_j = dQ_j - sum_a pi dQ_j`` of the feature
    columns, ``H_jk = sum_{s,a} w(s) pi(a|s) E_j(s, a) E_k(s, a)``: one factorisation of ``M`` per
    task (the current policy's) and ``p`` right-hand sides.

    Parameters
    ----------
    planner : Planner
    R : ndarray, shape (n, S, A)
        Rewards (only their shape is used: the point is given by ``log_pi`` and ``grad``).
    log_pi : ndarray, shape (n, S, A)
        The soft-optimal policy of ``R`` (:func:`soft_values`).
    counts : ndarray, shape (n, S, A)
        Demonstrated pair frequencies ``c(s, a) = mu_hat(s) pi_hat(a|s)``.
    grad : ndarray, shape (n, S, A)
        ``dJ/dR`` at ``R`` (:func:`mce_loss`).
    beta : float
    features : ndarray, shape (S*A, p) or (n, S*A, p)
        ``F`` shared by the tasks, or one per task.
    kind : {"exact", "gauss-newton"}
        The exact Hessian, or its Gauss-Newton part alone (``w = beta^2 c``).
    chunk : int, optional
        Tasks whose tangents are formed at once (default: as many as fit in
        :data:`HESSIAN_CHUNK_BYTES`).

    Returns
    -------
    hessian : ndarray, shape (n, p, p)
        Symmetric.
    solvers : list
        Per task, the factorisation of its policy's system (``PolicySystem.solvers``; None
        entries for planners without per-task solvers).
    """
    n, S, A = R.shape
    p = features.shape[-1]
    pi = np.exp(log_pi)
    w = beta * beta * counts.sum(axis=2)
    if kind == "exact":
        w = w + planner.gamma * beta * planner.pullback(grad)
    wpi = w[:, :, None] * pi
    size = max(1, HESSIAN_CHUNK_BYTES // (8 * S * A * p)) if chunk is None else max(1, int(chunk))
    H = np.empty((n, p, p))
    solvers = []
    for lo in range(0, n, size):
        c = slice(lo, min(n, lo + size))
        m = c.stop - c.start
        F = (features[c] if features.ndim == 3 else np.broadcast_to(features, (m, S * A, p))).reshape(m, S, A, p)
        # state features (the same for every action) cancel in the centred tangents: E = centre(gamma P dV)
        state_only = bool(np.all(F == F[:, :, :1, :]))
        F_pi = F[:, :, 0, :].copy() if state_only else _action_average(pi[c], F)  # sum_a pi dR, (m, S, p)
        system = planner.system(pi[c])
        U = planner.gamma * planner.backup(system.solve(F_pi)).reshape(m, S, A, p)  # gamma P dV
        if not state_only:
            U += F  # dQ = dR + gamma P dV
        mean = _action_average(pi[c], U)  # sum_a pi dQ, (m, S, p)
        # H = sum_{s,a} w pi dQ dQ^T - sum_s w mean mean^T: the centred second moment, action by action
        Hc = -np.matmul(mean.transpose(0, 2, 1), w[c, :, None] * mean)
        for a in range(A):
            Ua = U[:, :, a, :]
            Hc += np.matmul(Ua.transpose(0, 2, 1), wpi[c, :, a, None] * Ua)
        H[c] = 0.5 * (Hc + Hc.transpose(0, 2, 1))
        solvers += list(getattr(system, "solvers", None) or [None] * m)
    return H, solvers


def _action_average(pi, X):
    """``sum_a pi(a|s) X[:, s, a, :]`` (n, S, k) of X (n, S, A, k), action by action (no einsum)."""
    out = pi[:, :, 0, None] * X[:, :, 0, :]
    for a in range(1, X.shape[2]):
        out += pi[:, :, a, None] * X[:, :, a, :]
    return out


def soft_policy_values(planner, R, policy, beta):
    """Soft value of fixed stochastic policies: ``(I - gamma P_pi) V = sum_a pi R + H(pi) / beta``.

    ``H(pi)(s) = -sum_a pi log pi`` (``0 log 0 = 0``). Used to warm-start from a policy.
    """
    return planner.system(policy).solve(np.sum(policy * R, axis=2) + entr(policy).sum(axis=2) / beta)


class MCEObjective(Objective):
    """The MCE negative log-likelihood over a fixed set of tasks (see :class:`Objective`).

    Not least squares: use it with gradient step solvers (``armijo``, ``armijo-nonneg``, ``lbfgs``).
    Warm start: each task's last soft values start its next Newton iteration, and, with a
    planner whose systems expose per-task solvers (the sparse LU), its last factorisation is
    kept and reused: for chord steps of the next soft values and for the adjoint, by iterative
    refinement (:func:`refined_adjoint_solve`, from the task's last adjoint solution); a
    factorisation is made only when the kept
    one no longer contracts fast enough. One factorisation per task is kept between
    evaluations (dropped by :meth:`reset`, and not kept at all under a planning
    budget the tasks do not fit in at once). Results agree with fresh factorisations to the
    soft values' tolerance.
    """

    name = "mce"
    least_squares = False
    has_hessian = True

    @classmethod
    def log_policy(cls, planner, rewards, beta):
        """The soft-optimal policy ``beta (Q - V)`` of the soft Bellman equation (docs/maths.md §6), (n, S, A)."""
        return soft_values(planner, rewards, beta)[2]

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._kept = None  # per task: the solver of its last factorised soft policy, or None
        self._z = None  # per task: its last adjoint solution (n_tasks, S), NaN where none

    def reset(self):
        super().reset()
        self._kept = self._z = None

    def _forward(self, R, rows, warm):
        if self._chunk(self.n_tasks) < self.n_tasks:  # under a budget: nothing kept between calls
            kept = [None] * len(rows)
        else:
            if self._kept is None:
                self._kept = [None] * self.n_tasks
            kept = [self._kept[i] for i in rows]
        point = _forward(self.planner, R, self.mu[rows], self.pi_hat[rows], self.beta, warm, kept=kept)
        point.rows = rows
        if self._z is not None and self._kept is not None:
            z0 = self._z[rows]
            point.z0 = None if np.isnan(z0).any() else z0
        self._keep(point)
        return point

    def _keep(self, point):
        if self._kept is not None and self._chunk(self.n_tasks) >= self.n_tasks:
            for i, solver in zip(point.rows, point.kept):
                self._kept[i] = solver
            z = getattr(point, "z", None)
            if z is not None:
                if self._z is None:
                    self._z = np.full((self.n_tasks, z.shape[1]), np.nan)
                self._z[point.rows] = z

    def _warm_start(self, point):
        return point.V

    def _grad(self, point):
        grad = _gradient(self.planner, point)
        self._keep(point)
        return grad

    def hessian(self, rewards, rows=None, features=None, kind="exact"):
        """Hessian of every task's loss with respect to weights ``w_i`` of rewards ``R_i = F w_i``, (r, p, p).

        :func:`mce_hessian` at the rewards of tasks ``rows``: the loss and gradient there come
        from :meth:`loss_and_grad` (its cache when the tasks were last evaluated at exactly these
        rewards, as a step solver's accepted trial point; else one evaluation), the soft
        policy from the tasks' kept soft values (one soft backup, no solve). Each task's
        policy system is factorised once and kept for the next evaluations' chord steps and
        adjoints (as a Newton step's factorisation is).

        Parameters
        ----------
        rewards : ndarray, shape (r, S, A)
        rows : ndarray of int, shape (r,), optional
            The tasks (default: all).
        features : ndarray, shape (S*A, p) or (r, S*A, p), or RewardBasis, optional
            ``F`` shared or one per row, or a basis (its dense features of ``rows``,
            :func:`~factirl_opt.tasks.basis.features_matrix`); None: tabular weights (``F = I``,
            p = S*A, the Hessian with respect to the rewards themselves).
        kind : {"exact", "gauss-newton"}, default="exact"
            The exact Hessian, or its positive semidefinite Gauss-Newton (Fisher) part.

        Raises
        ------
        ValidationError
            For a ``kind`` or ``features`` of the wrong value or shape.
        """
        if kind not in HESSIAN_KINDS:
            raise ValidationError(f"kind must be one of {', '.join(HESSIAN_KINDS)}; got {kind!r}")
        rows = self._rows(rows)
        R = np.asarray(rewards, dtype=np.float64)
        S, A = self.mdp.n_states, self.mdp.n_actions
        F = np.asarray(features_matrix(features, S, A, rows), dtype=np.float64)
        if not (F.ndim in (2, 3) and F.shape[-2] == S * A and (F.ndim == 2 or F.shape[0] == len(rows))):
            raise ValidationError(f"features must have shape (S*A, p) = ({S * A}, p) or (r, S*A, p) with r = {len(rows)}; "
                                  f"got {F.shape}")
        _, grad = self.loss_and_grad(R, rows)
        _, _, log_pi = soft_backup(self.planner, R, self._warm[rows], self.beta)
        counts = self.mu[rows][:, :, None] * self.pi_hat[rows]
        budget = self._chunk(len(rows), F.shape[-1])
        H, solvers = mce_hessian(self.planner, R, log_pi, counts, grad, self.beta, F, kind,
                                 chunk=None if budget >= len(rows) else budget)
        if self._kept is not None and budget >= self.n_tasks:
            for i, solver in zip(rows, solvers):
                if solver is not None:
                    self._kept[i] = solver
        return H


@blas_limited
def mce_loss(mdp, rewards, mu_hat, pi_hat, beta, policy=None, planner="auto", max_iter=SOFT_MAX_ITER):
    """Maximum causal entropy negative log-likelihood per task and its gradient dJ/dR.

    The reference route: the soft values by plain guarded Newton steps and the adjoint by a fresh
    factorisation, so that every planner agrees to the tolerance the guide states. The learners'
    :class:`MCEObjective` reuses factorisations across steps and evaluations (chord steps and a
    refined adjoint) and agrees with this function to the soft values' polishing tolerance.

    Parameters
    ----------
    mdp : TabularMDP
    rewards : array_like, shape (S, A) or (n, S, A)
        Rewards ``R[i, s, a]``.
    mu_hat : array_like, shape (S,) or (n, S)
        Empirical state frequencies (see :func:`empirical_statistics`).
    pi_hat : array_like, shape (S, A) or (n, S, A)
        Empirical policies; the demonstrated pair frequencies are ``mu_hat(s) pi_hat(a|s)``.
    beta : float
        Inverse temperature of the soft Bellman equation (> 0).
    policy : array_like of float, shape (S, A) or (n, S, A), optional
        Warm start: a stochastic policy ``pi(a|s)`` (rows summing to 1), e.g. the soft-optimal
        policy of a nearby reward; the Newton iteration starts from its soft value. Default:
        start from ``V = 0``. The result does not depend on it (beyond 1e-12).
    planner : str, default="auto"
        See :func:`factirl_opt.available_planners`.
    max_iter : int
        Newton iterations allowed (each one solve per task); :class:`FactIRLError` beyond.

    Returns
    -------
    loss : ndarray, shape (n,)
        ``J_i = -sum_s mu_hat(s) sum_a pi_hat(a|s) log pi_i(a|s)``, ``pi_i`` soft-optimal for
        ``R_i``.
    grad : ndarray, shape (n, S, A)
        ``dJ_i / dR_i`` by the adjoint route (module docstring; docs/maths.md §6).
    """
    check_mdp(mdp)
    R, _ = check_rewards(mdp, rewards)
    mu, pi_hat = check_statistics(mdp, mu_hat, pi_hat, n=R.shape[0])
    beta = check_beta(beta)
    max_iter = check_int(max_iter, "max_iter", minimum=1)
    pl = get_planner(mdp, planner)
    V0 = None if policy is None else soft_policy_values(pl, R, check_stochastic_policy(mdp, policy, R.shape[0]), beta)
    point = _forward(pl, R, mu, pi_hat, beta, V0, max_iter)
    return point.loss, _gradient(pl, point)
