"""The planning memory budget: tasks planned, solved and released chunk by chunk, same results.

Reference: the same evaluations and fits without a budget (every task at once, factorisations
cached between calls). Chunks only change which factorisations are found cached or updated
(none, under a budget), so results agree to floating-point accuracy; a budget that every task
fits in changes nothing at all.
"""

import threading
import weakref

import numpy as np
import pytest
from helpers import random_statistics

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt.exceptions import ValidationError
from factirl_opt.objectives import MCEObjective, PolicyMatchingObjective
from factirl_opt.objectives.environments import MultiEnvironmentObjective
from factirl_opt.planning.budget import (
    ARRAYS_PER_DIRECTION,
    WORK_ARRAYS_PER_TASK,
    check_max_bytes,
    check_planner_options,
    chunk_size,
    effective_budget,
    task_bytes,
)

TOL = dict(rtol=1e-11, atol=1e-13)


@pytest.mark.parametrize("bad", [0, -5, 1.5, float("nan"), float("inf"), "1e9", True, [10]])
def test_bad_budgets_are_refused_naming_the_value(bad):
    with pytest.raises(ValidationError, match="max_bytes") as info:
        check_max_bytes(bad)
    assert repr(bad) in str(info.value)
    with pytest.raises(ValidationError, match="max_bytes"):
        with planning.planning_budget(bad):
            pass  # pragma: no cover - never entered
    assert planning.get_planning_budget() is None
    grid = fo.GridWorld(size=3)
    mu, pi = random_statistics(np.random.default_rng(0), grid, 2)
    with pytest.raises(ValidationError, match=r"planner_options\['max_bytes'\]"):
        PolicyMatchingObjective(grid, mu, pi, 2.0, planner_options={"max_bytes": bad})


def test_planner_options_are_validated():
    assert check_planner_options(None) == {"max_bytes": None}
    assert check_planner_options({"max_bytes": 16e9}) == {"max_bytes": 16 * 10**9}
    with pytest.raises(ValidationError, match="unknown planner_options 'max_memory'; known: max_bytes"):
        check_planner_options({"max_memory": 5})
    with pytest.raises(ValidationError, match="planner_options must be a dict or None; got int 5"):
        check_planner_options(5)


def test_context_budget_nests_and_is_per_thread():
    assert planning.get_planning_budget() is None
    with planning.planning_budget(1000) as budget:
        assert budget == planning.get_planning_budget() == 1000
        with planning.planning_budget(None):
            assert planning.get_planning_budget() is None
        assert effective_budget(None) == 1000 and effective_budget(7) == 7
        seen = []
        worker = threading.Thread(target=lambda: seen.append(planning.get_planning_budget()))
        worker.start()
        worker.join()
        assert seen == [None]  # another thread has its own context
    assert planning.get_planning_budget() is None and effective_budget(None) is None


def test_chunk_sizes():
    assert chunk_size(10, 100, None) == 10  # no budget: one chunk
    assert chunk_size(10, 100, 1000) == 10  # every task fits
    assert chunk_size(10, 300, 1000) == 3
    assert chunk_size(10, 10**6, 1000) == 1  # at least one task per chunk
    assert chunk_size(0, 100, 1) == 1


def test_task_bytes_estimates():
    grid = fo.GridWorld(size=6, p_success=0.7, gamma=0.9)
    dense, sparse = planning.get_planner(grid, "dense"), planning.get_planner(grid, "sparse-lu")
    assert dense.task_bytes() == 8 * 36 * 36
    # the estimate bounds the cached groups and the factorisation in use, whatever the policy
    rng = np.random.default_rng(0)
    biggest = max(sparse.factor(rng.integers(4, size=36)).nbytes for _ in range(20))
    assert sparse.task_bytes() >= (planning.CACHE_GROUPS_PER_TASK + 1) * biggest
    arrays = 8 * 36 * 4
    assert task_bytes(sparse) == sparse.task_bytes() + WORK_ARRAYS_PER_TASK * arrays
    assert task_bytes(sparse, 3) == task_bytes(sparse) + 3 * ARRAYS_PER_DIRECTION * arrays


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(8)
    mdp = fo.GridWorld(size=6, p_success=0.7, gamma=0.9)
    n = 7
    mu, pi = random_statistics(rng, mdp, n)
    shape = (n, mdp.n_states, mdp.n_actions)
    return mdp, mu, pi, rng.standard_normal(shape), rng.standard_normal(shape), rng.standard_normal((mdp.n_params, 3))


def assert_close(got, want):
    for x, y in zip(want, got):
        np.testing.assert_allclose(y, x, **TOL)


