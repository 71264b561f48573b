"""SharingSearch: the search of FactIRL's "auto" values as a parameter object (folds, grids, route, score, rule)."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ConvergenceWarning, PersistenceError, ValidationError
from factirl_opt.learners import clone, selection
from factirl_opt.learners.selection import routes, rules, scores, search
from factirl_opt.learners.selection import ROUTES, SharingSearch
from helpers import two_primitive_feature_tasks


@pytest.fixture(scope="module")
def data():
    """Eight tasks on a 3x3 grid from a 2-primitive dictionary on 4 state features, 3 demonstrations each."""
    mdp, F, _, demos = two_primitive_feature_tasks(8, 3, seed=5)
    return mdp, F, demos


def _auto(F, **search):
    return fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=F, max_iter=3, rng=0,
                      sharing_search=SharingSearch(**search) if search else None)


def _fit(model, mdp, demos):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return model.fit(mdp, demos)


def test_the_search_is_a_nested_parameter():
    model = _auto(None, cv=4, route="pca")
    params = model.get_params(deep=True)
    assert params["sharing_search__cv"] == 4 and params["sharing_search__route"] == "pca"
    twin = clone(model).set_params(sharing_search__cv=5, sharing_search__rule="share-within-noise")
    assert twin.sharing_search is not model.sharing_search and model.sharing_search.cv == 4
    assert twin.sharing_search.get_params()["cv"] == 5 and twin.sharing_search.rule == "share-within-noise"
    assert repr(twin) == ("FactIRL(n_primitives='auto', max_iter=3, rng=0, residual_penalty='auto', "
                          "sharing_search=SharingSearch(cv=5, route='pca', rule='share-within-noise'))")


def test_the_folds_grids_and_route_are_the_searchs(data):
    mdp, F, demos = data
    model = _fit(_auto(F, cv=[np.array([0, 1, 2, 3]), np.array([4, 5, 6, 7])], n_primitives_grid=(1, 3),
                       residual_penalty_grid=(np.inf, 0.0), route="full"), mdp, demos)
    res = model.cv_results_
    assert sorted(p["n_primitives"] for p in res["params"] if p["residual_penalty"] == np.inf) in ([1, 3], [1, 2, 3])
    assert {p["residual_penalty"] for p in res["params"]} == {np.inf, 0.0}
    assert "split1_test_score" in res and "split2_test_score" not in res and np.all(res["n_splits_scored"] == 2)
    # the flat fit of the PCA start and the candidates on the folds given: each task held out once
    tasks = np.column_stack([res[f"task{j}_test_score"] for j in range(8)])
    assert np.all(np.isfinite(tasks))
    # a splitter with split(X), as scikit-learn's KFold
    class Halves:
        def split(self, X):
            n = len(X)
            yield np.arange(n // 2, n), np.arange(n // 2)
            yield np.arange(n // 2), np.arange(n // 2, n)

    folds = selection.task_folds(8, Halves())
    assert [f.tolist() for f in folds] == [[0, 1, 2, 3], [4, 5, 6, 7]]
    assert [len(f) for f in selection.task_folds(8, 3, rng=0)] == [3, 3, 2]


def test_every_route_runs_and_the_pca_route_fits_no_candidate_beyond_its_start(data, monkeypatch):
    mdp, F, demos = data
    iterations = []
    fit = fo.FactIRL._fit_tasks  # the fit of a task set: the candidates' and the final one

    def counted(self, *args, **kw):
        out = fit(self, *args, **kw)
        iterations.append((self.n_primitives, self.max_iter, self.n_iter_))
        return out

    monkeypatch.setattr(fo.FactIRL, "_fit_tasks", counted)
    model = _fit(_auto(F, route="pca", n_primitives_grid=(1, 2), residual_penalty_grid=(np.inf, 1.0, 0.0)), mdp, demos)
    candidates, final = iterations[:-1], iterations[-1]  # the last: the final fit
    assert all(max_iter == 0 and n_iter == 0 for _, max_iter, n_iter in candidates)
    assert final[1] == 3 and model.n_iter_ == final[2]
    assert {"race", "full", "race-warm", "short", "pca"} <= set(ROUTES)
    short = _fit(_auto(F, route="short", n_primitives_grid=(1, 2), residual_penalty_grid=(np.inf, 0.0)), mdp, demos)
    assert [r["chosen"] for r in selection.validation_rows(short.cv_results_)].count(True) == 1


def test_share_within_noise_takes_the_candidate_that_shares_most_within_noise():
    def row(k, lam, scores):
        return {"n_primitives": k, "residual_penalty": lam, "score": float(np.mean(scores)), "score_std": 0.0,
                "fold_scores": [float(np.mean(scores))], "task_scores": list(scores), "chosen": False}

    base = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    rows = [row(5, np.inf, base + [0.1, -0.1, 0.2, -0.2, 0.1]),   # within noise of the best
            row(5, 1.0, base - 0.05),                               # the best mean
            row(2, np.inf, base + 1.0),                             # far behind
            row(1, 0.0, base + 2.0)]                                # the flat model, far behind
    assert selection.choose_row(rows) == 1
    assert selection.choose_row(rows, "share-within-noise") == 0
    # nothing within noise: the best stays
    rows[0] = row(5, np.inf, base + 0.5)
    assert selection.choose_row(rows, "share-within-noise") == 1
    # the flat model within noise of the best: kept under either rule
    rows[3] = row(1, 0.0, base + [-0.2, 0.2, -0.1, 0.1, 0.1])
    assert selection.choose_row(rows) == selection.choose_row(rows, "share-within-noise") == 3
    with pytest.raises(ValidationError, match=r"rule must be one of \('significant-gain', 'share-within-noise', "
                                              r"'fewest-within-se'\); got 'x'"):
        selection.choose_row(rows, "x")


def test_fewest_within_se_takes_the_fewest_primitives_within_one_standard_error_at_the_leaders_penalty():
    def row(k, lam, scores):
        return {"n_primitives": k, "residual_penalty": lam, "score": float(np.mean(scores)), "score_std": 0.0,
                "fold_scores": [float(np.mean(scores))], "task_scores": list(scores), "chosen": False}

    base = np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0])
    noise = np.array([0.1, -0.1, 0.2, -0.2, 0.1, -0.05])  # mean 0.0083, standard error 0.057
    rows = [row(6, np.inf, base - 0.05),          # the leader
            row(8, np.inf, base + noise),         # more primitives within noise: never taken
            row(5, np.inf, base + noise),         # within one standard error
            row(3, np.inf, base + 0.1 + noise),   # 0.158 behind, 2.8 standard errors
            row(2, 1.0, base + noise - 0.02),     # within noise, at another penalty: not compared
            row(1, 0.0, base + 1.0)]              # the flat model, far behind
    assert selection.choose_row(rows) == 0
    assert selection.choose_row(rows, "fewest-within-se") == 2
    assert selection.choose_row(rows, "share-within-noise") == 2
    rows[2] = row(5, np.inf, base + 0.06 + noise)  # 1.2 standard errors behind: the leader stays
    assert selection.choose_row(rows, "fewest-within-se") == 0
    rows[5] = row(1, 0.0, base + noise)  # the flat model within noise of the leader: kept
    assert selection.choose_row(rows, "fewest-within-se") == 5


def test_each_route_takes_its_own_rule_unless_one_is_given():
    from factirl_opt.learners.selection import ROUTE_RULES, route_rule

    assert SharingSearch().route == "evidence" and SharingSearch().rule is None
    assert route_rule("evidence") == ROUTE_RULES["evidence"] == "fewest-within-se"
    assert route_rule("race") == route_rule("pca") == selection.DEFAULT_RULE == "significant-gain"
    assert route_rule("evidence", "share-within-noise") == "share-within-noise"
    with pytest.raises(ValidationError, match=r"route must be one of .*; got 'x'"):
        route_rule("x")
    with pytest.raises(ValidationError, match=r"rule must be one of .* or None; got 'y'"):
        route_rule("race", "y")


@pytest.mark.parametrize("params, message", [
    ({"route": "grid"}, r"route must be one of \('race', 'full', 'race-warm', 'short', 'pca'.*\); got 'grid'"),
    ({"score": "accuracy"}, r"score must be one of"),
    ({"rule": "best"}, r"rule must be one of"),
    ({"n_primitives_grid": (0, 2)}, r"n_primitives_grid must be a non-empty tuple of integers >= 1"),
    ({"n_primitives_grid": ()}, r"n_primitives_grid must be a non-empty tuple"),
    ({"residual_penalty_grid": (np.inf, -1.0)}, r"residual_penalty_grid must be a non-empty tuple of numbers >= 0"),
    ({"residual_penalty_grid": (np.nan,)}, r"residual_penalty_grid must be"),
    ({"share_level": 1.5}, r"share_level must be a number >= 0 and < 1; got 1.5"),
    ({"race_margin": -0.1}, r"race_margin must be a number >= 0; got -0.1"),
    ({"cv": 1}, r"cv must be at least 2 folds; got 1"),
    ({"cv": [np.array([0, 9])]}, r"cv fold 0 must be a non-empty array of task indices in \[0, 8\)"),
    ({"cv": [np.arange(8)]}, r"cv fold 0 holds every task out"),
    ({"cv": "three"}, r"cv must be an int, a splitter with split\(X\) or an iterable of folds; got 'three'"),
    ({"cv": 3.5}, r"cv must be an int, a splitter with split\(X\) or an iterable of folds; got 3.5"),
    ({"n_transfer_demos": 0}, r"n_transfer_demos must be an integer >= 1"),
])
def test_bad_search_parameters_are_refused_before_any_fit(data, params, message):
    mdp, F, demos = data
    with pytest.raises(ValidationError, match=message):
        _auto(F, **params).fit(mdp, demos, flat_rewards=np.zeros((8, 9, 4)))


def test_a_sharing_search_that_is_not_one_is_refused(data):
    mdp, F, demos = data
    with pytest.raises(ValidationError, match=r"sharing_search must be a SharingSearch or None; got dict"):
        fo.FactIRL(n_primitives="auto", features=F, sharing_search={"cv": 3}).fit(mdp, demos, flat_rewards=np.zeros((8, 9, 4)))


def test_the_search_is_saved_with_the_model(data, tmp_path):
    mdp, F, demos = data
    model = _fit(_auto(F, cv=4, route="pca", residual_penalty_grid=(np.inf, 0.0)), mdp, demos)
    loaded = fo.load_model(fo.save_model(model, tmp_path / "m.npz"))
    assert loaded.sharing_search.get_params() == model.sharing_search.get_params()
    assert loaded.sharing_search.residual_penalty_grid == (np.inf, 0.0)
    np.testing.assert_array_equal(loaded.cv_results_["mean_test_score"], model.cv_results_["mean_test_score"])
    unsaved = _auto(F, cv=[np.arange(4), np.arange(4, 8)])
    with pytest.raises(PersistenceError, match=r"cannot save FactIRL with sharing_search.cv=\[array"):
        fo.save_model(unsaved, tmp_path / "folds.npz")


def test_a_preset_runs_its_adaptive_learner_with_its_route():
    """``Preset.sharing_route`` (``bench which-learner --route``): the default leaves the preset's
    fingerprint and the learner's options as they were; another route gives the learner its search."""
    import dataclasses

    from factirl_opt.lab.experiments.learner_solvers import factorial_options
    from factirl_opt.lab.experiments.presets import PRESETS

    grid = PRESETS["sharing-grid"]
    assert grid.sharing_route == "evidence" and PRESETS["quick"].sharing_route == "race"
    assert "sharing_search" not in factorial_options(grid, fo.SolverSettings(), adaptive=True)  # FactIRL's own
    race = dataclasses.replace(grid, sharing_route="race")
    assert factorial_options(race, fo.SolverSettings(), adaptive=True)["sharing_search"].route == "race"
    pca = dataclasses.replace(grid, sharing_route="pca")
    assert pca.fingerprint() != grid.fingerprint()  # its runs have keys of their own
    options = factorial_options(pca, fo.SolverSettings(), adaptive=True)
    assert options["sharing_search"].route == "pca" and "sharing_search" not in factorial_options(pca, fo.SolverSettings())
    with pytest.raises(ValidationError, match=r"sharing_route must be one of race, full, race-warm, short, pca.*; got 'x'"):
        dataclasses.replace(grid, sharing_route="x")


