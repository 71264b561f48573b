"""FactIRL(dictionary_constraint=...): nonnegative and/or sparse unit-norm primitives (docs/maths.md §8b),
and the matching score of learnt primitives against the true ones."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
import solvers
from factirl_opt.evaluation import dictionary_match
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
from factirl_opt.learners import clone
from factirl_opt.learners.dictionary import constrained_dictionary_solver, constrained_start
from factirl_opt.objectives.problems import dictionary_problem
from factirl_opt.learners.fitting import make_objective


@pytest.fixture(scope="module")
def data():
    """Eight tasks on a 4x4 grid from 2 nonnegative sparse primitives, 4 demonstrations each."""
    mdp = fo.GridWorld(size=4, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(5)
    D = np.abs(rng.normal(size=(mdp.n_params, 2))) * (rng.random((mdp.n_params, 2)) < 0.3)
    st = fo.synthetic_tasks(mdp, 8, 4, 6, dictionary=D, rng=rng)
    return mdp, st


def _fit(mdp, demos, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return fo.FactIRL(2, rng=0, max_iter=6, flat_max_iter=10, **kw).fit(mdp, demos)


@pytest.mark.parametrize("constraint", ["nonneg", "sparse", "nonneg-sparse"])
def test_constrained_primitives_are_unit_feasible_and_the_history_counts_the_penalty(data, constraint):
    mdp, st = data
    alpha = 0.02
    m = _fit(mdp, st.demos, dictionary_constraint=fo.DictionaryConstraint(constraint, alpha))
    D = m.dictionary_
    np.testing.assert_allclose(np.linalg.norm(D, axis=0), 1.0, atol=1e-12)
    if constraint.startswith("nonneg"):
        assert np.all(D >= 0)
    penalty = alpha * len(st.demos) * np.abs(D).sum() if constraint.endswith("sparse") else 0.0
    # the fit keeps its best point: the smallest total of the history is its loss plus the penalty
    assert min(m.loss_history_) == pytest.approx(m.loss_.sum() + penalty, rel=1e-10)
    assert m.loss_history_[-1] < m.loss_history_[0]
    free = _fit(mdp, st.demos)
    if constraint.endswith("sparse"):
        assert np.sum(D == 0) > np.sum(free.dictionary_ == 0)
    # transfer works as before with the constrained dictionary fixed
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        m.transfer(mdp, [d[:1] for d in st.demos[:2]], max_iter=3)
    assert m.transfer_coefficients_.shape == (2, 2)


@pytest.mark.parametrize("constraint", ["nonneg", "sparse", "nonneg-sparse"])
def test_the_d_step_decreases_the_penalised_loss_and_stays_feasible(data, constraint):
    """A D-step run with H fixed: feasible at every accepted point, monotone in J + penalty, its
    losses are J + penalty, and its proximal-gradient measure falls."""
    mdp, st = data
    rng = np.random.default_rng(0)
    n, p, k = len(st.demos), mdp.n_params, 2
    solver = constrained_dictionary_solver(solvers.get_solver("armijo"), constraint, 0.01, p, k, n)
    D0, H = constrained_start(solver, rng.normal(size=(p, k)), 0.5 * rng.normal(size=(n, k)), constraint.startswith("nonneg"))
    problem = dictionary_problem(make_objective(mdp, st.demos, 5.0, "policy-matching", "auto"), H)
    res = solver.run(problem, D0.reshape(1, -1), max_iter=60)
    assert np.all(np.diff(res.loss_history) <= 1e-12) and res.loss_history[-1] < 0.5 * res.loss_history[0]
    D = res.coefficients.reshape(p, k)
    np.testing.assert_allclose(np.linalg.norm(D, axis=0), 1.0, atol=1e-12)
    if constraint.startswith("nonneg"):
        assert np.all(D >= 0)
    loss, grad = problem.loss_and_grad(D.reshape(1, -1), np.arange(1))
    assert res.loss[0] == pytest.approx(loss[0] + 0.01 * n * np.abs(D).sum() * constraint.endswith("sparse"), rel=1e-12)
    g0 = solver.optimality(D0.reshape(1, -1), problem.loss_and_grad(D0.reshape(1, -1), np.arange(1))[1])[0]
    assert solver.optimality(D.reshape(1, -1), grad)[0] < g0


def test_the_start_is_moved_onto_the_constraint_keeping_the_rewards_of_the_positive_part():
    solver = constrained_dictionary_solver(solvers.get_solver("armijo"), "nonneg", 0.0, 3, 2, 4)
    D = np.array([[-2.0, 1.0], [-1.0, 0.0], [0.5, 0.0]])
    H = np.ones((4, 2))
    Dc, Hc = constrained_start(solver, D, H, nonneg=True)
    # column 0 is mostly negative: flipped (with its coefficients), then its positive part kept
    np.testing.assert_allclose(Dc[:, 0], np.array([2.0, 1.0, 0.0]) / np.sqrt(5.0))
    np.testing.assert_allclose(Hc[:, 0], -np.linalg.norm(D[:, 0]))
    np.testing.assert_allclose(Dc[:, 1], [1.0, 0.0, 0.0])


def test_a_tuple_start_and_the_residual_model_keep_the_constraint(data):
    mdp, st = data
    rng = np.random.default_rng(1)
    init = (rng.normal(size=(mdp.n_params, 2)), rng.normal(size=(len(st.demos), 2)))
    m = _fit(mdp, st.demos, init=init, dictionary_constraint="nonneg")
    assert np.all(m.dictionary_ >= 0)
    r = _fit(mdp, st.demos, dictionary_constraint="nonneg-sparse", residual_penalty=1.0)
    assert np.all(r.dictionary_ >= 0) and np.any(r.residuals_ != 0)
    np.testing.assert_allclose(np.linalg.norm(r.dictionary_, axis=0), 1.0, atol=1e-12)


def test_constraint_parameters_travel_with_get_params_and_clone():
    m = fo.FactIRL(3, dictionary_constraint=fo.DictionaryConstraint("sparse", alpha=0.5))
    params = m.get_params(deep=True)
    assert params["dictionary_constraint__kind"] == "sparse" and params["dictionary_constraint__alpha"] == 0.5
    c = clone(m)
    assert c.dictionary_constraint == fo.DictionaryConstraint("sparse", 0.5)
    assert clone(m.set_params(dictionary_constraint__alpha=0.25)).get_params(deep=True)["dictionary_constraint__alpha"] == 0.25
    named = fo.FactIRL(3, dictionary_constraint="nonneg")  # a kind's name: its default alpha
    assert clone(named).dictionary_constraint == "nonneg" and named._group("dictionary_constraint").alpha == 0.01


def test_the_former_dictionary_alpha_sets_the_groups_field_with_one_warning():
    with pytest.warns(FutureWarning, match="'dictionary_alpha' is now the field 'alpha' of dictionary_constraint"):
        m = fo.FactIRL(3, dictionary_constraint="sparse", dictionary_alpha=0.5)
    assert m.dictionary_constraint == fo.DictionaryConstraint("sparse", 0.5) and m.dictionary_alpha == 0.5
    with pytest.raises(ValidationError, match="either as one DictionaryConstraint"):
        fo.FactIRL(3, dictionary_constraint=fo.DictionaryConstraint("sparse"), dictionary_alpha=0.5)


@pytest.mark.parametrize("kw, fragment", [
    ({"dictionary_constraint": "positive"}, "dictionary_constraint must be None or one of"),
    ({"dictionary_constraint": fo.DictionaryConstraint("sparse", 0.0)}, "needs alpha > 0"),
    ({"dictionary_constraint": fo.DictionaryConstraint("nonneg", -1.0)}, r"dictionary_constraint\.alpha"),
    ({"dictionary_constraint": fo.DictionaryConstraint(alpha=np.nan)}, r"dictionary_constraint\.alpha"),
    ({"dictionary_constraint": 3}, "dictionary_constraint must be a DictionaryConstraint, None or one of"),
    ({"dictionary_constraint": "nonneg", "d_solver": "lbfgs"}, "d_solver must be 'armijo'"),
    ({"dictionary_constraint": "sparse", "d_solver": "armijo-nonneg"}, "d_solver must be 'armijo'"),
])
def test_bad_constraints_are_refused(data, kw, fragment):
    mdp, st = data
    with pytest.raises(ValidationError, match=fragment):
        fo.FactIRL(2, max_iter=1, flat_max_iter=1, **kw).fit(mdp, st.demos)


def test_dictionary_match_is_invariant_to_order_sign_and_scale(rng):
    T = rng.normal(size=(20, 3))
    L = T[:, [2, 0, 1]] * np.array([-2.0, 0.5, 3.0])
    score, C, matched = dictionary_match(L, T)
    assert score == pytest.approx(1.0)
    np.testing.assert_array_equal(matched, [1, 2, 0])
    assert C.shape == (3, 3) and np.all((C >= 0) & (C <= 1 + 1e-12))
    # one true column orthogonal to every learnt one: it scores 0 in the mean
    E = np.eye(4)
    s, _, m = dictionary_match(E[:, :2], E[:, [0, 2, 3]])
    assert s == pytest.approx(0.5) and m[0] == 0 and np.sum(m >= 0) == 2


@pytest.mark.parametrize("learnt, true", [(np.ones((3, 2)), np.ones((4, 2))), (np.ones(3), np.ones((3, 1))),
                                          (np.ones((3, 0)), np.ones((3, 1))), (np.full((3, 1), np.nan), np.ones((3, 1)))])
def test_dictionary_match_refuses_bad_shapes(learnt, true):
    with pytest.raises(ValidationError):
        dictionary_match(learnt, true)


def test_a_constrained_model_is_saved_and_loaded(data, tmp_path):
    mdp, st = data
    m = _fit(mdp, st.demos, dictionary_constraint=fo.DictionaryConstraint("nonneg-sparse", 0.03))
    loaded = fo.load_model(fo.save_model(m, tmp_path / "m.npz"))
    assert loaded.dictionary_constraint == fo.DictionaryConstraint("nonneg-sparse", 0.03)
    named = _fit(mdp, st.demos, dictionary_constraint="nonneg")  # a kind's name is saved as its group
    assert fo.load_model(fo.save_model(named, tmp_path / "n.npz")).dictionary_constraint == fo.DictionaryConstraint("nonneg")
    np.testing.assert_array_equal(loaded.dictionary_, m.dictionary_)
