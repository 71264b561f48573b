"""The reward basis: one type for every kind of reward features (tasks/basis.py)."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.learners.dictionary import pca_dictionary
from factirl_opt.tasks.basis import (
    ComposedBasis,
    RewardBasis,
    SharedBasis,
    StateBasis,
    TabularBasis,
    TaskBasis,
    as_basis,
)
from factirl_opt.tasks.features import StateBroadcast, TaskFeatures, linear_rewards
from factirl_opt.tasks.task_set import task_set

S, A = 6, 3


def _kinds(rng):
    """One basis of each kind over 3 tasks of S states and A actions (the per-task one ragged)."""
    F = rng.normal(size=(S * A, 4))
    per_task = TaskFeatures([rng.normal(size=(S, 4)), rng.normal(size=(4 * A, 4)), rng.normal(size=(S * A, 4))],
                            [S, 4, S], A)
    return {"tabular": TabularBasis(S, A), "state": StateBasis(S, A), "shared": SharedBasis(F, S, A),
            "per-task": TaskBasis(per_task), "composed": SharedBasis(F, S, A).compose(rng.normal(size=(4, 2)))}


def _grads(basis, rng, rows):
    """Random reward gradients (S_i, A) of tasks ``rows``, shaped like the basis' rewards."""
    R = basis.rewards(np.zeros((len(rows), basis.n_params)), rows)
    return [rng.normal(size=np.shape(r)) for r in R] if isinstance(R, list) else rng.normal(size=R.shape)


def _dot(a, b):
    return sum(float(np.sum(np.asarray(x) * np.asarray(y))) for x, y in zip(a, b))