# ----------------------------------------------------------------------------- infeasible candidates, unread settings


@pytest.fixture(scope="module")
def low_rank_tasks():
    """Eight tasks on a 3x3 grid with per-task features (9, 4): tasks 0-5 span the first two
    columns' directions only, tasks 6-7 a third; together the features span 3 directions, not p = 4."""
    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    rng = np.random.default_rng(7)
    feats = []
    for i in range(8):
        F = np.zeros((9, 4))
        F[:, :2] = rng.random((9, 2))
        if i >= 6:
            F[:, 2] = rng.random(9)
        feats.append(F)
    W = rng.normal(size=(8, 4))
    R = np.stack([np.repeat(F @ w, 4).reshape(9, 4) for F, w in zip(feats, W)])
    return mdp, feats, fo.sample_demonstrations(mdp, R, 3, 6, rng=rng)


@pytest.mark.parametrize("route", ["pca", "race", "full"])
def test_candidates_are_capped_at_the_directions_the_features_span(low_rank_tasks, route):
    """k above the features' rank (3 < p = 4) is never proposed: the search no longer ends on the
    PCA start's refusal ("n_components=4 exceeds the rank 3")."""
    mdp, feats, demos = low_rank_tasks
    model = _fit(fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=feats, max_iter=2, rng=0,
                            sharing_search=SharingSearch(route=route, n_primitives_grid=(1, 2, 4))), mdp, demos)
    assert max(model.cv_results_["param_n_primitives"]) <= 3
    assert not any(model.cv_results_["unscored_reason"])


