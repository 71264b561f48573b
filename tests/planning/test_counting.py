"""The counting planner: the wrapped planner's results, and the systems it took."""

import numpy as np

import factirl_opt as fo
from factirl_opt.planning import CountingPlanner, get_planner, optimal_q, plan


def test_counting_planner_gives_the_wrapped_results_and_counts_systems_and_solves():
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    R = np.random.default_rng(0).normal(size=(3, 9, 4))
    inner = get_planner(mdp)
    counting = CountingPlanner(inner)
    Q, policy = optimal_q(mdp, R)
    out = plan(counting, R)
    np.testing.assert_array_equal(out.Q, Q)
    np.testing.assert_array_equal(out.policy, policy)
    assert counting.n_systems >= 3 and counting.n_forward >= 3 and counting.n_transpose == 0
    assert counting.n_solves == counting.n_forward + counting.n_transpose
    assert counting.counts()["n_systems"] == counting.n_systems and counting.name == inner.name
    stochastic = np.full((2, 9, 4), 0.25)
    before = counting.n_stochastic_systems
    counting.system(stochastic).solve_transpose(np.ones((2, 9)))
    assert counting.n_stochastic_systems == before + 2 and counting.n_transpose == 2 and counting.n_transpose_calls == 1
