"""Minka's evidence for the number of primitives (learners.evidence) and the search route that reads k from it."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, ValidationError
from factirl_opt.learners import selection
from factirl_opt.learners.selection import evidence, routes, rules, scores, search
from factirl_opt.learners.selection.evidence import (
    confirmation_primitives, evidence_penalties, evidence_primitives, flat_start_evidence, flat_start_points, laplace_rank_evidence, pca_rank_evidence,
    plausible_ranks,
)
from factirl_opt.learners.fitting import learner_tasks
from factirl_opt.learners.selection import ROUTES, SharingSearch
from factirl_opt.tasks.task_set import task_set
from helpers import two_primitive_feature_tasks


def _low_rank(n, d, k, signal, rng):
    """n samples in d dimensions: k directions of standard deviation ``signal`` plus unit noise."""
    return rng.standard_normal((n, k)) @ (signal * rng.standard_normal((k, d))) + rng.standard_normal((n, d))


@pytest.mark.parametrize("n, d, k", [(300, 30, 5), (20, 200, 4), (40, 40, 3), (6, 100, 2)])
def test_the_evidence_finds_the_rank_of_low_rank_data_plus_noise(n, d, k):
    rng = np.random.default_rng(n + d + k)
    log_ev, rank = pca_rank_evidence(_low_rank(n, d, k, 3.0, rng))
    assert rank == k
    assert log_ev.shape == (min(n, d),) and log_ev[k] == log_ev.max()
    # no direction at all: isotropic noise is k = 0, with or without a mean removed
    assert pca_rank_evidence(rng.standard_normal((n, d)))[1] == 0
    assert pca_rank_evidence(rng.standard_normal((n, d)), center=True)[1] == 0


def test_the_evidence_does_not_depend_on_the_scale_and_takes_an_exact_rank():
    rng = np.random.default_rng(0)
    X = _low_rank(50, 12, 3, 2.0, rng)
    a, ka = pca_rank_evidence(X)
    b, kb = pca_rank_evidence(1e3 * X)
    np.testing.assert_allclose(a - a.max(), b - b.max(), atol=1e-6 * np.abs(a).max())
    assert ka == kb
    exact = rng.standard_normal((50, 2)) @ rng.standard_normal((2, 12))  # no noise: the rank itself
    assert pca_rank_evidence(exact)[1] == 2


def test_the_evidence_of_a_spectrum_is_minkas_formula():
    """k = 0 is the isotropic model; for k = 1 of a two-value spectrum every term written out (Minka 2000)."""
    from scipy.special import gammaln

    n = 10
    lam = np.array([4.0, 1.0])
    ev = laplace_rank_evidence(lam[::-1], n)  # any order
    assert ev[0] == pytest.approx(-0.5 * n * 2 * np.log(2.5))
    d, k, v = 2, 1, 1.0
    log_pu = -np.log(2.0) + gammaln(d / 2.0) - d / 2.0 * np.log(np.pi)
    log_az = np.log(n * (4.0 - 1.0) * (1.0 / v - 1.0 / 4.0))
    m = d * k - k * (k + 1) / 2.0
    expected = (log_pu - 0.5 * n * np.log(4.0) - 0.5 * n * (d - k) * np.log(v) + 0.5 * (m + k) * np.log(2 * np.pi)
                - 0.5 * log_az - 0.5 * k * np.log(n))
    assert ev[1] == pytest.approx(expected)
    assert laplace_rank_evidence([1.0, 0.0, 0.0], 5)[2] == -np.inf  # a zero k-th eigenvalue
    assert laplace_rank_evidence([3.0, 2.0, 1.0, 0.5], 5, max_rank=1).shape == (2,)


@pytest.mark.parametrize("seed, n, d, k", [(0, 200, 10, 3), (1, 500, 20, 4), (2, 60, 8, 2), (3, 300, 15, 6)])
def test_the_centred_evidence_chooses_as_scikit_learns_pca_mle(seed, n, d, k):
    decomposition = pytest.importorskip("sklearn.decomposition")
    X = _low_rank(n, d, k, 1.0, np.random.default_rng(seed)) + 5.0  # a mean, which the centred evidence removes
    chosen = decomposition.PCA(n_components="mle", svd_solver="full").fit(X).n_components_
    log_ev, _ = pca_rank_evidence(X, center=True)
    assert int(np.argmax(log_ev[1:])) + 1 == chosen  # scikit-learn does not consider k = 0


@pytest.mark.parametrize("call, message", [
    (lambda: laplace_rank_evidence([1.0], 5), r"spectrum must hold at least 2 non-negative eigenvalues"),
    (lambda: laplace_rank_evidence([1.0, -0.5], 5), r"spectrum must hold at least 2 non-negative eigenvalues"),
    (lambda: laplace_rank_evidence([0.0, 0.0], 5), r"not all zero"),
    (lambda: laplace_rank_evidence([1.0, np.nan], 5), r"spectrum"),
    (lambda: laplace_rank_evidence([[1.0, 0.5]], 5), r"spectrum"),
    (lambda: laplace_rank_evidence([1.0, 0.5], 0), r"n_samples must be an integer >= 1"),
    (lambda: laplace_rank_evidence([1.0, 0.5, 0.2], 4, max_rank=3), r"max_rank must be an integer"),
    (lambda: pca_rank_evidence(np.ones((1, 4))), r"X must have at least 2 rows \(samples\) and 2 columns; got \(1, 4\)"),
    (lambda: pca_rank_evidence(np.ones((2, 4)), center=True), r"X must have at least 3 rows"),
    (lambda: pca_rank_evidence(np.ones((5, 1))), r"and 2 columns; got \(5, 1\)"),
    (lambda: pca_rank_evidence(np.zeros((5, 3))), r"X is all zero"),
    (lambda: pca_rank_evidence(np.ones((5, 3)), center=True), r"X is all zero \(after centring\)"),
    (lambda: pca_rank_evidence(np.ones((5, 3)), max_rank=-1), r"max_rank must be an integer >= 0"),
    (lambda: evidence_primitives(-1, 4), r"rank must be an integer >= 0"),
    (lambda: evidence_primitives(2, 0), r"k_max must be an integer >= 1"),
    (lambda: evidence_primitives(2, 4, n_train=0), r"n_train must be an integer >= 1"),
    (lambda: evidence_primitives(3, 4, n_train=8, largest_plausible=2), r"largest_plausible must be an integer >= 3"),
    (lambda: confirmation_primitives(0, 4, 40), r"k must be an integer >= 1"),
    (lambda: confirmation_primitives(2, 0, 40), r"k_max must be an integer >= 1"),
    (lambda: confirmation_primitives(2, 4, 0), r"n_train must be an integer >= 1"),
    (lambda: plausible_ranks([[0.0, 1.0]]), r"log_evidence must be a 1-d array"),
    (lambda: plausible_ranks([0.0, np.nan]), r"log_evidence must be a 1-d array .* no NaN"),
    (lambda: plausible_ranks([-np.inf, -np.inf]), r"with a finite one"),
    (lambda: plausible_ranks([0.0, 1.0], -1.0), r"log_bayes_factor must be a finite number >= 0; got -1.0"),
    (lambda: plausible_ranks([0.0, 1.0], np.inf), r"log_bayes_factor must be a finite number >= 0; got inf"),
])
def test_bad_inputs_are_refused(call, message):
    with pytest.raises(ValidationError, match=message):
        call()


def test_the_candidates_are_the_evidences_k_half_and_twice_it_at_three_penalties():
    assert evidence_primitives(0, 8) == []
    assert evidence_primitives(1, 8) == [1, 2]
    assert evidence_primitives(3, 8) == [2, 3, 6]
    assert evidence_primitives(5, 8) == [3, 5, 8]
    assert evidence_primitives(14, 8) == [7, 8]
    assert evidence_primitives(14, 3) == [3]
    # more primitives than half the training tasks of a fold: the tasks share little, flat
    assert evidence_primitives(4, 8, n_train=16) == [2, 4, 8] and evidence_primitives(5, 8, n_train=9) == []
    assert evidence_primitives(4, 8, n_train=8) == [2, 4]  # 2k capped at two training tasks a primitive
    # a plausible rank above half the training tasks: flat too
    assert evidence_primitives(1, 8, n_train=3) == [1] and evidence_primitives(1, 8, n_train=3, largest_plausible=2) == []
    assert evidence_primitives(1, 8, n_train=4) == [1, 2]  # at most two training tasks a primitive
    assert evidence_primitives(3, 8, n_train=12, largest_plausible=3) == [2, 3, 6]
    # the confirmation: k - 1, k and k + 1 from 8 training tasks a primitive
    assert confirmation_primitives(6, 67, 66) == [5, 6, 7] and confirmation_primitives(9, 67, 66) == []
    assert confirmation_primitives(1, 9, 8) == [1, 2] and confirmation_primitives(4, 4, 40) == [3, 4]
    assert confirmation_primitives(5, 30, 39) == [] and evidence.CONFIRM_TASKS_PER_PRIMITIVE == 8
    assert evidence_penalties((np.inf, 1.0, 0.01, 0.0)) == [np.inf, 1.0, 0.0]
    assert evidence_penalties((0.0, 0.1, 10.0)) == [0.0, 10.0]
    assert evidence_penalties((0.01,)) == [0.01]


def test_plausible_ranks_are_within_the_bayes_factor_of_the_best():
    ev = np.array([0.0, 142.8, 140.0, 128.7, -np.inf])  # best rank 1, rank 2 within e^3
    assert plausible_ranks(ev).tolist() == [1, 2]
    assert plausible_ranks(ev, 0.0).tolist() == [1]
    assert plausible_ranks(ev, 14.1).tolist() == [1, 2] and plausible_ranks(ev, 14.2).tolist() == [1, 2, 3]
    assert plausible_ranks(ev, evidence.PLAUSIBLE_LOG_BAYES_FACTOR).tolist() == [1, 2]
    assert plausible_ranks([5.0]).tolist() == [0]


@pytest.fixture(scope="module")
def data():  # 3 folds: 5 training tasks at least
    """Eight tasks on a 3x3 grid from a 2-primitive dictionary on 4 state features, 3 demonstrations each."""
    return two_primitive_feature_tasks(8, 3, seed=5)


def test_the_points_are_what_the_pca_start_decomposes(data):
    """Tabular rewards: the rewards themselves; features: W G^(1/2), whose Gram matrix is the rewards' own."""
    mdp, F, R, demos = data
    tabular = fo.FactIRL(n_primitives=2)
    np.testing.assert_allclose(flat_start_points(learner_tasks(tabular, mdp, demos), R), R.reshape(8, -1), atol=1e-12)
    featured = fo.FactIRL(n_primitives=2, features=F)
    Y = flat_start_points(learner_tasks(featured, mdp, demos), R)
    rewards = R.reshape(8, -1)
    np.testing.assert_allclose(Y @ Y.T, rewards @ rewards.T, rtol=1e-8, atol=1e-8 * np.abs(rewards).max() ** 2)
    log_ev, rank = flat_start_evidence(learner_tasks(featured, mdp, demos), R)
    assert rank == 2 and log_ev.shape == (min(8, Y.shape[1]),)  # two primitives, exactly
    with pytest.raises(ValidationError, match=r"flat_rewards must have shape \(n, S, A\) = \(8, 9, 4\); got \(3, 9, 4\)"):
        flat_start_points(learner_tasks(featured, mdp, demos), R[:3])


