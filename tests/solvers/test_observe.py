"""Observing step-solver runs (solvers.observe_runs)."""

import threading

import numpy as np
import pytest
from solver_problems import exp_problem

import solvers
from solvers import SolverOptionError


def _record(seen):
    def callback(solver, problem, result, *, separable, cpu_seconds):
        seen.append((solver, problem, result, separable, cpu_seconds))
    return callback


def test_every_run_in_the_block_is_reported(rng):
    problem, *_ = exp_problem(rng)
    solver = solvers.get_solver("armijo")
    x0 = np.zeros((problem.n_rows, problem.n_params))
    seen = []
    with solvers.observe_runs(_record(seen)) as cb:
        assert callable(cb)
        plain = solver.run(problem, x0, 5)
        separate = solver.run(problem, x0, 5, separable=True)
    after = solver.run(problem, x0, 5)
    assert [(s[0], s[1], s[2], s[3]) for s in seen] == [(solver, problem, plain, False), (solver, problem, separate, True)]
    assert all(s[4] >= 0.0 for s in seen)
    np.testing.assert_array_equal(after.coefficients, plain.coefficients)  # observing changes no result


def test_nested_blocks_and_exceptions_unregister(rng):
    problem, *_ = exp_problem(rng)
    solver = solvers.get_solver("lbfgs")
    x0 = np.zeros((problem.n_rows, problem.n_params))
    outer, inner = [], []
    with solvers.observe_runs(_record(outer)):
        with pytest.raises(SolverOptionError):
            with solvers.observe_runs(_record(inner)):
                solver.run(problem, x0, 2)
                solver.run(problem, x0, 2, separable="yes")  # a run that raises is not reported
        solver.run(problem, x0, 2)
    solver.run(problem, x0, 2)
    assert len(inner) == 1 and len(outer) == 2


def test_runs_in_other_threads_are_reported(rng):
    problem, *_ = exp_problem(rng)
    solver = solvers.get_solver("armijo")
    x0 = np.zeros((problem.n_rows, problem.n_params))
    seen = []
    with solvers.observe_runs(_record(seen)):
        threads = [threading.Thread(target=solver.run, args=(problem, x0, 3)) for _ in range(3)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert len(seen) == 3


def test_callback_must_be_callable():
    with pytest.raises(SolverOptionError, match="callback must be callable; got int"):
        with solvers.observe_runs(1):
            pass