@pytest.mark.parametrize("how", ["options", "context"])
@pytest.mark.parametrize("planner", ["dense", "sparse-lu"])
def test_objective_under_budget_equals_unbounded(problem, planner, how):
    mdp, mu, pi, R, dR, F = problem
    free = PolicyMatchingObjective(mdp, mu, pi, 2.0, planner=planner)
    options = {"max_bytes": 1} if how == "options" else None  # one task per chunk
    tight = PolicyMatchingObjective(mdp, mu, pi, 2.0, planner=planner, planner_options=options)
    rows = np.array([6, 2, 3, 0, 5])
    with planning.planning_budget(1 if how == "context" else None):
        for step in range(3):
            Rk = R + 0.2 * step * dR
            assert_close(tight.loss_and_grad(Rk), free.loss_and_grad(Rk))
        assert_close(tight.residual_jacobian(R[rows], rows, F), free.residual_jacobian(R[rows], rows, F))
        la, lb = free.linearize(R[rows], rows), tight.linearize(R[rows], rows)
        assert_close((lb.loss, lb.residual), (la.loss, la.residual))
        for _ in range(2):  # every product plans again: the same products each time
            np.testing.assert_allclose(lb.jvp(dR[rows]), la.jvp(dR[rows]), **TOL)
            np.testing.assert_allclose(lb.vjp(la.residual), la.vjp(la.residual), **TOL)
        k = np.stack([dR[rows], R[rows]], axis=-1)  # k directions at once
        np.testing.assert_allclose(lb.jvp(k), la.jvp(k), **TOL)
    assert free.n_evaluations == tight.n_evaluations == 5  # replayed products are not counted


def test_budget_that_every_task_fits_changes_nothing(problem):
    mdp, mu, pi, R, dR, F = problem
    planning.clear_caches(mdp)
    free = PolicyMatchingObjective(mdp, mu, pi, 2.0, planner="sparse-lu")
    a = [free.loss_and_grad(R + 0.1 * s * dR) for s in range(3)] + [free.residual_jacobian(R, None, F)]
    planning.clear_caches(mdp)
    roomy = PolicyMatchingObjective(mdp, mu, pi, 2.0, planner="sparse-lu", planner_options={"max_bytes": 10**12})
    b = [roomy.loss_and_grad(R + 0.1 * s * dR) for s in range(3)] + [roomy.residual_jacobian(R, None, F)]
    for x, y in zip(a, b):
        for u, v in zip(x, y):
            np.testing.assert_array_equal(v, u)


def test_chunks_release_their_factorisations(problem, monkeypatch):
    """At most one chunk's factorisations are alive at a time, none after the call, and this
    thread's own cache is neither fed nor kept."""
    mdp, mu, pi, R, dR, F = problem
    planner = planning.get_planner(mdp, "sparse-lu")
    planning.clear_caches(mdp)
    PolicyMatchingObjective(mdp, mu, pi, 2.0, planner="sparse-lu").loss_and_grad(R)  # fills this thread's cache
    assert len(planner.factor_cache) > 0
    made, alive_at_creation = [], []
    factor = planner.factor

    def counting(policy_i):
        out = factor(policy_i)
        alive_at_creation.append(sum(ref() is not None for ref in made))
        made.append(weakref.ref(out))
        return out

    monkeypatch.setattr(planner, "factor", counting)
    per_chunk = 2
    budget = per_chunk * task_bytes(planner, F.shape[1])
    tight = PolicyMatchingObjective(mdp, mu, pi, 2.0, planner="sparse-lu", planner_options={"max_bytes": budget})
    for step in range(2):
        tight.loss_and_grad(R + 0.3 * step * dR)
        tight.residual_jacobian(R, None, F)
    lin = tight.linearize(R)
    lin.jvp(dR)
    lin.vjp(lin.residual)
    assert len(made) >= 7  # every task factorised at least once
    assert max(alive_at_creation) < (planning.CACHE_GROUPS_PER_TASK + 1) * per_chunk
    assert all(ref() is None for ref in made)
    assert len(planner.factor_cache) == 0  # emptied by the chunked call, never refilled


def test_mce_under_budget_equals_unbounded(problem):
    mdp, mu, pi, R, dR = problem[:5]
    free = MCEObjective(mdp, mu, pi, 2.0, planner="sparse-lu")
    tight = MCEObjective(mdp, mu, pi, 2.0, planner="sparse-lu", planner_options={"max_bytes": 1})
    for step in range(2):
        assert_close(tight.loss_and_grad(R + step * dR), free.loss_and_grad(R + step * dR))
    assert tight.n_evaluations == free.n_evaluations == 2


@pytest.mark.parametrize("how", ["options", "context"])
def test_many_environments_under_budget(problem, how):
    mdp, mu, pi, R = problem[:4]
    other = fo.GridWorld(size=6, p_success=0.8, gamma=0.9)
    mdps = [mdp, other, mdp, other, mdp, mdp, other]
    free = MultiEnvironmentObjective(mdps, mu, pi, 2.0, planner="sparse-lu")
    options = {"max_bytes": 1} if how == "options" else None
    tight = MultiEnvironmentObjective(mdps, mu, pi, 2.0, planner="sparse-lu", planner_options=options)
    assert all(o.max_bytes == (1 if how == "options" else None) for o in tight.objectives)
    with planning.planning_budget(1 if how == "context" else None):
        assert_close(tight.loss_and_grad(R), free.loss_and_grad(R))
        lin_free, lin_tight = free.linearize(R), tight.linearize(R)
        np.testing.assert_allclose(lin_tight.jvp(R), lin_free.jvp(R), **TOL)


