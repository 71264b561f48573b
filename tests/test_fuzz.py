"""Seeded fuzzing of the public API with malformed and extreme arrays.

Every call must either raise one of the library's own exceptions (``FactIRLError``) or return
finite results, within a time bound (no hang), and never emit a numpy warning.
"""

import warnings

import numpy as np
from helpers import Hang, hang_guard
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import FactIRLError

TIME_LIMIT = 20  # seconds per call: far above any legitimate call here (they take milliseconds)
N_CASES = 150


def _bad_value(rng):
    return rng.choice(np.array([np.nan, np.inf, -np.inf, 1e308, -1e308, 1e200, -5.0, 0.5, 2.0**70, 0.0], dtype=object))


def _array(rng, shape):
    """A random array of roughly the right shape, often malformed."""
    kind = rng.integers(0, 9)
    if kind == 0 and len(shape) > 0:  # wrong shape
        shape = tuple(int(max(0, s + rng.integers(-1, 2))) for s in shape)
    if kind == 1:  # wrong ndim
        shape = shape[:-1] if len(shape) > 1 else shape + (2,)
    x = rng.standard_normal(shape) * 10.0 ** rng.integers(-3, 4)
    if kind == 2 and x.size:
        x.flat[rng.integers(0, x.size)] = _bad_value(rng)
    if kind == 3:
        return x.astype(object) if rng.random() < 0.5 else x.astype(str)
    if kind == 4:
        return x.astype(complex)
    if kind == 5:
        return x.tolist()
    if kind == 6:
        return None
    return x


def _check_result(value):
    for v in value if isinstance(value, tuple) else (value,):
        if isinstance(v, (np.ndarray, float)):
            assert np.all(np.isfinite(v)), f"non-finite result {v!r}"


def _cases(rng):
    mdp = fo.GridWorld(3)
    S, A, n = 9, 4, 2
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((n, S, A)), 2, 4, rng=0)
    mu, pi = fo.empirical_statistics(mdp, demos)
    return [
        ("TabularMDP", lambda: fo.TabularMDP(_array(rng, (S, A, S)), _bad_value(rng) if rng.random() < 0.5 else 0.9)),
        ("optimal_q", lambda: fo.optimal_q(mdp, _array(rng, (n, S, A)))),
        ("policy_evaluation", lambda: fo.policy_evaluation(mdp, _array(rng, (n, S, A)), _array(rng, (n, S, A)))),
        ("boltzmann_policy", lambda: fo.boltzmann_policy(_array(rng, (S, A)), _bad_value(rng))),
        ("policy_matching_loss", lambda: fo.policy_matching_loss(mdp, _array(rng, (n, S, A)), _array(rng, (n, S)), pi)),
        ("policy_matching_loss pi", lambda: fo.policy_matching_loss(mdp, np.zeros((n, S, A)), mu, _array(rng, (n, S, A)))),
        ("residual_jacobian", lambda: fo.objectives.residual_jacobian(mdp, np.zeros((n, S, A)), mu, pi, 5.0, _array(rng, (S * A, 2)))),
        ("sample_demonstrations", lambda: fo.sample_demonstrations(mdp, _array(rng, (n, S, A)), 2, 3, rng=0)),
        ("empirical_statistics", lambda: fo.empirical_statistics(mdp, [_array(rng, (2, 3, 2))])),
        ("deviation", lambda: fo.deviation(mdp, _array(rng, (n, S, A)), _array(rng, (n, S, A)))),
        ("score", lambda: fo.score(mdp, _array(rng, (n, S, A)), np.zeros((n, S, A)))),
        ("pca_dictionary", lambda: fo.pca_dictionary(_array(rng, (5, 8)), 2)),
        ("task_rewards", lambda: fo.task_rewards(_array(rng, (S * A, 2)), _array(rng, (n, 2)), S, A)),
        ("GradIRL features", lambda: fo.GradIRL(features=_array(rng, (S, 3)), max_iter=3).fit(mdp, demos).rewards_),
        ("GradIRL beta", lambda: fo.GradIRL(beta=_bad_value(rng), max_iter=2).fit(mdp, demos).rewards_),
        ("FactIRL init", lambda: fo.FactIRL(n_primitives=2, init=(_array(rng, (S * A, 2)), _array(rng, (n, 2))),
                                            max_iter=2).fit(mdp, demos).rewards_),
        ("FactIRL features", lambda: fo.FactIRL(n_primitives=2, features=_array(rng, (S * A, 3)), max_iter=2,
                                                flat_max_iter=2).fit(mdp, demos).rewards_),
    ]


@pytest.mark.parametrize("seed", range(3))
def test_public_api_raises_own_errors_or_returns_finite_results(seed):
    rng = np.random.default_rng(seed)
    cases = _cases(rng)
    for _ in range(N_CASES // 3):
        name, call = cases[rng.integers(0, len(cases))]
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # numpy overflow / invalid value warnings
            warnings.filterwarnings("ignore", category=fo.exceptions.ConvergenceWarning)
            try:
                with hang_guard(TIME_LIMIT, name):
                    result = call()
            except FactIRLError:
                continue
            except Hang:
                pytest.fail(f"{name} hung (> {TIME_LIMIT} s)")
            except Exception as exc:  # noqa: BLE001 - the point of the test
                pytest.fail(f"{name} raised a raw {type(exc).__name__}: {exc}")
        _check_result(result)
