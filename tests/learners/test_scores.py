"""The held-out scores of the sharing search (learners.selection.scores): the deviation under a reference reward."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
from factirl_opt.learners import selection
from factirl_opt.learners.fitting import learner_tasks
from factirl_opt.learners.selection import scores, search
from factirl_opt.learners.start import flat_solver
from helpers import two_primitive_feature_tasks


@pytest.fixture(scope="module")
def two_primitives():
    """Eight tasks on a 3x3 grid from a 2-primitive dictionary on 4 state features, 4 demonstrations each."""
    return two_primitive_feature_tasks(8, 4, seed=11)


def _deviation_search(mdp, F, demos, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        search_ = fo.SharingSearch(route="full", score="deviation", n_primitives_grid=(1, 2, 4))
        return fo.FactIRL(rng=0, max_iter=4, features=F, n_primitives="auto", residual_penalty=np.inf,
                          sharing_search=search_, **kw).fit(mdp, demos)


def test_the_deviation_is_the_benchmarks_under_the_range_normalised_reference():
    mdp = fo.GridWorld(size=3, p_success=0.8, gamma=0.9)
    rng = np.random.default_rng(0)
    ref, R = rng.normal(size=(2, 9, 4))
    value = selection.held_out_deviation(mdp, ref, R)
    assert value == pytest.approx(fo.deviation(mdp, ref / (ref.max() - ref.min()), R), rel=1e-12)
    assert 0.0 < value <= 1.0 / (1.0 - mdp.gamma)
    # the reference's scale and offset do not matter; the transferred reward's scale does not either
    assert selection.held_out_deviation(mdp, 3.0 * ref - 5.0, R) == pytest.approx(value, rel=1e-9)
    assert selection.held_out_deviation(mdp, ref, 0.1 * R) == pytest.approx(value, rel=1e-9)
    # acting on the reference itself loses nothing; a constant reference makes every policy optimal
    assert selection.held_out_deviation(mdp, ref, ref) == pytest.approx(0.0, abs=1e-12)
    assert selection.held_out_deviation(mdp, np.full((9, 4), 2.0), R) == 0.0
    # state rewards are one task's reward too
    assert selection.held_out_deviation(mdp, ref[:, 0], R[:, 0]) == pytest.approx(
        fo.deviation(mdp, np.repeat(ref[:, :1], 4, axis=1) / np.ptp(ref[:, 0]), np.repeat(R[:, :1], 4, axis=1)), rel=1e-12)


def test_a_bad_reference_or_reward_is_refused_by_name():
    mdp = fo.GridWorld(size=3)
    with pytest.raises(ValidationError, match=r"rewards must be one task's reward, of shape \(S, A\) = \(9, 4\)"):
        selection.held_out_deviation(mdp, np.zeros((2, 9, 4)), np.zeros((9, 4)))
    with pytest.raises(ValidationError, match="rewards"):
        selection.held_out_deviation(mdp, np.zeros((9, 4)), np.full((9, 4), np.nan))
    with pytest.raises(ValidationError, match="rewards"):
        selection.held_out_deviation(mdp, np.zeros((8, 4)), np.zeros((9, 4)))


def test_the_reference_is_the_flat_fit_of_the_demonstrations_a_transfer_does_not_see(two_primitives):
    mdp, F, R, demos = two_primitives
    learner = fo.FactIRL(features=F, n_primitives="auto")
    tasks = learner_tasks(learner, mdp, demos)
    ref = search.reference_rewards(learner, tasks, 1)
    start = learner._group("start")
    alone = search.flat_start_rewards(learner, learner_tasks(learner, mdp, [d[1:] for d in demos]), flat_solver(learner),
                                      start.flat_tol, start.flat_stol)
    np.testing.assert_allclose(ref, alone, rtol=0, atol=0)
    # the first demonstration, the one a held-out task is transferred from, plays no part
    other = [np.concatenate([demos[-1 - i][:1], d[1:]]) for i, d in enumerate(demos)]
    np.testing.assert_array_equal(search.reference_rewards(learner, learner_tasks(learner, mdp, other), 1), ref)
    assert not np.allclose(search.reference_rewards(learner, tasks, 2), ref)
    with pytest.raises(ValidationError, match=r"after the first 4: task 0 has 4; give every task at least 5"):
        search.reference_rewards(learner, tasks, 4)


def test_a_deviation_score_needs_a_reference_per_held_out_task(two_primitives):
    mdp, F, R, demos = two_primitives
    model = fo.FactIRL(n_primitives=2, features=F, max_iter=2, rng=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(mdp, demos[:6])
    tasks = learner_tasks(model, mdp, demos)
    assert scores.needs_reference("deviation") and not scores.needs_reference("likelihood")
    with pytest.raises(ValidationError, match=r"score='deviation' needs a reference reward per held-out task \(2\); got none"):
        scores._score(model, tasks, [6, 7], 1, "deviation")
    with pytest.raises(ValidationError, match=r"per held-out task \(2\); got 1"):
        scores._score(model, tasks, [6, 7], 1, "deviation", reference=R[:1])
    # with the true rewards as the reference, the score is the transfer's true deviation in units of their range
    value = scores._score(model, tasks, [6, 7], 1, "deviation", reference=R[6:])
    true = [fo.deviation(mdp, R[i] / np.ptp(R[i]), model.transfer_rewards_[j]) for j, i in enumerate((6, 7))]
    np.testing.assert_allclose(value, true, rtol=1e-12)


def test_the_deviation_score_prefers_the_true_number_of_primitives(two_primitives):
    """Two primitives generate the tasks: one underfits every held-out transfer, and the search takes two."""
    mdp, F, R, demos = two_primitives
    model = _deviation_search(mdp, F, demos)
    rows = {r["n_primitives"]: r["score"] for r in selection.validation_rows(model.cv_results_)}
    assert model.n_primitives_ == 2
    assert rows[2] == min(rows.values()) and rows[1] > 10 * rows[2]
    assert set(rows) >= {1, 2, 4}  # the grid, and the bisection's k = 3 between 2 and 4


def test_the_deviation_search_gives_the_same_table_for_the_same_rng_and_fits_its_reference_once(two_primitives, monkeypatch):
    mdp, F, R, demos = two_primitives
    calls = []
    fitted = search.reference_rewards
    monkeypatch.setattr(search, "reference_rewards", lambda *a, **kw: calls.append(1) or fitted(*a, **kw))
    a, b = _deviation_search(mdp, F, demos), _deviation_search(mdp, F, demos)
    assert calls == [1, 1]  # once per search, whatever its folds and candidates
    assert a.cv_results_["mean_test_score"].tolist() == b.cv_results_["mean_test_score"].tolist()
    for name in (n for n in a.cv_results_ if n.endswith("_test_score")):
        np.testing.assert_array_equal(a.cv_results_[name], b.cv_results_[name])
