"""The objective's contract (objectives/contract.py): every kind of objective implements it, and
the step problems and learners ask no objective what it can do."""

import ast
import pathlib

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.learners.fitting import task_objective
from factirl_opt.learners.multi_intent_fit import WeightedObjective
from factirl_opt.objectives import Objective, get_objective
from factirl_opt.objectives.contract import TaskObjective
from factirl_opt.objectives.distributed import ShardedObjective
from factirl_opt.objectives.environments import MultiEnvironmentObjective
from factirl_opt.objectives.problems import weights_problem
from factirl_opt.objectives.sharded_environments import ShardedEnvironments
from factirl_opt.objectives.sharding import Execution
from factirl_opt.planning import get_planner, plan
from factirl_opt.tasks.task_set import task_set

ROOT = pathlib.Path(__file__).resolve().parents[2] / "factirl_opt"
KINDS = [Objective, MultiEnvironmentObjective, ShardedObjective, ShardedEnvironments, WeightedObjective]


@pytest.mark.parametrize("cls", KINDS, ids=lambda c: c.__name__)
def test_every_kind_of_objective_implements_the_contract(cls):
    assert issubclass(cls, TaskObjective)
    abstract = {name for name in TaskObjective.__abstractmethods__ if getattr(cls, name, None) is None
                or getattr(getattr(cls, name), "__isabstractmethod__", False)}
    assert abstract == set()
    assert isinstance(cls.builds_problems, bool)
    assert cls.builds_problems == (cls is ShardedObjective)


def test_no_objective_capability_is_probed():
    """No ``hasattr(objective, ...)`` in the objectives and learners: capabilities are declared."""
    found = []
    for path in sorted([*(ROOT / "objectives").rglob("*.py"), *(ROOT / "learners").rglob("*.py")]):
        for n in ast.walk(ast.parse(path.read_text())):
            if (isinstance(n, ast.Call) and isinstance(n.func, ast.Name) and n.func.id == "hasattr" and n.args
                    and isinstance(n.args[0], ast.Name) and n.args[0].id in ("objective", "obj", "sobj")):
                found.append(f"{path.relative_to(ROOT)}:{n.lineno}")
    assert found == []


def test_the_factorial_point_of_an_objective_is_its_gradient(grid3):
    rng = np.random.default_rng(0)
    R = rng.normal(size=(3, 9, 4))
    tasks = task_set(grid3, fo.sample_demonstrations(grid3, R, 3, 5, rng), np.abs(rng.normal(size=(9, 3))))
    obj = task_objective(tasks, 2.0)
    D, H = rng.normal(size=(3, 2)), rng.normal(size=(3, 2))
    loss, gradients = obj.factorial_point(tasks.basis, D, H)
    gH, gD = gradients(D, H)
    G = weights_problem(obj, tasks.basis).loss_and_grad(H @ D.T, np.arange(3))[1]  # Phi^T y_i
    np.testing.assert_allclose(gH, G @ D, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(gD, G.T @ H, rtol=1e-10, atol=1e-12)
    assert obj.reward_limit() > 0 and WeightedObjective(obj, np.ones(3)).reward_limit() == obj.reward_limit()


def test_execution_settings_are_one_value():
    ex = Execution(2, "processes", None, "dense", {"max_bytes": 10**9})
    model = fo.FactIRL(execution=ex)
    assert model.execution is ex and model._group("execution") is ex
    nested = {f"execution__{k}": v for k, v in ex.get_params().items()}
    for cls in (fo.GradIRL, fo.FactIRL, fo.MultiIntentIRL):
        est = cls(execution=ex) if cls is not fo.MultiIntentIRL else cls(2, execution=ex)
        assert {k: v for k, v in est.get_params().items() if k.startswith("execution__")} == nested
    # the former flat names build the same value
    assert fo.FactIRL(n_jobs=2, planner="dense", planner_options={"max_bytes": 10**9}).execution == ex


def test_the_former_per_task_builders_warn_and_build_the_same_problem(grid3):
    from factirl_opt.exceptions import DeprecatedNameWarning
    from factirl_opt.objectives import problems

    rng = np.random.default_rng(1)
    tasks = task_set([grid3, grid3], fo.sample_demonstrations(grid3, rng.normal(size=(2, 9, 4)), 2, 4, rng),
                     [np.ones((9, 2)), np.abs(rng.normal(size=(9, 2)))])
    obj = task_objective(tasks, 2.0)
    W, H, D = rng.normal(size=(2, 2)), rng.normal(size=(2, 2)), rng.normal(size=(2, 2))
    with pytest.warns(DeprecatedNameWarning, match="task_weights_problem"):
        old = problems.task_weights_problem(obj, tasks.basis)
    np.testing.assert_array_equal(old.loss_and_grad(W, np.arange(2))[1],
                                  weights_problem(obj, tasks.basis).loss_and_grad(W, np.arange(2))[1])
    with pytest.warns(DeprecatedNameWarning, match="task_dictionary_problem"):
        old = problems.task_dictionary_problem(obj, H, tasks.basis)
    new = problems.dictionary_problem(obj, H, tasks.basis)
    np.testing.assert_array_equal(old.loss_and_grad(D.reshape(1, -1), None)[1], new.loss_and_grad(D.reshape(1, -1), None)[1])


@pytest.mark.parametrize("name", ["policy-matching", "mce"])
def test_the_policy_and_optimal_values_of_one_call_are_those_of_two(grid3, name):
    """``log_policy_and_values``: the objective's log-policy and ``V*`` of the same rewards, exactly as
    ``log_policy`` and a plan of their own give them (policy matching from one plan)."""
    cls = get_objective(name)
    planner = get_planner(grid3)
    R = np.random.default_rng(0).normal(size=(3, grid3.n_states, grid3.n_actions))
    log_pi, V = cls.log_policy_and_values(planner, R, 2.0)
    np.testing.assert_array_equal(log_pi, cls.log_policy(planner, R, 2.0))
    np.testing.assert_array_equal(V, plan(planner, R).V)
    assert V.shape == (3, grid3.n_states)
