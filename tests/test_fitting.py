"""What the learners share: each fit built once, the stall rule, the features digest, the reward basis."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
import factirl_opt.tasks.demonstrations as demonstrations_module
import factirl_opt.tasks.task_set as task_set_module
import solvers
from factirl_opt.exceptions import ConvergenceWarning, MaxIterWarning, ValidationError
from factirl_opt.learners.fitting import check_features_digest, first_step_stall
from factirl_opt.learners.start import FLAT_SOLVER
from factirl_opt.tasks.task_set import features_digest, reward_features
from factirl_opt.objectives import Objective
from factirl_opt.tasks.features import StateBroadcast

K = 2


@pytest.fixture
def data(rng, grid3):
    D = fo.random_dictionary(36, K, rng)
    H = fo.random_coefficients(4, K, rng=rng)
    return grid3, fo.sample_demonstrations(grid3, fo.task_rewards(D, H, 9, 4), 4, 6, rng)


class Counts:
    """Counts demonstration parses, objective builds and solver look-ups (by name)."""

    def __init__(self, monkeypatch):
        self.parses, self.objectives, self.solvers = 0, 0, []
        parse, init, resolve = demonstrations_module.parse_demonstrations, Objective.__init__, solvers.resolve_solver

        def counted_parse(*args, **kwargs):
            self.parses += 1
            return parse(*args, **kwargs)

        def counted_init(obj, *args, **kwargs):
            self.objectives += 1
            init(obj, *args, **kwargs)

        def counted_resolve(solver, options=None):
            self.solvers.append(solver)
            return resolve(solver, options)

        for module in (demonstrations_module, task_set_module):  # empirical_statistics', and the task set's
            monkeypatch.setattr(module, "parse_demonstrations", counted_parse)
        monkeypatch.setattr(Objective, "__init__", counted_init)
        monkeypatch.setattr(solvers, "resolve_solver", counted_resolve)


@pytest.mark.parametrize("init", ["pca", "random"])
def test_factirl_fit_parses_builds_and_resolves_once(monkeypatch, data, init):
    mdp, demos = data
    counts = Counts(monkeypatch)
    fo.FactIRL(n_primitives=K, init=init, solver="lbfgs", d_solver="armijo", max_iter=3, flat_max_iter=5).fit(mdp, demos)
    assert counts.parses == 1 and counts.objectives == 1
    # one look-up per solver: the H- and D-solvers, and the flat learner's of the PCA start (FLAT_SOLVER)
    assert sorted(counts.solvers) == sorted(["lbfgs", "armijo"] + ([FLAT_SOLVER] if init == "pca" else []))


def test_gradirl_fit_and_transfer_parse_build_and_resolve_once(monkeypatch, data):
    mdp, demos = data
    model = fo.FactIRL(n_primitives=K, init="random", max_iter=2).fit(mdp, demos)
    counts = Counts(monkeypatch)
    fo.GradIRL(max_iter=3).fit(mdp, demos)
    assert (counts.parses, counts.objectives, counts.solvers) == (1, 1, ["armijo"])
    counts = Counts(monkeypatch)
    model.transfer(mdp, demos[:2], max_iter=3)
    assert (counts.parses, counts.objectives, counts.solvers) == (1, 1, ["armijo"])


def test_the_pca_start_shares_the_fits_objective_with_the_results_of_separate_ones(data):
    """One objective for the flat start and the factorial fit gives what separate objectives gave."""
    mdp, demos = data
    start = fo.Start()  # the start's flat fit: FLAT_SOLVER, its tolerance and saturation rule, no gradient rule
    flat = fo.GradIRL(max_iter=8, solver=FLAT_SOLVER, tol=start.flat_tol, stol=start.flat_stol, gtol=0.0).fit(mdp, demos)
    own = fo.FactIRL(n_primitives=K, max_iter=4, flat_max_iter=8).fit(mdp, demos)
    given = fo.FactIRL(n_primitives=K, max_iter=4).fit(mdp, demos, flat_rewards=flat.rewards_)
    np.testing.assert_array_equal(own.dictionary_, given.dictionary_)
    np.testing.assert_array_equal(own.loss_history_, given.loss_history_)
    assert own.n_evaluations_ == given.n_evaluations_ + flat.n_evaluations_


def test_objective_reset_plans_as_a_fresh_objective(data):
    mdp, demos = data
    used = fo.learners.gradirl.make_objective(mdp, demos, 5.0)
    R = np.random.default_rng(0).standard_normal((4, 9, 4))
    used.loss_and_grad(R)
    used.loss_and_grad(2 * R)
    used.reset()
    fresh = fo.learners.gradirl.make_objective(mdp, demos, 5.0)
    for a, b in zip(used.loss_and_grad(R), fresh.loss_and_grad(R)):
        np.testing.assert_array_equal(a, b)
    assert used.n_evaluations == 3  # the count survives the reset


def test_first_step_stall_rule():
    assert first_step_stall([2.5, 2.5], 1) == ("stalled", "stalled: the first iteration changed nothing (total loss 2.5 "
                                                "before and after)")
    assert first_step_stall([2.5, 2.5], 1, held=True) is None  # a start held by the constraint has converged
    assert first_step_stall([2.0, 1.0], 1) is None
    assert first_step_stall([2.0, 1.0, 1.0], 2) is None
    assert first_step_stall([2.0], 0) is None


def test_gradirl_with_a_tiny_beta_reports_stalled_like_factirl(data):
    mdp, demos = data
    with pytest.warns(ConvergenceWarning, match="GradIRL.fit stalled"):
        flat = fo.GradIRL(beta=1e-8, max_iter=20).fit(mdp, demos)
    assert flat.n_iter_ == 1 and flat.loss_history_[0] == flat.loss_history_[1]
    assert flat.status_ == "stalled" and flat.stop_reason_.startswith("stalled: the first iteration changed nothing")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        fact = fo.FactIRL(n_primitives=K, beta=1e-8, max_iter=5, init="random", rng=0).fit(mdp, demos)
    assert fact.status_ == "stalled" and fact.stop_reason_ == flat.stop_reason_


def test_a_start_held_by_an_l1_penalty_converges_and_a_saturated_one_stalls(data):
    mdp, demos = data
    D = np.linalg.qr(np.random.default_rng(0).standard_normal((36, K)))[0]
    held = fo.transfer_coefficients(mdp, demos, D, h_solver="gn-qp-osqp-sparse", h_solver_options={"alpha": 1e3}, max_iter=5)
    assert held.status == "converged" and np.all(held.coefficients == 0)
    with pytest.warns(ConvergenceWarning, match="stalled at its first step"):
        model = fo.FactIRL(n_primitives=K, init=(1e6 * D, np.ones((4, K))), max_iter=3).fit(mdp, demos)
    assert model.status_ == "stalled"


def test_gradirl_records_its_stop_reason(data):
    mdp, demos = data
    with pytest.warns(MaxIterWarning, match=r"max_iter=2 before its tolerance for 4 of 4 task\(s\): \[0, 1, 2, 3\]"):
        model = fo.GradIRL(max_iter=2).fit(mdp, demos)
    assert model.stop_reason_ == "per row, of 4: 4 at max_iter=2: rows [0, 1, 2, 3]" and model.status_ == "max_iter"
    assert fo.GradIRL(max_iter=200, tol=0.5).fit(mdp, demos).stop_reason_ == "per row, of 4: 4 by relative decrease <= tol=0.5"


def test_features_digest():
    F = np.arange(12.0).reshape(6, 2)
    assert features_digest(None) is None
    assert features_digest(F) == features_digest(F.copy()) and len(features_digest(F)) == 64
    assert features_digest(F) != features_digest(F.reshape(4, 3))  # the shape counts
    G = F.copy()
    G[0, 0] = np.nextafter(0.0, 1.0)
    assert features_digest(F) != features_digest(G)
    check_features_digest(features_digest(F), F, "m")
    with pytest.raises(ValidationError, match="m was fitted with other features"):
        check_features_digest(features_digest(F), G, "m")
    with pytest.raises(ValidationError, match="fitted without features"):
        check_features_digest(None, F, "m")
    with pytest.raises(ValidationError, match="features=None now"):
        check_features_digest(features_digest(F), None, "m")


@pytest.mark.parametrize("how", ["set_attribute", "same_shape_state_features"])
def test_transfer_refuses_other_features_of_the_same_shape(data, how):
    mdp, demos = data
    Phi = np.random.default_rng(0).standard_normal((9, 4))
    model = fo.FactIRL(n_primitives=K, features=Phi, init="random", max_iter=2, rng=0).fit(mdp, demos)
    assert model.features_sha256_ == features_digest(np.repeat(Phi, 4, axis=0))
    model.transfer(mdp, demos[:1], max_iter=2)  # the same features: accepted
    model.features = Phi[::-1].copy() if how == "set_attribute" else Phi + 1e-12
    with pytest.raises(ValidationError, match="fitted with other features than the ones set now"):
        model.transfer(mdp, demos[:1], max_iter=2)
    model.features = None
    with pytest.raises(ValidationError):
        model.transfer(mdp, demos[:1], max_iter=2)


def test_models_without_features_record_no_digest(data):
    mdp, demos = data
    assert fo.GradIRL(max_iter=1).fit(mdp, demos).features_sha256_ is None
    model = fo.FactIRL(n_primitives=K, init="random", max_iter=1).fit(mdp, demos)
    assert model.features_sha256_ is None
    model.features = np.ones((9, 4))
    with pytest.raises(ValidationError, match="fitted without features"):
        model.transfer(mdp, demos[:1])


def test_reward_features(grid3):
    assert reward_features(grid3) is None
    assert isinstance(reward_features(grid3, reward="state"), StateBroadcast)
    assert reward_features(grid3, np.ones((9, 2))).shape == (36, 2)
    with pytest.raises(ValidationError, match="reward must be one of 'state-action', 'state'; got 'states'"):
        reward_features(grid3, reward="states")
    with pytest.raises(ValidationError, match=r"reward='state' .* takes no features \(got features of shape \(9, 2\)\)"):
        reward_features(grid3, np.ones((9, 2)), reward="state")


@pytest.mark.parametrize("learner", [fo.GradIRL, fo.FactIRL])
def test_learners_refuse_state_rewards_with_features(data, learner):
    mdp, demos = data
    with pytest.raises(ValidationError, match="reward='state'"):
        learner(features=np.ones((9, 3)), reward="state").fit(mdp, demos)


def test_features_far_from_order_one_are_named_in_the_overflow(data):
    mdp, demos = data
    Phi = np.random.default_rng(0).standard_normal((9, 4)) * 1e200
    with pytest.raises(ValidationError, match=r"largest \|features\| = .*e\+200.*the features are far from order 1"):
        fo.GradIRL(features=Phi, max_iter=5).fit(mdp, demos)
    with pytest.raises(ValidationError, match=r"the features are far from order 1"):
        # the Armijo flat start overflows on them (an L-BFGS start's first step is scaled to the gradient)
        fo.FactIRL(n_primitives=K, features=Phi, max_iter=2, flat_max_iter=5,
                   solver=fo.SolverSettings(flat_solver="armijo")).fit(mdp, demos)
