"""Helpers shared by the tests (``from helpers import ...``; registered by conftest)."""

import contextlib
import signal
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning

__all__ = ["hang_guard", "central_difference", "rel_err", "random_statistics", "greedy_gap"]


class Hang(Exception):
    """A guarded call did not return in time."""


@contextlib.contextmanager
def hang_guard(seconds, what="the call"):
    """Turn a hang into a test failure (SIGALRM after ``seconds``): a bound, not a speed test."""

    def _raise(signum, frame):
        raise Hang(f"{what} did not return within {seconds} s")

    previous = signal.signal(signal.SIGALRM, _raise)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def central_difference(f, x, eps=1e-6):
    """Gradient of a scalar function of an array by central differences, same shape as x."""
    x = np.array(x, dtype=np.float64)
    g = np.empty_like(x)
    for idx in np.ndindex(x.shape):
        xp, xm = x.copy(), x.copy()
        xp[idx] += eps
        xm[idx] -= eps
        g[idx] = (f(xp) - f(xm)) / (2 * eps)
    return g


def rel_err(a, b):
    """Relative error ``||a - b|| / ||b||`` of flattened arrays."""
    return np.linalg.norm(np.ravel(a) - np.ravel(b)) / np.linalg.norm(np.ravel(b))


def random_statistics(rng, mdp, n):
    """Random empirical statistics ``(mu_hat (n, S), pi_hat (n, S, A))``.

    ``mu_hat`` rows on the simplex with state 0 unvisited; ``pi_hat`` rows on the simplex,
    zero in the unvisited state (as :func:`factirl_opt.empirical_statistics` produces).
    """
    S, A = mdp.n_states, mdp.n_actions
    mu = rng.random((n, S))
    mu[:, 0] = 0.0
    mu /= mu.sum(axis=1, keepdims=True)
    pi = rng.dirichlet(np.ones(A), size=(n, S))
    pi[:, 0] = 0.0
    return mu, pi


def greedy_gap(mdp, rewards):
    """Smallest gap between the best and second-best Q* over all states (and tasks)."""
    Q, _ = fo.optimal_q(mdp, rewards)
    Qs = np.sort(np.asarray(Q), axis=-1)
    return float(np.min(Qs[..., -1] - Qs[..., -2]))


def five_tasks_on_a_small_grid():
    """Five tasks on one 3x3 grid with random rewards and features (p = 4): ``(mdp, features, demos)``."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(7)
    R = 2.0 * rng.standard_normal((5, 9, 4))
    demos = fo.sample_demonstrations(mdp, R, 3, 6, rng=rng)
    return mdp, rng.random((9, 4)), demos


def three_tasks_on_two_grids():
    """Three tasks on grids of 9, 16 and 9 states (the first and last the same object), state
    features p = 3: ``(mdps, features, demos)``."""
    g3, g4 = fo.GridWorld(size=3, p_success=0.7, gamma=0.9), fo.GridWorld(size=4, p_success=0.8, gamma=0.9)
    mdps = [g3, g4, g3]
    rng = np.random.default_rng(0)
    Phis = [rng.random((9, 3)), rng.random((16 * 4, 3)), rng.random((9, 3))]
    R = [2.0 * rng.normal(size=(m.n_states, 4)) for m in mdps]
    demos = [fo.sample_demonstrations(m, r[None], 2, 5, rng=i)[0] for i, (m, r) in enumerate(zip(mdps, R))]
    return mdps, Phis, demos


def quiet_fit(model, *args):
    """``model.fit(*args)`` with its ConvergenceWarning silenced (a capped fit on purpose)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return model.fit(*args)


def five_dictionary_tasks(rng, grid3, k):
    """Five tasks on a 3x3 grid whose state-action rewards mix ``k`` random primitives:
    ``(mdp, rewards (5, 9, 4), demos)`` (4 demonstrations of 6 steps each)."""
    D = fo.random_dictionary(36, k, rng)
    H = fo.random_coefficients(5, k, rng=rng)
    R = fo.task_rewards(D, H, 9, 4)
    return grid3, R, fo.sample_demonstrations(grid3, R, 4, 6, rng)


def transfer_tasks_on_a_grid(size, n_train, n_test, length, rng):
    """Synthetic tasks of a k = 2 dictionary on a ``size`` x ``size`` grid: ``n_train`` tasks of 4
    demonstrations and ``n_test`` new tasks of one, all of ``length`` steps, drawn with seeds ``rng``
    and ``rng + 1``: ``(mdp, train, test)`` (``fo.datasets.synthetic_tasks``' results)."""
    from factirl_opt.datasets.synthetic import synthetic_tasks

    mdp = fo.GridWorld(size=size, p_success=0.8, gamma=0.9)
    train = synthetic_tasks(mdp, n_train, 4, length, n_primitives=2, rng=rng)
    test = synthetic_tasks(mdp, n_test, 1, length, dictionary=train.dictionary, rng=rng + 1)
    return mdp, train, test


def two_primitive_feature_tasks(n_tasks, n_demos, seed):
    """``n_tasks`` tasks on a 3x3 grid whose state rewards mix 2 random primitives over 4 random
    state features, ``n_demos`` demonstrations of 6 steps each, all drawn from ``seed``:
    ``(mdp, F (9, 4), R (n_tasks, 9, 4), demos)``."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(seed)
    F = rng.random((9, 4))
    D, H = rng.normal(size=(4, 2)), 3.0 * rng.normal(size=(n_tasks, 2))
    R = np.repeat((H @ D.T) @ F.T, 4, axis=1).reshape(n_tasks, 9, 4)
    return mdp, F, R, fo.sample_demonstrations(mdp, R, n_demos, 6, rng=rng)

