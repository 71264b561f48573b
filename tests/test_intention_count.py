"""Choosing the number of intentions: the criteria's arithmetic, the candidate range's checks,
and MultiIntentIRL(n_intentions="auto") picking the true K on easy problems."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.learners.intention_count import (best_candidate, bic, check_candidates, fold_assignment, free_parameters,
                                         held_out_scores, one_standard_error_choice)


def test_free_parameters_count_flat_and_rank_limited_rewards():
    assert free_parameters(3, 10, None) == 3 * 10 + 2
    # K <= k: the shared model spans every K x p reward matrix, as the flat one
    assert free_parameters(3, 10, 5) == free_parameters(3, 10, None)
    # K > k: rank-k K x p matrices, k (K + p - k) parameters
    assert free_parameters(8, 10, 2) == 2 * (8 + 10 - 2) + 7
    assert free_parameters(1, 4, 1) == 4


def test_bic_is_the_schwarz_formula():
    assert bic(-10.0, 3, 100) == pytest.approx(20.0 + 3 * np.log(100))
    assert best_candidate(np.array([5.0, 2.0, 2.0, 7.0])) == 1


def test_fold_assignment_balances_the_folds():
    folds = fold_assignment(11, 3, np.random.default_rng(0))
    assert sorted(np.bincount(folds)) == [3, 4, 4]


def test_held_out_scores_score_each_episode_with_the_fit_without_its_fold():
    folds = np.array([0, 1, 0, 1, 1])
    seen = []

    def fit(idx, K):
        seen.append((tuple(idx), K))
        return (set(idx.tolist()), K)

    def score(run, idx):
        train, K = run
        assert not train & set(idx.tolist())
        return -float(K) * (1.0 + idx)

    out = held_out_scores(fit, score, [1, 2], folds)
    np.testing.assert_allclose(out, [-(1.0 + np.arange(5)), -2.0 * (1.0 + np.arange(5))])
    assert seen == [((1, 3, 4), 1), ((0, 2), 1), ((1, 3, 4), 2), ((0, 2), 2)]


def test_one_standard_error_rule_prefers_the_smaller_k_within_the_noise():
    rng = np.random.default_rng(0)
    base = rng.normal(-10.0, 1.0, size=50)
    clear = np.stack([base - 3.0, base, base + 0.01 * rng.normal(size=50)])  # K=2 and 3 tie, K=1 far worse
    assert one_standard_error_choice(clear) == 1
    better = np.stack([base - 3.0, base, base + 1.0])  # K=3 better on every episode
    assert one_standard_error_choice(better) == 2
    assert one_standard_error_choice(np.array([[-1.0], [-2.0]])) == 0  # one episode: no noise estimate
    # gains 1.2, 0.8, 1.6, -0.8 (total 2.8): standard error of the total sqrt(4) * 1.052 = 2.104
    close = np.array([[0.0, 0.0, 0.0, 0.0], [1.2, 0.8, 1.6, -0.8]])
    assert one_standard_error_choice(close) == 1 and one_standard_error_choice(close, n_se=1.5) == 0


@pytest.mark.parametrize("given, n, folds, match", [
    (3, 10, None, "pair of integers"),
    ((1, 2, 3), 10, None, "pair of integers"),
    ((1.0, 3), 10, None, "pair of integers"),
    ((True, 3), 10, None, "pair of integers"),
    ((0, 3), 10, None, "1 <= low <= high"),
    ((4, 3), 10, None, "1 <= low <= high"),
    ((1, 11), 10, None, "exceeds the 10 episodes"),
    ((1, 7), 10, 3, "exceeds the 6 episodes outside"),
])
def test_check_candidates_errors(given, n, folds, match):
    with pytest.raises(fo.exceptions.ValidationError, match=match):
        check_candidates(given, n, folds)


def test_check_candidates_range():
    np.testing.assert_array_equal(check_candidates((2, 4), 10, 2), [2, 3, 4])
    np.testing.assert_array_equal(check_candidates((np.int64(1), 6), 9, 3), np.arange(1, 7))


def _tasks(n_tasks):
    mdp = fo.GridWorld(5)
    tasks = fo.synthetic_tasks(mdp, n_tasks, 12, 20, n_primitives=3, rng=1)
    return mdp, tasks, [ep for d in tasks.demos for ep in d]


@pytest.mark.parametrize("n_tasks, selection", [(1, "held-out"), (3, "held-out"), (2, "bic"), (3, "bic")])
def test_auto_picks_the_true_number_of_tasks_on_few_features(n_tasks, selection):
    mdp, tasks, episodes = _tasks(n_tasks)
    em = fo.MultiIntentIRL("auto", n_intentions_range=(1, 4), selection=selection, features=tasks.dictionary,
                           max_iter=5, m_step_max_iter=10, rng=0).fit(mdp, episodes)
    assert em.n_intentions_ == n_tasks and em.rewards_.shape[0] == n_tasks
    np.testing.assert_array_equal(em.n_intentions_candidates_, [1, 2, 3, 4])
    assert em.n_intentions_scores_.shape == (4,) and np.all(np.isfinite(em.n_intentions_scores_))
    if selection == "bic":
        assert np.argmin(em.n_intentions_scores_) == n_tasks - 1
    truth = np.repeat(np.arange(n_tasks), 12)
    assert fo.adjusted_rand_index(truth, em.labels_) > 0.9


def test_auto_default_range_and_given_k_records_it():
    mdp, tasks, episodes = _tasks(1)
    em = fo.MultiIntentIRL("auto", selection="bic", features=tasks.dictionary, max_iter=2, m_step_max_iter=3,
                           rng=0).fit(mdp, episodes[:6])
    np.testing.assert_array_equal(em.n_intentions_candidates_, np.arange(1, 7))
    fixed = fo.MultiIntentIRL(2, features=tasks.dictionary, max_iter=2, m_step_max_iter=3, rng=0).fit(mdp, episodes[:6])
    assert fixed.n_intentions_ == 2 and not hasattr(fixed, "n_intentions_scores_")
    em.n_intentions = 2  # refitting with a given K drops the earlier selection's record
    em.fit(mdp, episodes[:6])
    assert em.n_intentions_ == 2 and not hasattr(em, "n_intentions_candidates_")


@pytest.mark.parametrize("kwargs, match", [
    (dict(n_intentions="many"), "positive integer or 'auto'"),
    (dict(n_intentions="auto", selection="aic"), "selection must be one of"),
    (dict(n_intentions="auto", n_folds=1), "n_folds"),
    (dict(n_intentions="auto", n_folds=7), "n_folds=7 exceeds"),
    (dict(n_intentions="auto", init=np.zeros(6, dtype=int)), "named init"),
    (dict(n_intentions="auto", n_intentions_range=(0, 2)), "1 <= low <= high"),
    (dict(n_intentions="auto", n_intentions_range=(1, 5)), "exceeds the 4 episodes outside"),
    (dict(n_intentions="auto", selection="bic", n_intentions_range=(1, 7)), "exceeds the 6 episodes"),
])
def test_auto_error_paths(kwargs, match):
    mdp, _, episodes = _tasks(1)
    with pytest.raises(fo.exceptions.ValidationError, match=match):
        fo.MultiIntentIRL(max_iter=1, **kwargs).fit(mdp, episodes[:6])