def _auto(F, **search):
    return fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=F, max_iter=3, rng=0,
                      sharing_search=SharingSearch(route="evidence", **search))


def _fit(model, mdp, demos):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return model.fit(mdp, demos)


def _forced_rank(monkeypatch, rank):
    """The route with the evidence's k forced to ``rank``, and the (k, max_iter) of every candidate fit recorded."""
    monkeypatch.setattr(routes, "flat_start_evidence", lambda *args, **kw: (np.zeros(rank + 1), rank))
    fits = []
    fit = fo.FactIRL._fit_tasks  # the fit of a task set: the candidates' and the final one

    def counted(self, *args, **kw):
        fits.append((self.n_primitives, self.residual_penalty, self.max_iter))
        return fit(self, *args, **kw)

    monkeypatch.setattr(fo.FactIRL, "_fit_tasks", counted)
    return fits


def test_the_evidence_route_scores_its_k_half_and_twice_it_from_pca_starts(data, monkeypatch):
    mdp, F, _, demos = data
    assert ROUTES["evidence"].name == "evidence"
    fits = _forced_rank(monkeypatch, 2)
    model = _fit(_auto(F), mdp, demos)  # lambda = 0.01 is not scored
    res = model.cv_results_
    # 2k = 4 capped at 2: two of the 5 training tasks of a fold a primitive
    assert sorted(map(tuple, (p.values() for p in res["params"]))) == [(1, 0.0), (1, 1.0), (1, np.inf), (2, 1.0),
                                                                       (2, np.inf)]
    assert np.all(res["n_splits_scored"] == 3) and np.all(np.isfinite(res["mean_test_score"]))
    candidates = fits[:-1]  # the final fit last
    assert candidates and all(max_iter == 0 for _, _, max_iter in candidates)  # PCA starts only, no bisection
    assert {k for k, _, _ in candidates} <= {1, 2}
    assert (model.n_primitives_, model.residual_penalty_) in {tuple(p.values()) for p in res["params"]}