def test_factirl_fit_under_budget_equals_unbounded():
    rng = np.random.default_rng(2)
    mdp = fo.GridWorld(size=5, p_success=0.7, gamma=0.9)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((6, mdp.n_states, mdp.n_actions)), 4, 6, rng)
    kw = dict(n_primitives=2, max_iter=3, init="random", rng=0, planner="sparse-lu", features=rng.random((25, 4)),
              solver="gn-qp-clarabel", d_solver="lbfgs", inner_steps=2)
    planning.clear_caches(mdp)
    a = fo.FactIRL(**kw).fit(mdp, demos)
    with planning.planning_budget(1):
        b = fo.FactIRL(**kw).fit(mdp, demos)
    for name in ("dictionary_", "coefficients_", "loss_"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-10, atol=1e-12, err_msg=name)
    assert a.n_evaluations_ == b.n_evaluations_ and a.n_iter_ == b.n_iter_ == 3


def test_estimators_take_a_budget_of_their_own():
    rng = np.random.default_rng(3)
    mdp = fo.GridWorld(size=5, p_success=0.7, gamma=0.9)
    demos = fo.sample_demonstrations(mdp, rng.standard_normal((6, mdp.n_states, mdp.n_actions)), 4, 6, rng)
    F = rng.random((25, 4))
    kw = dict(n_primitives=2, max_iter=2, init="random", rng=0, planner="sparse-lu", features=F,
              solver="gn-qp-clarabel", d_solver="lbfgs", inner_steps=2)
    seen = []
    spy = PolicyMatchingObjective._chunk  # the chunk rule every evaluation asks: record the budget it sees

    def recording(self, *args, **kwargs):
        seen.append(effective_budget(self.max_bytes))
        return spy(self, *args, **kwargs)

    a = fo.FactIRL(**kw).fit(mdp, demos)
    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(PolicyMatchingObjective, "_chunk", recording)
        b = fo.FactIRL(planner_options={"max_bytes": 1}, **kw).fit(mdp, demos)
    assert seen and set(seen) == {1}
    assert planning.get_planning_budget() is None  # the estimator's budget ends with its fit
    for name in ("dictionary_", "coefficients_", "loss_"):
        np.testing.assert_allclose(getattr(b, name), getattr(a, name), rtol=1e-10, atol=1e-12, err_msg=name)
    assert a.n_evaluations_ == b.n_evaluations_
    new = demos[:2]
    np.testing.assert_allclose(b.transfer(mdp, new), a.transfer(mdp, new), rtol=1e-10, atol=1e-12)
    flat_a = fo.GradIRL(features=F, max_iter=5, planner="sparse-lu").fit(mdp, demos)
    flat_b = fo.GradIRL(features=F, max_iter=5, planner="sparse-lu", planner_options={"max_bytes": 1}).fit(mdp, demos)
    np.testing.assert_allclose(flat_b.weights_, flat_a.weights_, rtol=1e-10, atol=1e-12)


def test_shards_plan_under_the_fit_budget():
    from factirl_opt.objectives.distributed import ShardedObjective
    from factirl_opt.planning.budget import budget_options

    grid = fo.GridWorld(size=3)
    mu, pi = random_statistics(np.random.default_rng(0), grid, 4)
    obj = PolicyMatchingObjective(grid, mu, pi, 2.0)
    assert budget_options(obj) is None
    with planning.planning_budget(5000):
        assert budget_options(obj) == {"max_bytes": 5000}
        sharded = ShardedObjective(obj, 2)
    try:
        assert [spec[1][-1] for spec in sharded.shards.specs] == [{"max_bytes": 5000}] * 2
    finally:
        sharded.close()
    own = PolicyMatchingObjective(grid, mu, pi, 2.0, planner_options={"max_bytes": 7000})
    with planning.planning_budget(5000):
        assert budget_options(own) == {"max_bytes": 7000}  # an objective's own budget wins


@pytest.mark.parametrize("options, match", [({"max_memory": 5}, "unknown planner_options 'max_memory'"),
                                            (5, "planner_options must be a dict or None"),
                                            ({"max_bytes": -1}, r"planner_options\['max_bytes'\]")])
def test_estimators_refuse_bad_planner_options(options, match):
    mdp = fo.GridWorld(size=3)
    demos = fo.sample_demonstrations(mdp, np.random.default_rng(0).standard_normal((2, 9, 4)), 2, 3, 0)
    for model in (fo.GradIRL(max_iter=1, planner_options=options), fo.FactIRL(n_primitives=1, max_iter=1,
                                                                              planner_options=options)):
        with pytest.raises(ValidationError, match=match):
            model.fit(mdp, demos)
