"""How accurate each planner is (the user guide's "What depends on the planner"): the dense and
sparse-LU planners against an exact reference, and the conditioning that bounds them both.

At the same rewards (3 tasks, 3 demonstrations of 5 steps each, seeds 0-2, beta 5), per world
and planner: the largest error relative to the reference (max |a - ref| / max |ref| over the 3
tasks, the measure of ``agreement.py`` and ``tests/test_audit_planners.py``) of ``optimal_q``'s Q,
``policy_evaluation``'s V of the greedy policy, the soft values of MCE, and the policy-matching
and MCE losses and gradients (``policy_matching_loss``, ``mce_loss``); the same between the two
planners; and whether their greedy policies are equal.

The reference solves the same equations in long double (x87 80-bit, eps 1.1e-19), on the
float64 model data as given: every Bellman system by iterative refinement of a float64 LU with
long-double residuals (accurate to about 1e-19 / (1 - gamma), three digits beyond float64), policy iteration from the dense planner's greedy policy, the soft values
by Newton's method to a residual of 1e-18.

``conditioning``: how much the reference's losses and gradients move when every transition
probability is perturbed by a relative eps = 2.2e-16 (uniform in [-eps, eps]): the error that
rounding the model's own data to float64 already implies, and so the best any float64 planner
can promise (a backward-stable solve is exact for data perturbed at that level).

Worlds: GridWorld 5x5, 10x10 and 16x16 and a 10x10 Objectworld (``rng=0``), at gamma 0.9, 0.99
and 0.999, with N(0, 1) state-action rewards; and the Objectworld with its multi-task feature
rewards (``multitask_rewards``; state rewards, so actions tie where the dynamics do not tell them
apart: the greedy policy, hence the policy-matching gradient, is then not unique). Prints JSON:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/planners/accuracy.py > results/planners/accuracy.json
"""

import json

import numpy as np
import scipy.linalg as sla

import factirl_opt as fo
from factirl_opt.objectives.mce import soft_values

LD = np.longdouble
BETA = 5.0
PLANNERS = ("dense", "sparse-lu")
QUANTITIES = ("Q", "V", "soft V", "policy matching", "its gradient", "mce", "mce gradient")


def ld_solve(M, b):
    """``M x = b`` in long double: iterative refinement of a float64 LU, residuals in long double."""
    lu = sla.lu_factor(M.astype(np.float64))
    x = sla.lu_solve(lu, b.astype(np.float64)).astype(LD)
    last = np.inf
    for _ in range(30):  # until the correction stops shrinking (at eps_ld times the condition number)
        dx = sla.lu_solve(lu, (b - M @ x).astype(np.float64)).astype(LD)
        x, size = x + dx, np.max(np.abs(dx))
        if size <= 1e-20 * np.max(np.abs(x)) or size > 0.5 * last:
            return x
        last = size
    raise RuntimeError("iterative refinement did not converge")


class Reference:
    """One task's planning quantities in long double (the MDP's float64 data, exactly)."""

    def __init__(self, mdp, P=None):
        self.S, self.A = mdp.n_states, mdp.n_actions
        self.P = mdp.csr().toarray().reshape(self.S, self.A, self.S).astype(LD) if P is None else P
        self.gamma, self.eye = LD(mdp.gamma), np.eye(self.S, dtype=LD)

    def system(self, policy):
        """``I - gamma P_pi`` of a deterministic (S,) or stochastic (S, A) policy."""
        P_pi = self.P[np.arange(self.S), policy] if policy.ndim == 1 else np.einsum("sa,sat->st", policy, self.P)
        return self.eye - self.gamma * P_pi

    def q(self, R, V):
        return R + self.gamma * np.einsum("sat,t->sa", self.P, V)

    def pullback(self, G):
        return np.einsum("sat,sa->t", self.P, G)

    def optimal(self, R, policy):
        """Q*, a greedy policy and its values, by policy iteration from ``policy``."""
        R, policy, S = R.astype(LD), policy.copy(), np.arange(self.S)
        for _ in range(100):
            V = ld_solve(self.system(policy), R[S, policy])
            Q = self.q(R, V)
            best = Q.argmax(axis=1)
            better = Q[S, best] > Q[S, policy] + LD(1e-17) * np.abs(Q).max()
            if not better.any():
                return Q, policy, V
            policy = np.where(better, best, policy)
        raise RuntimeError("policy iteration did not converge")

    def soft(self, R, beta):
        """Soft values: Q, V = T V and log pi, by Newton's method (soft policy iteration)."""
        R, beta, V = R.astype(LD), LD(beta), np.zeros(self.S, dtype=LD)
        for _ in range(200):
            Q = self.q(R, V)
            m = Q.max(axis=1, keepdims=True)
            z = beta * (Q - m)
            lse = np.log(np.exp(z).sum(axis=1, keepdims=True))
            TV, log_pi = (m + lse / beta)[:, 0], z - lse
            if np.max(np.abs(TV - V)) <= LD(1e-18) * max(LD(1), np.abs(V).max()):
                return Q, TV, log_pi
            pi = np.exp(log_pi)
            V = ld_solve(self.system(pi), np.sum(pi * (R - log_pi / beta), axis=1))
        raise RuntimeError("Newton's method did not converge")

    def policy_matching(self, R, policy, mu, pi_hat, beta):
        """Eq. (5) and its gradient by the adjoint (objectives/policy_matching.py), greedy on Q*."""
        Q, policy, _ = self.optimal(R, policy)
        z = LD(beta) * (Q - Q.max(axis=1, keepdims=True))
        pi = np.exp(z)
        pi /= pi.sum(axis=1, keepdims=True)
        mu, diff = mu.astype(LD)[:, None], pi - pi_hat.astype(LD)
        e = 2 * mu * diff
        g = LD(beta) * pi * (e - np.sum(pi * e, axis=1, keepdims=True))
        y = g.copy()
        y[np.arange(self.S), policy] += self.gamma * ld_solve(self.system(policy).T, self.pullback(g))
        return np.sum(mu * diff * diff), y

    def mce(self, R, mu, pi_hat, beta):
        """The MCE loss and its gradient by the adjoint (objectives/mce.py), and the soft values."""
        _, V, log_pi = self.soft(R, beta)
        c = mu.astype(LD)[:, None] * pi_hat.astype(LD)
        pi = np.exp(log_pi)
        g = LD(beta) * (c - c.sum(axis=1, keepdims=True) * pi)
        z = ld_solve(self.system(pi).T, self.pullback(g))
        return -np.sum(c * log_pi), -(g + self.gamma * pi * z[:, None]), V