@pytest.mark.parametrize("kind", ["tabular", "state", "shared", "per-task", "composed"])
def test_pull_is_the_adjoint_of_rewards_and_dense_is_the_matrix(kind):
    rng = np.random.default_rng(0)
    basis = _kinds(rng)[kind]
    rows = np.array([2, 0])
    W = rng.normal(size=(2, basis.n_params))
    Y = _grads(basis, rng, rows)
    R = basis.rewards(W, rows)
    np.testing.assert_allclose(_dot(R, Y), np.sum(W * basis.pull(Y, rows)), rtol=1e-12)
    for j, F in enumerate(basis.dense(rows)):  # Phi_i w_i, row s * A + a
        np.testing.assert_allclose(np.reshape(R[j], -1), F @ W[j], rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("kind", ["tabular", "state", "shared", "per-task"])
def test_the_dictionary_products_are_those_of_the_composed_basis(kind):
    rng = np.random.default_rng(1)
    basis = _kinds(rng)[kind]
    D, H = rng.normal(size=(basis.n_params, 2)), rng.normal(size=(3, 2))
    Y = _grads(basis, rng, np.arange(3))
    composed = basis.compose(D)
    for R in (basis.factorial_rewards(D, H), basis.dictionary_rewards(D, H)):
        np.testing.assert_allclose(np.concatenate([np.ravel(r) for r in R]),
                                   np.concatenate([np.ravel(r) for r in composed.rewards(H, np.arange(3))]), rtol=1e-10)
    G = basis.pull(Y, np.arange(3))  # Phi_i^T y_i
    np.testing.assert_allclose(basis.dictionary_gradient(Y, H), G.T @ H, rtol=1e-10, atol=1e-12)
    gH, gD = basis.factorial_gradients(Y, D, H)
    np.testing.assert_allclose(gH, G @ D, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(gD, G.T @ H, rtol=1e-10, atol=1e-12)
    np.testing.assert_allclose(basis.point_pull(Y) @ D, gH, rtol=1e-10, atol=1e-12)


def test_a_per_task_basis_serves_its_last_products_again_only_for_equal_inputs():
    import pickle

    rng = np.random.default_rng(4)
    features = TaskFeatures([rng.normal(size=(S, 4)), rng.normal(size=(S * A, 4))], [S, S], A)
    basis = TaskBasis(features)
    D, H, Y = rng.normal(size=(4, 2)), rng.normal(size=(2, 2)), rng.normal(size=(2, S, A))

    def fresh(D, H, Y):  # a new basis: nothing kept
        return TaskBasis(features).factorial_rewards(D, H), TaskBasis(features).factorial_gradients(Y, D, H)

    for _ in range(2):  # the second time from what was kept: the same bits
        R, (gH, gD) = basis.factorial_rewards(D, H), basis.factorial_gradients(Y, D, H)
        R0, (gH0, gD0) = fresh(D, H, Y)
        for got, want in ((R, R0), (gH, gH0), (gD, gD0)):
            np.testing.assert_array_equal(got, want)
    D[1, 0] += 1.0  # changed in place: what was kept is not served
    Y[1, 2, 0] -= 1.0
    R, (gH, gD) = basis.factorial_rewards(D, H), basis.factorial_gradients(Y, D, H)
    R0, (gH0, gD0) = fresh(D, H, Y)
    for got, want in ((R, R0), (gH, gH0), (gD, gD0)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(basis.compose(D).rewards(H), R0)
    copy = pickle.loads(pickle.dumps(basis))  # not pickled
    assert copy._last_times is None and copy._last_pull is None
    np.testing.assert_array_equal(copy.factorial_rewards(D, H), R0)


def test_a_row_subset_and_the_digest():
    rng = np.random.default_rng(2)
    kinds = _kinds(rng)
    per_task = kinds["per-task"]
    sub = per_task.subset([2, 1])
    W = rng.normal(size=(2, 4))
    for j, i in enumerate([2, 1]):
        np.testing.assert_array_equal(sub.rewards(W)[j], per_task.rewards(W[[j]], [i])[0])
    assert kinds["shared"].subset([1]) is kinds["shared"]
    assert kinds["shared"].digest() == SharedBasis(kinds["shared"].features.copy(), S, A).digest()
    assert kinds["tabular"].digest() is None and kinds["state"].digest() is None and per_task.digest() is None


def test_as_basis_reads_every_older_form():
    F = np.ones((S * A, 2))
    assert isinstance(as_basis(None, S, A), TabularBasis) and isinstance(as_basis(F, S, A), SharedBasis)
    assert isinstance(as_basis(StateBroadcast(S, A), S, A), StateBasis)
    tf = TaskFeatures([F], [S], A)
    assert isinstance(as_basis(tf), TaskBasis)
    basis = TabularBasis(S, A)
    assert as_basis(basis) is basis
    with pytest.raises(ValidationError, match="numbers of states and actions"):
        as_basis(F)


def test_point_rewards_refuse_what_the_planner_would_overflow_on():
    basis = SharedBasis(np.ones((S * A, 2)), S, A)
    with pytest.raises(ValidationError, match="features @ weights overflow"):
        basis.point_rewards(np.full((1, 2), 1e300), None, 1e10)
    with pytest.raises(ValidationError, match="other environments|cannot fit"):
        basis.check_environments([S + 1], A)
    with pytest.raises(ValidationError, match="one MDP"):
        TabularBasis(S, A).check_environments([S, S], A + 1)


# ----------------------------------------------------------------------------- a new kind of features plugs in


class LowRankBasis(RewardBasis):
    """Features ``Phi = U V^T`` (S*A, p) of rank r, never formed: ``Phi w = U (V^T w)`` and
    ``Phi^T y = V (U^T y)``. Defined here only: the learners and objectives take it unchanged."""

    def __init__(self, U, V, n_states, n_actions):
        self.U, self.V = np.asarray(U, dtype=float), np.asarray(V, dtype=float)
        self.n_states, self.n_actions, self.n_params = n_states, n_actions, self.V.shape[0]

    def rewards(self, weights, rows=None, names=None):
        W = np.asarray(weights, dtype=float)
        return np.einsum("mr,pr,np...->nm...", self.U, self.V, W).reshape(len(W), self.n_states, self.n_actions,
                                                                          *W.shape[2:])

    def pull(self, grads, rows=None):
        Y = np.asarray(grads, dtype=float).reshape(len(grads), -1)
        return (Y @ self.U) @ self.V.T

    def dense(self, rows=None):
        return [self.U @ self.V.T] * (1 if rows is None else len(np.atleast_1d(rows)))

    def check_environments(self, n_states, n_actions):
        if n_actions != self.n_actions or any(s != self.n_states for s in np.atleast_1d(n_states)):
            raise ValidationError(f"low-rank features for S = {self.n_states}, A = {self.n_actions}")


@pytest.fixture(scope="module")
def low_rank_problem():
    rng = np.random.default_rng(3)
    mdp = fo.GridWorld(size=3, p_success=0.8, gamma=0.9)
    n_states, n_actions = mdp.n_states, mdp.n_actions
    basis = LowRankBasis(rng.normal(size=(n_states * n_actions, 3)), rng.normal(size=(5, 3)), n_states, n_actions)
    W = rng.normal(size=(4, 5))
    R = basis.rewards(W)
    demos = fo.sample_demonstrations(mdp, R, 8, 10, rng=rng)
    return mdp, basis, demos


def test_a_basis_defined_outside_the_library_fits_gradirl(low_rank_problem):
    mdp, basis, demos = low_rank_problem
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        model = fo.GradIRL(beta=2.0, features=basis, max_iter=20).fit(mdp, demos)
    assert model.weights_.shape == (4, 5) and model.loss_history_[-1] < model.loss_history_[0]
    np.testing.assert_allclose(model.rewards_, basis.rewards(model.weights_), rtol=1e-12)


@pytest.mark.parametrize("init", ["pca", "random"])
def test_a_basis_defined_outside_the_library_fits_factirl_and_transfers(low_rank_problem, init):
    mdp, basis, demos = low_rank_problem
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        model = fo.FactIRL(2, beta=2.0, features=basis, init=init, rng=0, max_iter=5, flat_max_iter=10,
                           transfer_max_iter=10).fit(mdp, demos)
        assert model.dictionary_.shape == (5, 2) and model.loss_history_[-1] <= model.loss_history_[0]
        np.testing.assert_allclose(model.rewards_, basis.rewards(model.coefficients_ @ model.dictionary_.T),
                                   rtol=1e-10, atol=1e-12)
        H = model.transfer(mdp, demos[:2])
    assert H.shape == (2, 2) and np.all(np.isfinite(model.transfer_loss_))
    np.testing.assert_allclose(model.transfer_rewards_, basis.rewards(H @ model.dictionary_.T), rtol=1e-10, atol=1e-12)


def test_a_basis_defined_outside_the_library_refuses_another_environment(low_rank_problem):
    mdp, basis, demos = low_rank_problem
    with pytest.raises(ValidationError, match="low-rank features"):
        task_set(fo.GridWorld(size=4), demos, basis)


def test_the_default_start_is_the_pca_of_the_rewards(low_rank_problem):
    """The generic start (PCA in the metric Phi^T Phi) spans the rewards' principal directions."""
    mdp, basis, demos = low_rank_problem
    W = np.random.default_rng(4).normal(size=(4, 5))
    D, H = basis.start_dictionary(basis.start_points(W), 2, 0, pca_dictionary)
    X = basis.rewards(W).reshape(4, -1)
    Dr, Hr = pca_dictionary(X, 2, 0)
    np.testing.assert_allclose(np.abs(basis.rewards(H @ D.T).reshape(4, -1)), np.abs(Hr @ Dr.T), rtol=1e-8, atol=1e-10)
    assert isinstance(basis.compose(D), ComposedBasis)


def test_a_basis_defined_outside_the_library_serves_the_functions_and_multi_intent(low_rank_problem):
    mdp, basis, demos = low_rank_problem
    rng = np.random.default_rng(5)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        fit = fo.fit_factorial(mdp, demos, rng.normal(size=(5, 2)), 0.1 * rng.normal(size=(4, 2)), base_features=basis,
                               max_iter=3)
        assert fit.loss_history[-1] < fit.loss_history[0]
        moved = fo.transfer_coefficients(mdp, demos[:2], fit.dictionary, base_features=basis, max_iter=3)
        np.testing.assert_allclose(moved.rewards, basis.rewards(moved.coefficients @ fit.dictionary.T), rtol=1e-10, atol=1e-12)
        episodes = [ep for task in demos for ep in task]
        mixture = fo.MultiIntentIRL(n_intentions=2, n_primitives=2, features=basis, max_iter=3, rng=0).fit(mdp, episodes)
    np.testing.assert_allclose(mixture.rewards_, basis.rewards(mixture.coefficients_ @ mixture.dictionary_.T),
                               rtol=1e-10, atol=1e-12)


def test_the_rank_of_a_basis_is_the_reward_directions_it_spans(low_rank_problem):
    """A sharing search caps its candidate k at it: the rank of the mean Gram matrix, not p."""
    mdp, basis, demos = low_rank_problem
    assert basis.n_params == 5 and basis.rank(4) == 3
    S, A = mdp.n_states, mdp.n_actions
    assert TabularBasis(S, A).rank(4) == S * A
    Phi = np.random.default_rng(6).normal(size=(S * A, 2)) @ np.random.default_rng(7).normal(size=(2, 4))  # rank 2
    shared = task_set(mdp, demos, Phi).basis
    assert shared.n_params == 4 and shared.rank(4) == 2


# ----------------------------------------------------------------------------- the boundary of a basis' outputs


class FaultyBasis(LowRankBasis):
    """The low-rank basis with one fault: what a user's basis may return by mistake."""

    def __init__(self, U, V, n_states, n_actions, fault):
        super().__init__(U, V, n_states, n_actions)
        self.fault = fault
        if fault == "n_params":
            self.n_params = "5"

    def rewards(self, weights, rows=None, names=None):
        R = super().rewards(weights, rows, names)
        return {"shape": lambda: R[:, :-1], "nan": lambda: R * np.nan, "none": lambda: None,
                "complex": lambda: R + 0j}.get(self.fault, lambda: R)()

    def pull(self, grads, rows=None):
        G = super().pull(grads, rows)
        return {"pull-nan": lambda: np.full_like(G, np.nan), "pull-shape": lambda: G[:, :-1]}.get(self.fault, lambda: G)()

    def dense(self, rows=None):
        out = super().dense(rows)
        return [np.full_like(F, np.nan) for F in out] if self.fault == "dense-nan" else out


@pytest.mark.parametrize("fault, message", [
    ("shape", r"FaultyBasis\.rewards\(\) must return rewards of shape \(S_i, A\) = \(9, 4\) per row .*row 0 has shape \(8, 4\)"),
    ("nan", r"FaultyBasis\.rewards\(\) returned rewards that are not finite \(nan at index \(0, 0, 0\)\) for finite inputs"),
    ("none", r"FaultyBasis\.rewards\(\) must return rewards as numpy arrays; got NoneType"),
    ("complex", r"FaultyBasis\.rewards\(\) must return rewards of real floating-point numbers; got dtype complex128"),
    ("pull-nan", r"FaultyBasis\.pull\(\) returned weight gradients that are not finite"),
    ("pull-shape", r"FaultyBasis\.pull\(\) must return shape \(r, p\) = \(4, 5\) .*; got \(4, 4\)"),
    ("dense-nan", r"FaultyBasis\.dense\(\) returned dense rows that are not finite \(nan at index \(0, 0\) of matrix 0\)"),
    ("n_params", r"FaultyBasis\.n_params must be an integer >= 1; got '5' \(str\)"),
])
@pytest.mark.parametrize("learner", ["GradIRL", "FactIRL"])
def test_what_a_basis_defined_outside_the_library_returns_is_checked_where_it_enters(low_rank_problem, fault, message,
                                                                                      learner):
    """Each fault is a ValidationError naming the basis class, the method and what was wrong (before: numpy's
    IndexError in the planner, an "overflow ... divide by" message for NaN or None rewards with zero weights,
    complex rewards_ fitted silently, eigh failing on NaN dense rows, a str/int comparison)."""
    mdp, basis, demos = low_rank_problem
    faulty = FaultyBasis(basis.U, basis.V, basis.n_states, basis.n_actions, fault)
    model = (fo.GradIRL(beta=2.0, features=faulty, max_iter=5) if learner == "GradIRL" else
             fo.FactIRL(2, beta=2.0, features=faulty, rng=0, max_iter=3, flat_max_iter=5))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        with pytest.raises(ValidationError, match=message):
            model.fit(mdp, demos)


def test_a_basis_that_really_overflows_keeps_the_overflow_message(low_rank_problem):
    mdp, basis, _ = low_rank_problem
    for scale in (1e200, 1e307):  # rewards beyond the planner's limit; rewards that are inf
        with pytest.raises(ValidationError, match=r"features @ weights overflow float64"):
            basis.point_rewards(np.full((1, 5), scale), None, 1e10)


@pytest.mark.parametrize("make, message", [
    (lambda F: SharedBasis(np.where(np.arange(F.size).reshape(F.shape) == 5, np.nan, F), S, A),  # entry 5 = (1, 1)
     r"SharedBasis: the features must be finite; found nan at index \(1, 1\)"),
    (lambda F: SharedBasis(F[:-1], S, A), r"SharedBasis: the features must have shape \(S\*A, p\) = \(\d+, p >= 1\); got"),
    (lambda F: linear_rewards(F[:-1], np.zeros((1, 4)), S, A), r"the features must have shape \(S\*A, p\)"),
    (lambda F: linear_rewards(F, np.zeros((1, 3)), S, A), r"the weights must have shape \(n, p\) = \(n, 4\)"),
    (lambda F: linear_rewards(F, np.full((1, 4), np.nan), S, A), r"not finite: the weights hold nan at index \(0, 0\)"),
])
def test_the_built_in_kinds_name_bad_features_not_an_overflow(make, message):
    """Wrong-shape or NaN features given to the built-in kinds were reported as an overflow ("rescale them
    (e.g. divide by nan)"); the overflow message is left for real overflow."""
    F = np.random.default_rng(0).normal(size=(S * A, 4))
    with pytest.raises(ValidationError, match=message) as info:
        make(F)
    assert "overflow" not in str(info.value)