def test_a_candidate_that_cannot_be_fitted_on_a_fold_is_recorded_unscored(low_rank_tasks):
    """A fold whose training tasks span fewer directions than a candidate's k: that candidate is
    scored no further and its row says why; the search chooses among the others."""
    mdp, feats, demos = low_rank_tasks
    folds = [np.array([0, 1]), np.array([6, 7]), np.array([2, 3])]  # fold 1 trains on tasks spanning 2 directions
    model = _fit(fo.FactIRL(n_primitives="auto", residual_penalty=np.inf, features=feats, max_iter=2, rng=0,
                            sharing_search=SharingSearch(cv=folds, route="full", n_primitives_grid=(1, 3))), mdp, demos)
    res = model.cv_results_
    row = {int(k): i for i, k in enumerate(res["param_n_primitives"])}
    assert "exceeds the rank 2" in res["unscored_reason"][row[3]] and "fold 1" in res["unscored_reason"][row[3]]
    assert res["unscored_reason"][row[1]] == "" and res["n_splits_scored"][row[3]] == 1
    assert res["n_splits_scored"][row[1]] == 3 and model.n_primitives_ in (1, 2)  # 2: bisected between 1 and 3
    assert res["chosen"][row[model.n_primitives_]] and res["n_splits_scored"][row[model.n_primitives_]] == 3