def relative(a, b):
    a, b = np.asarray(a, dtype=LD), np.asarray(b, dtype=LD)
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), LD(1e-300)))


def planner_quantities(mdp, R, mu, pi_hat, planner):
    fo.planning.clear_caches(mdp)
    Q, greedy = fo.optimal_q(mdp, R, planner=planner)
    pm, pm_grad = fo.policy_matching_loss(mdp, R, mu, pi_hat, beta=BETA, planner=planner)
    mce, mce_grad = fo.mce_loss(mdp, R, mu, pi_hat, beta=BETA, planner=planner)
    soft_v = soft_values(fo.planning.get_planner(mdp, planner), R, BETA)[1]
    return greedy, dict(zip(QUANTITIES, (Q, fo.policy_evaluation(mdp, R, greedy, planner=planner), soft_v,
                                          pm, pm_grad, mce, mce_grad)))


def reference_quantities(ref, R, greedy, mu, pi_hat):
    out = {k: [] for k in QUANTITIES}
    for i in range(len(R)):
        Q, _, V = ref.optimal(R[i], greedy[i])
        pm = ref.policy_matching(R[i], greedy[i], mu[i], pi_hat[i], BETA)
        mce, mce_grad, soft_v = ref.mce(R[i], mu[i], pi_hat[i], BETA)
        for k, v in zip(QUANTITIES, (Q, V, soft_v, *pm, mce, mce_grad)):
            out[k].append(v)
    return {k: np.array(v) for k, v in out.items()}


def worlds():
    for size in (5, 10, 16):
        for gamma in (0.9, 0.99, 0.999):
            yield f"grid {size}x{size}, gamma {gamma}", fo.GridWorld(size=size, gamma=gamma), None
    for gamma in (0.9, 0.99, 0.999):
        world = fo.objectworld.make_objectworld(size=10, gamma=gamma, rng=0)
        yield f"objectworld 10x10, gamma {gamma}", world.mdp(), None
        yield f"objectworld 10x10 feature rewards, gamma {gamma}", world.mdp(), world


out = {}
eps = np.finfo(np.float64).eps
for name, mdp, world in worlds():
    ref = Reference(mdp)
    perturbed = Reference(mdp, ref.P * (1 + LD(eps) * np.random.default_rng(100).uniform(-1, 1, ref.P.shape).astype(LD)))
    errors = {p: dict.fromkeys(QUANTITIES, 0.0) for p in (*PLANNERS, "between planners", "conditioning")}
    greedy_equal = True
    for seed in range(3):
        rng = np.random.default_rng(seed)
        if world is None:
            R = rng.normal(size=(3, mdp.n_states, mdp.n_actions))
        else:
            R = fo.objectworld.state_action_rewards(fo.objectworld.multitask_rewards(world, 3, rng=seed)[0])
        mu, pi_hat = fo.empirical_statistics(mdp, fo.sample_demonstrations(mdp, R, 3, 5, rng))
        got = {p: planner_quantities(mdp, R, mu, pi_hat, p) for p in PLANNERS}
        greedy_equal &= bool(np.array_equal(got["dense"][0], got["sparse-lu"][0]))
        exact = reference_quantities(ref, R, got["dense"][0], mu, pi_hat)
        moved = reference_quantities(perturbed, R, got["dense"][0], mu, pi_hat)
        for k in QUANTITIES:
            for p in PLANNERS:
                errors[p][k] = max(errors[p][k], relative(got[p][1][k], exact[k]))
            errors["between planners"][k] = max(errors["between planners"][k],
                                                relative(got["sparse-lu"][1][k], got["dense"][1][k]))
            errors["conditioning"][k] = max(errors["conditioning"][k], relative(moved[k], exact[k]))
    out[name] = {**errors, "greedy_equal": greedy_equal}
print(json.dumps(out, indent=1))
