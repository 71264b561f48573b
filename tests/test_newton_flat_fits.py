"""The ``newton`` solver in the flat fits of both objectives: each task's weights are those of a
fit of that task alone (per-task convergence), in one environment and in several, and the fit
reaches the loss of the first-order solvers' fits."""

import numpy as np
import pytest

import factirl_opt as fo
from helpers import five_tasks_on_a_small_grid, quiet_fit, three_tasks_on_two_grids

OBJECTIVES = ["policy-matching", "mce"]


@pytest.fixture(scope="module")
def tasks():
    return five_tasks_on_a_small_grid()


@pytest.fixture(scope="module")
def worlds():
    return three_tasks_on_two_grids()


def _assert_alone(together, alone, i):
    np.testing.assert_allclose(together.weights_[i], alone.weights_[0], rtol=0, atol=1e-9)
    assert abs(together.loss_[i] - alone.loss_[0]) <= 1e-10


@pytest.mark.parametrize("age", [1, 3])
@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize("features", [False, True], ids=["tabular", "features"])
def test_flat_fit_equals_each_task_fitted_alone(tasks, objective, features, age):
    mdp, F, demos = tasks
    kw = dict(max_iter=40, solver="newton", solver_options={"hessian_age": age}, objective=objective,
              features=F if features else None)
    together = quiet_fit(fo.GradIRL(**kw), mdp, demos)
    for i in range(len(demos)):
        _assert_alone(together, quiet_fit(fo.GradIRL(**kw), mdp, demos[i:i + 1]), i)


@pytest.mark.parametrize("objective", OBJECTIVES)
def test_flat_fit_over_environments_equals_each_task_alone(worlds, objective):
    mdps, Phis, demos = worlds
    kw = dict(max_iter=40, solver="newton", objective=objective)
    together = quiet_fit(fo.GradIRL(features=Phis, **kw), mdps, demos)
    for i in range(len(demos)):
        _assert_alone(together, quiet_fit(fo.GradIRL(features=[Phis[i]], **kw), [mdps[i]], demos[i:i + 1]), i)


def test_newton_reaches_the_loss_of_lbfgs_in_fewer_evaluations(tasks):
    """MCE on features (p = 4; a smooth likelihood with one minimum here): both solvers converge,
    Newton to a loss no higher (to 1e-6) with fewer planning evaluations."""
    objective = "mce"
    mdp, F, demos = tasks
    fits = {s: quiet_fit(fo.GradIRL(max_iter=300, solver=s, objective=objective, features=F, tol=1e-8, gtol=0.0), mdp, demos)
            for s in ("lbfgs", "newton")}
    assert np.all(fits["newton"].loss_ <= fits["lbfgs"].loss_ + 1e-6)
    assert fits["newton"].n_evaluations_ < fits["lbfgs"].n_evaluations_


def test_factirl_takes_newton_as_its_flat_solver(tasks):
    mdp, F, demos = tasks
    for objective in OBJECTIVES:
        model = quiet_fit(fo.FactIRL(n_primitives=2, features=F, objective=objective, flat_solver="newton", max_iter=3,
                                flat_max_iter=20, rng=0), mdp, demos)
        assert np.all(np.isfinite(model.rewards_))