def test_a_search_none_of_whose_candidates_can_be_fitted_says_why(low_rank_tasks):
    mdp, feats, demos = low_rank_tasks
    folds = [np.array([6, 7]), np.array([0, 1])]
    search = SharingSearch(cv=folds, route="full", n_primitives_grid=(3,))
    with pytest.raises(ValidationError, match=r"no candidate of the sharing search could be fitted: \(k=3, lambda=inf\): "
                                              r"cannot be fitted on the training tasks of fold 0: .*exceeds the rank 2"):
        _fit(fo.FactIRL(n_primitives="auto", residual_penalty=np.inf, features=feats, max_iter=2, rng=0,
                        sharing_search=search), mdp, demos)


@pytest.mark.parametrize("route, params, name", [
    ("evidence", {"n_primitives_grid": (3,)}, "n_primitives_grid"),
    ("evidence", {"race_margin": 0.2}, "race_margin"),
    ("pca", {"race_margin": 0.2}, "race_margin"),
    ("full", {"race_margin": 0.0}, "race_margin"),
])
def test_a_route_refuses_by_name_a_setting_it_does_not_read(data, route, params, name):
    """SharingSearch(n_primitives_grid=(3,)) on the evidence route scored k = 1-4 and chose 4."""
    mdp, F, demos = data
    with pytest.raises(ValidationError, match=rf"{name}=.* is not read by the '{route}' route .*take a route that reads it"):
        _auto(F, route=route, **params).fit(mdp, demos, flat_rewards=np.zeros((8, 9, 4)))
    SharingSearch(route="race", **params).check()  # the race reads all three
    SharingSearch(route=route, n_primitives_grid=[1, 2, 4, 8, 16]).check()  # the default, as a list


def test_the_screen_routes_take_init_random(data):
    """FactIRL("auto", residual_penalty="auto", init="random"): the evidence and pca routes' candidates
    are PCA starts of the flat rewards, which fit computes for them (it asked for flat_rewards)."""
    mdp, F, demos = data
    for route in ("evidence", "pca"):
        model = _fit(fo.FactIRL(n_primitives="auto", residual_penalty="auto", start=fo.Start(init="random"), features=F,
                                max_iter=3, rng=0, sharing_search=SharingSearch(route=route)), mdp, demos)
        assert model.start.init == "random" and np.all(np.isfinite(model.rewards_))
        assert np.all(np.isfinite(model.cv_results_["mean_test_score"][model.cv_results_["n_splits_scored"] > 0]))


def test_an_unscored_candidate_names_the_fold_it_failed_on_in_a_race(low_rank_tasks):
    """A race scores the contenders on the later folds in a second pass: the reason still names the
    fold of the whole search (fold 1 here), not the pass's own count."""
    mdp, feats, demos = low_rank_tasks
    folds = [np.array([0, 1]), np.array([6, 7]), np.array([2, 3])]
    search = SharingSearch(cv=folds, route="race", n_primitives_grid=(1, 3), residual_penalty_grid=(np.inf, 0.0))
    model = _fit(fo.FactIRL(n_primitives="auto", residual_penalty="auto", features=feats, max_iter=2, rng=0,
                            sharing_search=search), mdp, demos)
    res = model.cv_results_  # (3, inf) leads on fold 0 and races on with the flat model
    (row,) = np.flatnonzero(res["param_n_primitives"] == 3)
    assert res["unscored_reason"][row].startswith("cannot be fitted on the training tasks of fold 1:")
    assert res["n_splits_scored"][row] == 1
