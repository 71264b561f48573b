"""The planner registry: names, "auto", lookup errors, registering a planner, per-MDP planners."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt import planning
from factirl_opt.exceptions import ValidationError

PLANNERS = fo.available_planners()


def test_available_planners_lists_auto_first():
    assert PLANNERS[0] == "auto" and {"dense", "sparse-lu"} <= set(PLANNERS)
    assert planning.available_planners() == PLANNERS


def test_unknown_planner_lists_the_available_ones(grid3):
    with pytest.raises(ValidationError, match="unknown planner 'lu'; available: " + ", ".join(PLANNERS)):
        fo.optimal_q(grid3, np.zeros((9, 4)), planner="lu")
    with pytest.raises(ValidationError, match="unknown planner 3"):
        fo.policy_matching_loss(grid3, np.zeros((9, 4)), np.full(9, 1 / 9), np.full((9, 4), 0.25), planner=3)
    with pytest.raises(ValidationError, match="unknown planner 'lu'; available: auto, dense, sparse-lu"):
        planning.get_planner(grid3, "lu")


def test_auto_resolves_at_the_measured_crossover():
    small = fo.GridWorld(int(np.sqrt(planning.AUTO_DENSE_MAX_STATES)))
    assert small.n_states <= planning.AUTO_DENSE_MAX_STATES
    assert planning.get_planner(small).name == "dense"
    big = fo.GridWorld(int(np.sqrt(planning.AUTO_DENSE_MAX_STATES)) + 1)
    assert planning.get_planner(big).name == "sparse-lu"
    assert planning.resolve_planner("auto", big.n_states) == "sparse-lu"


def test_one_planner_per_mdp_and_name(grid3):
    assert planning.get_planner(grid3, "dense") is planning.get_planner(grid3, "dense")
    assert planning.get_planner(grid3, "auto") is planning.get_planner(grid3, "dense")
    assert planning.get_planner(grid3, "sparse-lu") is not planning.get_planner(fo.GridWorld(3), "sparse-lu")


def test_a_planner_instance_must_be_bound_to_the_mdp(grid3):
    other = planning.get_planner(fo.GridWorld(3), "dense")
    assert planning.get_planner(other.mdp, other) is other
    with pytest.raises(ValidationError, match="bound to another MDP"):
        planning.get_planner(grid3, other)
    with pytest.raises(ValidationError, match="mdp must be a TabularMDP; got str"):
        planning.get_planner("grid", "dense")


class EchoPlanner(planning.DensePlanner):
    """The dense planner under another name (a registered third-party planner)."""

    name = "echo"


@pytest.fixture
def echo_registered():
    planning.register_planner("echo", EchoPlanner)
    yield
    planning.unregister_planner("echo")


def test_register_planner_makes_it_available_everywhere(grid3, echo_registered):
    assert "echo" in fo.available_planners()
    R = np.random.default_rng(0).standard_normal((2, 9, 4))
    Q, pol = fo.optimal_q(grid3, R, planner="echo")
    np.testing.assert_array_equal(Q, fo.optimal_q(grid3, R, planner="dense")[0])
    assert isinstance(planning.get_planner(grid3, "echo"), EchoPlanner)


def test_register_planner_errors(echo_registered):
    with pytest.raises(ValidationError, match="a planner named 'echo' is already registered"):
        planning.register_planner("echo", EchoPlanner)
    planning.register_planner("echo", EchoPlanner, overwrite=True)
    with pytest.raises(ValidationError, match="other than 'auto'"):
        planning.register_planner("auto", EchoPlanner)
    with pytest.raises(ValidationError, match="non-empty string"):
        planning.register_planner("", EchoPlanner)
    with pytest.raises(ValidationError, match="must be a Planner subclass; got <class 'object'>"):
        planning.register_planner("thing", object)
    with pytest.raises(ValidationError, match="unknown planner 'thing'; available: auto, dense, sparse-lu, echo"):
        planning.unregister_planner("thing")


def test_the_base_classes_are_abstract(grid3):
    with pytest.raises(TypeError):
        planning.Planner(grid3)
    with pytest.raises(TypeError):
        planning.PolicySystem()
