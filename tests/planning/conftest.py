"""Fixtures of the planning tests: random sparse non-grid models and residual checks.

The models have absorbing states, self-loops and 1 to 4 successors per (state, action); each is
built sparse (scipy CSR, (S*A, S)) and, for the reference, dense ((S, A, S) array). The dense
planner on the dense copy is the reference route; every planner on the sparse copy must agree
with it to 1e-9 (relative), and every solve must reach a relative residual of 1e-12.
"""

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo


def random_sparse_transitions(rng, S=40, A=3, n_absorbing=3):
    """(S*A, S) CSR: absorbing states, self-loops, 1-4 successors per row (Dirichlet weights)."""
    absorbing = set(rng.choice(S, n_absorbing, replace=False).tolist())
    rows, cols, vals = [], [], []
    for s in range(S):
        for a in range(A):
            if s in absorbing:
                succ, p = [s], [1.0]
            else:
                k = int(rng.integers(1, 5))
                succ = rng.choice(S, k, replace=False)
                if rng.random() < 0.3 and s not in succ:
                    succ[0] = s  # a self-loop
                p = rng.dirichlet(np.ones(k))
            rows += [s * A + a] * len(succ)
            cols += list(succ)
            vals += list(p)
    return sp.csr_matrix((vals, (rows, cols)), shape=(S * A, S))



@pytest.fixture
def sparse_transitions():
    """The random (S*A, S) CSR dynamics builder ``f(rng, S=40, A=3, n_absorbing=3)``."""
    return random_sparse_transitions


@pytest.fixture(params=[0, 1])
def twins(request):
    """(sparse model, dense copy of the same dynamics) of a random non-grid MDP (gamma 0.9 / 0.95)."""
    rng = np.random.default_rng(100 + request.param)
    P = random_sparse_transitions(rng, S=40 + 10 * request.param, A=3 + request.param)
    gamma = (0.9, 0.95)[request.param]
    S, A = P.shape[1], P.shape[0] // P.shape[1]
    return fo.TabularMDP(P, gamma), fo.TabularMDP(P.toarray().reshape(S, A, S), gamma)


@pytest.fixture
def assert_rel():
    """``f(x, ref, tol=1e-9)``: max |x - ref| <= tol * max |ref|."""

    def check(x, ref, tol=1e-9):
        scale = max(float(np.max(np.abs(ref))), 1e-300)
        assert float(np.max(np.abs(np.asarray(x) - ref))) <= tol * scale

    return check


def policy_matrix_dense(mdp, policy):
    """Dense (n, S, S) P_pi of deterministic (n, S) or stochastic (n, S, A) policies (test reference)."""
    P3 = mdp.transitions
    w = policy if policy.ndim == 3 else np.eye(mdp.n_actions)[policy]
    return np.einsum("nsa,sat->nst", w, P3)


def relative_residuals(mdp, system, policy, B):
    M = np.eye(mdp.n_states)[None] - mdp.gamma * policy_matrix_dense(mdp, policy)
    X, XT = system.solve(B), system.solve_transpose(B)
    res = np.linalg.norm(np.einsum("nst,nt...->ns...", M, X) - B, axis=1) / np.linalg.norm(B, axis=1)
    res_t = np.linalg.norm(np.einsum("nts,nt...->ns...", M, XT) - B, axis=1) / np.linalg.norm(B, axis=1)
    return max(res.max(), res_t.max())


@pytest.fixture
def residual_of():
    """``f(mdp, system, policy, B)``: largest relative residual of a PolicySystem's solves (both ways)."""
    return relative_residuals