@pytest.mark.parametrize("rank", [0, 3])  # none shared; more than half the 5 training tasks of a fold
def test_little_shared_chooses_the_flat_model_without_a_fit(data, monkeypatch, tmp_path, rank):
    mdp, F, _, demos = data
    fits = _forced_rank(monkeypatch, rank)
    model = _fit(_auto(F), mdp, demos)
    assert (model.n_primitives_, model.residual_penalty_) == (1, 0.0)
    assert len(fits) == 1  # the final fit: no candidate
    res = model.cv_results_
    selection.check_cv_results(res)
    assert res["params"] == [{"n_primitives": 1, "residual_penalty": 0.0}] and res["n_splits_scored"].tolist() == [0]
    assert np.isnan(res["mean_test_score"][0]) and res["chosen"].tolist() == [True]
    loaded = fo.load_model(fo.save_model(model, tmp_path / "flat.npz"))
    assert loaded.cv_results_["params"] == res["params"] and np.isnan(loaded.cv_results_["mean_test_score"][0])
    assert loaded.cv_results_["confirmed"].dtype == bool and loaded.cv_results_["confirmed"].tolist() == [False]
    # at a fixed lambda it gives k = 1 at that lambda, unscored
    fixed = _fit(fo.FactIRL(n_primitives="auto", residual_penalty=np.inf, features=F, max_iter=3, rng=0,
                            sharing_search=SharingSearch(route="evidence")), mdp, demos)
    assert (fixed.n_primitives_, fixed.residual_penalty_) == (1, np.inf)


def test_the_evidence_route_reads_k_from_the_data(data):
    """Unforced, from the true rewards as the flat start: two primitives exactly, so the evidence's k
    is 2 and the candidates' k are 1 and 2 (4 is more than half the 5 training tasks of a fold), and
    the flat model."""
    mdp, F, R, demos = data
    assert flat_start_evidence(task_set(mdp, demos, F), R)[1] == 2
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model = _auto(F, residual_penalty_grid=(np.inf, 0.0)).fit(mdp, demos, flat_rewards=R)
    assert sorted(map(tuple, (p.values() for p in model.cv_results_["params"]))) == [(1, 0.0), (1, np.inf), (2, np.inf)]


def test_the_evidence_search_needs_the_flat_rewards(data):
    mdp, F, _, demos = data
    with pytest.raises(ValidationError, match=r"search='evidence' chooses k from the flat start's rewards: give flat_rewards"):
        selection.search_sharing(_auto(F), task_set(mdp, demos, F), None, search="evidence")
    assert "evidence" in ROUTES and evidence.__all__


def test_a_choice_at_the_edge_of_the_evidences_ks_walks_on_then_is_bisected(data, monkeypatch):
    """The held-out score (scripted) is best at k = 5.4 without residuals; the evidence says 16, so
    the candidates are 8, 16 and 20 (32 capped at half the 40 training tasks of a fold): the choice
    of 8 walks down to 4 (2 is worse), then the bisection finds 5."""
    mdp, _, _, demos = data
    noise = np.random.default_rng(0).normal(scale=0.001, size=60)

    def score_candidates(learner, tasks, flat_rewards, folds, candidates, progress, **kw):
        for k, lam in candidates:
            base = 3.0 if lam == 0.0 else 1.0 + (k - 5.4) ** 2 / 100 + (0.0 if lam == np.inf else 0.5)
            progress.scores.setdefault((k, lam), []).extend(base + noise[held] for held in folds)

    monkeypatch.setattr(search, "score_candidates", score_candidates)
    monkeypatch.setattr(routes, "flat_start_evidence", lambda *args, **kw: (np.zeros(17), 16))
    learner = fo.FactIRL(rng=0, n_primitives="auto", residual_penalty="auto")
    many = [demos[i % 8] for i in range(60)]  # 40 training tasks a fold, p = 36 rewards
    found = selection.search_sharing(learner, task_set(mdp, many), np.zeros((60, 9, 4)), search="evidence")
    assert (found.n_primitives, found.residual_penalty) == (5, np.inf)
    tried = [r["n_primitives"] for r in found.rows if r["residual_penalty"] == np.inf]
    # 40 training tasks a fold, 8 a primitive: 4, 5 and 6 confirmed last (their screen rows replaced)
    assert tried[:3] == [8, 16, 20] and 2 in tried[3:-3] and tried[-3:] == [4, 5, 6]
    assert [r.get("confirmed", False) for r in found.rows[-3:]] == [True] * 3
    assert all(len(r["fold_scores"]) == 3 for r in found.rows)
    assert ROUTES["evidence"].below(8, [8, 16, 32], 36) == [4] and ROUTES["evidence"].below(32, [8, 16, 32], 36) == []  # only down
    assert ROUTES["evidence"].below(16, [8, 16, 32], 36) == [] and ROUTES["evidence"].below(1, [1, 2], 5) == []


def test_the_default_search_is_the_evidence_route_with_its_rule(data, monkeypatch):
    """FactIRL's "auto" without a search of its own: the evidence route's candidates, chosen by the
    fewest-within-se rule."""
    mdp, F, _, demos = data
    _forced_rank(monkeypatch, 2)
    default = fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=F, max_iter=3, rng=0)
    model = _fit(default, mdp, demos)
    rows = selection.validation_rows(model.cv_results_)
    assert sorted((r["n_primitives"], r["residual_penalty"]) for r in rows) == [
        (1, 0.0), (1, 1.0), (1, np.inf), (2, 1.0), (2, np.inf)]
    chosen = next(r for r in rows if r["chosen"])
    assert rows.index(chosen) == selection.choose_row(rows, "fewest-within-se")
    assert (model.n_primitives_, model.residual_penalty_) == (chosen["n_primitives"], chosen["residual_penalty"])


def _scripted_scores(full_best):
    """Held-out scores by (k, lambda), best at k = 5.4 without residuals for the screen's
    candidates (``candidate_max_iter=0``) and at ``full_best`` for fully fitted ones (None); the
    fitted candidates recorded."""
    noise = np.random.default_rng(0).normal(scale=0.001, size=60)
    full = []

    def score_candidates(learner, tasks, flat_rewards, folds, candidates, progress, **kw):
        for k, lam in candidates:
            best = 5.4 if kw["candidate_max_iter"] == 0 else full_best
            if kw["candidate_max_iter"] is None:
                full.append((k, lam))
            base = 3.0 if lam == 0.0 else 1.0 + (k - best) ** 2 / 100 + (0.0 if lam == np.inf else 0.5)
            progress.scores.setdefault((k, lam), []).extend(base + noise[held] for held in folds)

    return score_candidates, full


@pytest.mark.parametrize("n_tasks, confirmed", [(60, True), (45, False)])  # 40 or 30 training tasks a fold
def test_a_shared_k_with_many_tasks_per_primitive_is_confirmed_by_full_fits(data, monkeypatch, n_tasks, confirmed):
    """The screen chooses (5, inf); with 40 training tasks a fold (8 a primitive) k = 4, 5 and 6
    are refitted fully on every fold, their screen scores replaced, and the choice is among them
    (scripted: best at 4 when fitted); with 30 (6 a primitive) the screen's choice stands."""
    mdp, _, _, demos = data
    scores, full = _scripted_scores(4.0)
    monkeypatch.setattr(search, "score_candidates", scores)
    monkeypatch.setattr(routes, "flat_start_evidence", lambda *args, **kw: (np.zeros(9), 8))
    learner = fo.FactIRL(rng=0, n_primitives="auto", residual_penalty="auto")
    found = selection.search_sharing(learner, task_set(mdp, [demos[i % 8] for i in range(n_tasks)]), np.zeros((n_tasks, 9, 4)),
                                    search="evidence", candidate_max_iter=0, rule="fewest-within-se")
    table = selection.cv_results(found)
    selection.check_cv_results(table)
    pairs = [(int(k), float(lam)) for k, lam in zip(table["param_n_primitives"], table["param_residual_penalty"])]
    assert len(set(pairs)) == len(pairs)  # a confirmed candidate's screen row is replaced, not repeated
    if confirmed:
        assert full == [(4, np.inf), (5, np.inf), (6, np.inf)]
        assert (found.n_primitives, found.residual_penalty) == (4, np.inf)
        assert sorted(p for p, c in zip(pairs, table["confirmed"]) if c) == full
        assert table["rank_test_score"][pairs.index((4, np.inf))] == 1 and table["chosen"][pairs.index((4, np.inf))]
        assert np.all(table["rank_test_score"][table["confirmed"]] <= 3)  # the confirmed candidates rank first
    else:
        assert full == [] and not table["confirmed"].any()
        assert (found.n_primitives, found.residual_penalty) == (5, np.inf)
    # a fixed k is not confirmed (nothing to choose), nor a flat choice
    fixed = fo.FactIRL(rng=0, n_primitives=5, residual_penalty="auto")
    full.clear()
    selection.search_sharing(fixed, task_set(mdp, [demos[i % 8] for i in range(n_tasks)]), np.zeros((n_tasks, 9, 4)),
                            search="evidence", candidate_max_iter=0)
    assert full == []
