"""FactIRL(n_primitives="auto", residual_penalty="auto"): k and lambda chosen by validation over tasks.

The fits here search by the race (``SharingSearch(route="race")``), which scores the whole grid of
candidates; the default route, ``"evidence"``, is tested in tests/learners/test_evidence.py."""

import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.learners import selection
from factirl_opt.learners.selection import routes, rules, scores, search
from factirl_opt.learners.em import log_policies
from factirl_opt.learners.fitting import learner_tasks
from factirl_opt.learners.start import flat_solver
from factirl_opt.planning import get_planner
from factirl_opt.exceptions import ConvergenceWarning, InterruptedFitWarning, ValidationError
from helpers import two_primitive_feature_tasks


@pytest.fixture(scope="module")
def data():
    """Six tasks on a 3x3 grid from a 2-primitive dictionary on 4 state features, 3 demonstrations each."""
    mdp, F, _, demos = two_primitive_feature_tasks(6, 3, seed=11)
    return mdp, F, demos


def _table(model):
    """The rows of a model's ``cv_results_`` (the former validation table)."""
    return selection.validation_rows(model.cv_results_)


#: the search of these tests' "auto" fits
RACE = fo.SharingSearch(route="race")


def _fit(mdp, demos, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        return fo.FactIRL(rng=0, max_iter=4, **{"sharing_search": RACE, **kw}).fit(mdp, demos)


@pytest.fixture(scope="module")
def auto(data):
    mdp, F, demos = data
    return _fit(mdp, demos, features=F, n_primitives="auto", residual_penalty="auto")


def test_the_chosen_pair_is_the_best_of_the_table(auto):
    rows = _table(auto)
    pairs = [(r["n_primitives"], r["residual_penalty"]) for r in rows]
    assert len(set(pairs)) == len(pairs)
    # k up to the 4 training tasks of a fold; lambda = 0 once (the dictionary plays no part there)
    grid = sorted((k, lam) for k in (1, 2, 4) for lam in (np.inf, 1.0, 1e-2))
    assert sorted(p for p in pairs if p[1] > 0 and p[0] in selection.K_CANDIDATES) == grid
    # and k = 3 only if the bisection of k ran, at the chosen lambda, around a chosen k of 2 or 4
    assert [p for p in pairs if p[0] not in selection.K_CANDIDATES] in ([], [(3, auto.residual_penalty_)])
    assert [p for p in pairs if p[1] == 0.0] == [(1, 0.0)]
    # the default search is a race: the candidates far behind on the first fold are not scored on the
    # others; the flat model always is (unless it is the only contender left: then it is the choice)
    assert [r["chosen"] for r in rows].count(True) == 1
    chosen = next(r for r in rows if r["chosen"])
    assert rows.index(chosen) == selection.choose_row(rows)
    assert (auto.n_primitives_, auto.residual_penalty_) == (chosen["n_primitives"], chosen["residual_penalty"])
    lead = min(r["fold_scores"][0] for r in rows)
    contenders = [r for r in rows if r["fold_scores"][0] <= lead + selection.RACE_MARGIN * abs(lead)
                  or r["residual_penalty"] == 0.0]
    for r in rows:
        assert len(r["fold_scores"]) in (1, 3) and r["score"] == pytest.approx(np.mean(r["fold_scores"]))
        assert len(r["task_scores"]) == 2 * len(r["fold_scores"])  # 6 tasks, 3 folds of 2
        assert r["score"] == pytest.approx(np.mean(r["task_scores"]))
        assert (len(r["fold_scores"]) == 3) == (r in contenders and len(contenders) > 1)
    assert auto.dictionary_.shape == (4, auto.n_primitives_) and auto.n_primitives == "auto"


def _rows(flat, shared):
    """A validation table of the flat model and one sharing candidate, scored on the same tasks."""
    return [{"n_primitives": 2, "residual_penalty": 1.0, "score": float(np.mean(shared)), "score_std": 0.0,
             "fold_scores": [float(np.mean(shared))], "task_scores": list(shared), "chosen": False},
            {"n_primitives": 1, "residual_penalty": 0.0, "score": float(np.mean(flat)), "score_std": 0.0,
             "fold_scores": [float(np.mean(flat))], "task_scores": list(flat), "chosen": False}]


def test_sharing_must_beat_the_flat_model_significantly():
    """A one-sided paired t-test at SHARE_LEVEL = 0.05 over the held-out tasks: with 4 tasks the
    mean gain must exceed t_3(0.95) = 2.353 standard errors."""
    assert selection.SHARE_LEVEL == 0.05
    flat = np.array([1.0, 2.0, 3.0, 4.0])
    # the paired gains 0.1, -0.2, 0.3, 0.2: mean 0.1 < their standard error 0.108: the flat model stays
    assert rules._choice(_rows(flat, flat - [0.1, -0.2, 0.3, 0.2])) == 1
    # gains 0.1, 0.3, 0.3, 0.3: mean 0.25, standard error 0.05: t = 5 > 2.353: the sharing candidate
    assert rules._choice(_rows(flat, flat - [0.1, 0.3, 0.3, 0.3])) == 0
    # gains 0.0, 0.3, 0.3, 0.3: mean 0.225, standard error 0.075: t = 3 > 2.353 > 1 ...
    assert rules._choice(_rows(flat, flat - [0.0, 0.3, 0.3, 0.3])) == 0
    # ... gains -0.1, 0.3, 0.3, 0.3: mean 0.2, standard error 0.1: t = 2, beyond one standard error
    # but not significant: the flat model stays
    assert rules._choice(_rows(flat, flat - [-0.1, 0.3, 0.3, 0.3])) == 1
    # the flat model leads: it is the choice; without a flat row, the lowest mean wins
    assert rules._choice(_rows(flat, flat + 0.5)) == 1
    assert rules._choice(_rows(flat, flat - [0.1, -0.2, 0.3, 0.2])[:1]) == 0
    # a row scored on fewer folds (pruned in a race) is never chosen
    rows = _rows(flat, flat - 5.0)
    rows[1]["fold_scores"] = rows[1]["fold_scores"] * 2
    assert selection.choose_row(rows) == 1


def test_the_number_of_primitives_is_bisected_around_the_chosen_one(data, monkeypatch):
    """After the race over K_CANDIDATES, k is refined between the chosen k and its nearest tried
    neighbours, at the chosen lambda, scored on every fold, while the choice moves."""
    mdp, _, demos = data
    noise = np.random.default_rng(0).normal(scale=0.01, size=30)

    def score_candidates(learner, tasks, flat_rewards, folds, candidates, progress, **kw):
        def one(k, lam, held):
            base = 3.0 if lam == 0.0 else 1.0 + (k - 6) ** 2 / 100 + (0.0 if lam == 1.0 else 0.5)
            return base + noise[held]
        for k, lam in candidates:
            progress.scores.setdefault((k, lam), []).extend(one(k, lam, held) for held in folds)

    monkeypatch.setattr(search, "score_candidates", score_candidates)
    learner = fo.FactIRL(rng=0, n_primitives="auto", residual_penalty="auto")
    k, lam, rows = selection.choose_sharing(learner, mdp, [demos[i % 6] for i in range(30)])
    assert (k, lam) == (6, 1.0)
    refined = [(r["n_primitives"], r["residual_penalty"]) for r in rows if r["n_primitives"] not in selection.K_CANDIDATES]
    assert refined == [(3, 1.0), (6, 1.0), (5, 1.0), (7, 1.0)]  # 4 -> {3, 6}; 6 -> {5, 7}; 6 stays: the end
    assert all(len(r["fold_scores"]) == 3 for r in rows if (r["n_primitives"], r["residual_penalty"]) in refined)
    # a fixed k is not refined
    learner = fo.FactIRL(rng=0, n_primitives=4, residual_penalty="auto")
    assert selection.choose_sharing(learner, mdp, [demos[i % 6] for i in range(30)])[:2] == (4, 1.0)


def test_choose_sharing_is_a_deprecated_wrapper_of_the_search(data, monkeypatch):
    from factirl_opt import _deprecation
    from factirl_opt.exceptions import DeprecatedNameWarning
    from factirl_opt.learners.selection import SharingSearch

    mdp, _, demos = data

    def score_candidates(learner, tasks, flat_rewards, folds, candidates, progress, **kw):
        for k, lam in candidates:
            progress.scores.setdefault((k, lam), []).extend(
                (1.0 + (k - 6) ** 2 / 100 + (2.0 if lam == 0.0 else 0.0)) + 0.01 * held for held in folds)

    monkeypatch.setattr(search, "score_candidates", score_candidates)
    monkeypatch.setattr(_deprecation, "_warned", set())
    learner, tasks = fo.FactIRL(rng=0, n_primitives="auto", residual_penalty="auto"), [demos[i % 6] for i in range(30)]
    with pytest.warns(DeprecatedNameWarning, match="choose_sharing is deprecated: search_sharing"):
        got = selection.choose_sharing(learner, mdp, tasks, search="full")
    want = selection.search_sharing(learner, learner_tasks(learner, mdp, tasks), search="full").as_tuple()
    assert got == want and got[:2] == (6, np.inf)
    assert SharingSearch(route="full").search(learner, learner_tasks(learner, mdp, tasks)).as_tuple() == want  # as a component


def test_the_bisection_steps_between_tried_numbers_of_primitives():
    assert selection.bisection_midpoints(8, [1, 2, 4, 8, 16], 67) == [6, 12]
    assert selection.bisection_midpoints(6, [1, 2, 4, 6, 8, 12, 16], 67) == [5, 7]
    assert selection.bisection_midpoints(4, [1, 2, 4, 8], 5) == [3]          # 6 is beyond k_max
    assert selection.bisection_midpoints(16, [1, 2, 4, 8, 16], 20) == [12]   # never beyond the tried range
    assert selection.bisection_midpoints(1, [1, 2], 5) == []
    assert selection.bisection_midpoints(5, [4, 5, 6], 9) == []


def test_the_search_flat_start_takes_the_learner_saturation_rule(data):
    """The auto search's flat start is GradIRL with FactIRL's flat_tol and flat_stol, the gradient
    rule off: a saturation rule stops it earlier, with the weights GradIRL gives."""
    mdp, F, demos = data
    learner = fo.FactIRL(features=F, flat_max_iter=60)
    plain = selection.flat_start_rewards(learner, learner_tasks(learner, mdp, demos), "lbfgs", 1e-5)
    saturated = selection.flat_start_rewards(learner, learner_tasks(learner, mdp, demos), "lbfgs", 1e-5, 1e-2)
    flat = fo.GradIRL(features=F, max_iter=60, tol=1e-5, gtol=0.0, stol=1e-2, solver="lbfgs").fit(mdp, demos)
    np.testing.assert_array_equal(saturated, flat.rewards_)
    assert not np.allclose(saturated, plain)


def test_the_race_scores_its_contenders_as_the_full_search_does(data, auto):
    """The full search scores every candidate on every fold; the cold race's rows are the same
    numbers (each fold's fit is independent of the others), so it chooses the same pair whenever
    the full search's winner stays in the race."""
    mdp, F, demos = data
    learner = fo.FactIRL(rng=0, max_iter=4, features=F, n_primitives="auto", residual_penalty="auto")
    start = learner._group("start")  # the flat start of FactIRL's own search
    flat = selection.flat_start_rewards(learner, learner_tasks(learner, mdp, demos), flat_solver(learner), start.flat_tol,
                                        start.flat_stol)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        k, lam, full = selection.choose_sharing(learner, mdp, demos, flat, search="full")
        kr, lr, race = selection.choose_sharing(learner, mdp, demos, flat, search="race")
    assert all(len(r["fold_scores"]) == 3 for r in full)
    by_pair = {(r["n_primitives"], r["residual_penalty"]): r for r in full}
    for r in race:  # lambda = 0 is not fitted in a race; its transfer, the flat learner's, needs no dictionary
        other = by_pair[r["n_primitives"], r["residual_penalty"]]
        assert r["fold_scores"] == other["fold_scores"][:len(r["fold_scores"])]
    assert sum(len(r["fold_scores"]) for r in race) < 3 * len(race)
    complete = [r for r in race if len(r["fold_scores"]) == 3]
    assert (kr, lr) == (race[rules._choice(race)]["n_primitives"], race[rules._choice(race)]["residual_penalty"])
    assert (k, lam) == (full[rules._choice(full)]["n_primitives"], full[rules._choice(full)]["residual_penalty"])
    if all(any(r["fold_scores"] == by_pair[pair]["fold_scores"] for r in complete)
           for pair in by_pair if by_pair[pair]["score"] <= by_pair[k, lam]["score"] or pair[1] == 0.0):
        assert (kr, lr) == (k, lam)  # the full search's winner stayed in the race
    assert [r["fold_scores"] for r in race] == [r["fold_scores"] for r in _table(auto)]  # the default
    # the warm race starts each candidate from its predecessor's fit: the first candidate of each k is
    # scored as in the full search on the first fold
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        warm = selection.choose_sharing(learner, mdp, demos, flat, search="race-warm")[2]
    for r in warm:
        if r["residual_penalty"] == np.inf:
            assert r["fold_scores"][0] == by_pair[r["n_primitives"], np.inf]["fold_scores"][0]
    with pytest.raises(ValidationError, match=r"search must be one of \('race', 'full', 'race-warm', 'short', 'pca', 'evidence'\); got 'grid'"):
        selection.choose_sharing(learner, mdp, demos, flat, search="grid")


def test_the_final_fit_is_the_fixed_fit_of_the_chosen_pair(data, auto):
    """From the search's flat start, the fixed fit of the chosen pair to the last bit; from its own flat
    start to rounding, by which the saturation rule may stop a flat fit one step apart (the search plans
    its flat start on the fit's warm planning caches; 5e-8 measured)."""
    mdp, F, demos = data
    kw = dict(features=F, n_primitives=auto.n_primitives_, residual_penalty=auto.residual_penalty_)
    learner = fo.FactIRL(rng=0, max_iter=4, **kw)
    start = learner._group("start")
    flat = selection.flat_start_rewards(learner, learner_tasks(learner, mdp, demos), flat_solver(learner), start.flat_tol,
                                        start.flat_stol)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        given = learner.fit(mdp, demos, flat_rewards=flat)
    np.testing.assert_array_equal(auto.rewards_, given.rewards_)
    fixed = _fit(mdp, demos, **kw)
    np.testing.assert_allclose(auto.rewards_, fixed.rewards_, rtol=1e-6, atol=1e-8)


def test_transfer_after_auto(data, auto):
    mdp, F, demos = data
    h = auto.transfer(mdp, [d[:1] for d in demos[:2]])
    assert h.shape == (2, auto.n_primitives_) and auto.transfer_rewards_.shape == (2, 9, 4)


def test_a_fixed_value_is_kept(data):
    mdp, F, demos = data
    model = _fit(mdp, demos, features=F, n_primitives=2, residual_penalty="auto")
    assert {r["n_primitives"] for r in _table(model)} == {2} and model.n_primitives_ == 2
    model = _fit(mdp, demos, features=F, n_primitives="auto", residual_penalty=np.inf)
    assert {r["residual_penalty"] for r in _table(model)} == {np.inf} and model.residual_penalty_ == np.inf


def test_a_constrained_h_solver_validates_only_the_factorial_model(data):
    mdp, F, demos = data
    model = _fit(mdp, demos, features=F, n_primitives=2, residual_penalty="auto", solver="armijo-nonneg")
    assert [r["residual_penalty"] for r in _table(model)] == [np.inf]


def test_validation_needs_two_tasks_and_a_demonstration_to_score(data):
    mdp, F, demos = data
    with pytest.raises(ValidationError, match=r"needs at least 2 tasks; got 1"):
        _fit(mdp, demos[:1], features=F, n_primitives="auto")
    with pytest.raises(ValidationError, match=r"task 0 has 1; give every task at least 2"):
        _fit(mdp, [d[:1] for d in demos], features=F, residual_penalty="auto")
    with pytest.raises(ValidationError, match=r"n_primitives must be an integer >= 1"):
        _fit(mdp, demos, features=F, n_primitives=0, residual_penalty="auto")
    with pytest.raises(ValidationError, match=r"init must be 'pca' or 'random', not a \(D0, H0\) tuple"):
        _fit(mdp, demos, features=F, n_primitives="auto", init=(np.ones((4, 2)), np.ones((6, 2))))


def test_plot_validation(auto):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    ax = selection.plot_validation(auto)
    assert len(ax.get_lines()) >= 3 and ax.get_xscale() == "log"
    with pytest.raises(ValidationError, match=r"has no cv_results_"):
        selection.plot_validation(fo.FactIRL())


def test_the_choice_and_its_table_are_saved_and_checked(auto, tmp_path):
    import json

    from factirl_opt.exceptions import PersistenceError

    loaded = fo.load_model(fo.save_model(auto, tmp_path / "auto.npz"))
    assert loaded.cv_results_.keys() == auto.cv_results_.keys() and loaded.n_primitives == "auto"
    for key, value in auto.cv_results_.items():
        if key == "params":
            assert loaded.cv_results_[key] == value
        else:
            np.testing.assert_array_equal(loaded.cv_results_[key], value)
            assert loaded.cv_results_[key].dtype == value.dtype, key
    assert (loaded.n_primitives_, loaded.residual_penalty_) == (auto.n_primitives_, auto.residual_penalty_)
    np.testing.assert_array_equal(loaded.residuals_, auto.residuals_)

    def rewrite(edit, name):
        with np.load(tmp_path / "auto.npz", allow_pickle=False) as npz:
            header = json.loads(str(npz["__header__"][()]))
            arrays = {k: npz[k] for k in npz.files if k != "__header__"}
        edit(header["attributes"])
        np.savez(tmp_path / name, __header__=np.array(json.dumps(header)), **arrays)
        return tmp_path / name

    bad = rewrite(lambda a: a["cv_results_"]["chosen"].__setitem__(0, not a["cv_results_"]["chosen"][0]), "two.npz")
    with pytest.raises(PersistenceError, match=r"attribute cv_results_\['chosen'\] must mark exactly one candidate; [02] are"):
        fo.load_model(bad)
    bad = rewrite(lambda a: a.update(residual_penalty_=-1.0), "neg.npz")
    with pytest.raises(PersistenceError, match=r"attribute residual_penalty_ must be a number >= 0, or inf; got -1.0"):
        fo.load_model(bad)
    bad = rewrite(lambda a: a["cv_results_"].pop("mean_test_score"), "keys.npz")
    with pytest.raises(PersistenceError, match=r"attribute cv_results_ has no key 'mean_test_score'"):
        fo.load_model(bad)
    bad = rewrite(lambda a: a["cv_results_"]["std_test_score"].pop(), "short.npz")
    with pytest.raises(PersistenceError, match=r"attribute cv_results_\['std_test_score'\] must have one entry per candidate"):
        fo.load_model(bad)

    # a file of 0.1.0: the table as validation_ rows (task_scores absent before 2026-11-26), loaded as cv_results_
    rows = [{k: v for k, v in r.items() if k != "task_scores"} for r in _table(auto)]
    old = rewrite(lambda a: a.update(validation_=json.loads(json.dumps(rows))) or a.pop("cv_results_"), "old.npz")
    model = fo.load_model(old)
    assert [{k: v for k, v in r.items() if k != "task_scores"} for r in _table(model)] == rows
    np.testing.assert_array_equal(model.cv_results_["chosen"], auto.cv_results_["chosen"])
    bad = rewrite(lambda a: a.update(validation_=[dict(rows[0], task_scores="1.0")]) or a.pop("cv_results_"), "tasks.npz")
    with pytest.raises(PersistenceError, match=r"attribute validation_\[0\] task_scores must be a list of numbers"):
        fo.load_model(bad)
    with pytest.warns(fo.exceptions.DeprecatedNameWarning, match=r"validation_ is deprecated: read cv_results_"):
        assert model.validation_ == _table(model)


def test_cv_results_is_a_table_of_equal_length_arrays(auto):
    res = auto.cv_results_
    m = len(res["params"])
    assert all(len(v) == m for v in res.values())
    assert res["chosen"].dtype == bool and res["chosen"].sum() == 1
    chosen = int(np.flatnonzero(res["chosen"])[0])
    assert res["params"][chosen] == {"n_primitives": auto.n_primitives_, "residual_penalty": auto.residual_penalty_}
    splits = np.column_stack([res[f"split{f}_test_score"] for f in range(3)])
    tasks = np.column_stack([res[f"task{j}_test_score"] for j in range(6)])
    np.testing.assert_array_equal(res["n_splits_scored"], np.isfinite(splits).sum(axis=1))
    assert np.all(np.isfinite(tasks).sum(axis=1) == 2 * res["n_splits_scored"])  # 6 tasks, 3 folds of 2
    np.testing.assert_allclose(res["mean_test_score"], np.nanmean(tasks, axis=1), rtol=1e-12)
    np.testing.assert_allclose(res["mean_test_score"], np.nanmean(splits, axis=1), rtol=1e-12)
    complete = res["n_splits_scored"] == res["n_splits_scored"].max()  # the rows chosen from, ranked first
    assert res["rank_test_score"][complete].min() == 1 and res["rank_test_score"][complete].max() == complete.sum()
    assert res["rank_test_score"][chosen] <= complete.sum()
    assert sorted(res["rank_test_score"]) == list(range(1, m + 1))
    try:
        import pandas
    except ImportError:  # the table is plain arrays; pandas only shows it
        return
    assert pandas.DataFrame(res).shape[0] == m


def test_held_out_likelihood_is_the_boltzmann_policys_at_its_best_temperature(data):
    """The held-out score of policy matching: minus the mean log-probability of the held-out
    (state, action) pairs under the Boltzmann policy of the transferred reward's Q* (eq. 7), at
    the learner's beta (``temper=False``) or at the inverse temperature that fits them best."""
    mdp, F, demos = data
    R = np.random.default_rng(0).normal(size=(mdp.n_states, mdp.n_actions))
    Q = fo.optimal_q(mdp, R[None])[0][0]
    pairs = demos[0].reshape(-1, 2)

    def nll(beta):
        pi = fo.boltzmann_policy(Q, beta)
        with np.errstate(divide="ignore"):
            return -np.mean(np.log(pi[pairs[:, 0], pairs[:, 1]]))

    model = fo.FactIRL(beta=5.0)
    assert selection.held_out_nll(mdp, demos[0], R, model, temper=False) == pytest.approx(nll(5.0), rel=1e-12)
    betas = np.exp(np.linspace(-6, 6, 4001))
    grid = min(nll(b) for b in betas)
    tempered = selection.held_out_nll(mdp, demos[0], R, model)
    assert grid - 1e-6 <= tempered <= min(grid, nll(5.0), np.log(mdp.n_actions)) + 1e-9
    # the reward's scale does not matter (Q* is positively homogeneous), its direction does
    assert selection.held_out_nll(mdp, demos[0], 7.0 * R, model) == pytest.approx(tempered, abs=1e-7)
    assert selection.held_out_nll(mdp, demos[0], np.zeros_like(R), model) == pytest.approx(np.log(mdp.n_actions))


def test_held_out_likelihood_of_mce_is_the_soft_policys(data):
    mdp, F, demos = data
    R = np.random.default_rng(1).normal(size=(mdp.n_states, mdp.n_actions))
    model = fo.FactIRL(beta=2.0, objective="mce")
    log_pi = log_policies(get_planner(mdp), R[None], 2.0, "mce")[0]
    pairs = demos[1].reshape(-1, 2)
    fixed = selection.held_out_nll(mdp, demos[1], R, model, temper=False)
    assert fixed == pytest.approx(-np.mean(log_pi[pairs[:, 0], pairs[:, 1]]), rel=1e-12)
    assert selection.held_out_nll(mdp, demos[1], R, model) <= min(fixed, np.log(mdp.n_actions)) + 1e-12


def test_either_score_chooses_from_its_table_and_an_unknown_one_is_refused(data):
    mdp, F, demos = data
    learner = fo.FactIRL(rng=0, max_iter=2, features=F, n_primitives="auto", residual_penalty="auto")
    start = learner._group("start")  # the flat start of FactIRL's own search
    flat = selection.flat_start_rewards(learner, learner_tasks(learner, mdp, demos), flat_solver(learner), start.flat_tol,
                                        start.flat_stol)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        for score in selection.SCORES:
            k, lam, table = selection.choose_sharing(learner, mdp, demos, flat, score=score)
            chosen = table[rules._choice(table)]
            assert (k, lam) == (chosen["n_primitives"], chosen["residual_penalty"]) and chosen["chosen"]
    with pytest.raises(ValidationError, match="score must be one of"):
        selection.choose_sharing(learner, mdp, demos, flat, score="accuracy")


def test_occupancy_gap_is_zero_for_the_greedy_policys_own_paths_and_matches_enumeration():
    """held_out_occupancy_gap: the total variation between the demonstrations' discounted
    state-action occupancy and the reward's greedy policy's from the same starts, for the same
    lengths; checked on a deterministic model (0 for the greedy paths) and against an explicit
    sum over the dense transition array."""
    rng = np.random.default_rng(3)
    det = fo.TabularMDP(np.eye(9)[rng.integers(9, size=(9, 4))], 0.9)  # deterministic: one successor each
    R = rng.normal(size=(det.n_states, det.n_actions))
    greedy = np.asarray(fo.optimal_q(det, R[None])[1]).reshape(det.n_states)
    P = np.asarray(det.transitions)  # (S, A, S)
    paths = []
    for s in (0, 4, 8):
        path = []
        for _ in range(5):
            path.append((s, greedy[s]))
            s = int(np.argmax(P[s, greedy[s]]))
        paths.append(path)
    demos = np.array(paths)
    assert selection.held_out_occupancy_gap(det, demos, R) == pytest.approx(0.0, abs=1e-12)

    mdp = fo.GridWorld(size=3, p_success=0.7, gamma=0.9)
    episodes = [np.array([[0, 1], [1, 2], [4, 0]]), np.array([[8, 3], [5, 3]])]  # two lengths
    greedy = np.asarray(fo.optimal_q(mdp, R[None])[1]).reshape(mdp.n_states)
    P = np.asarray(mdp.transitions)
    expert, learnt = np.zeros((9, 4)), np.zeros((9, 4))
    for e in episodes:
        d = np.zeros(9)
        d[e[0, 0]] = 1.0
        for t, (s, a) in enumerate(e):
            expert[s, a] += 0.9 ** t / 2
            for x in range(9):
                learnt[x, greedy[x]] += 0.9 ** t * d[x] / 2
            d = np.array([sum(d[x] * P[x, greedy[x], y] for x in range(9)) for y in range(9)])
    gap = selection.held_out_occupancy_gap(mdp, episodes, R)
    assert gap == pytest.approx(np.abs(expert - learnt).sum(), rel=1e-12)
    # the value of any reward under the two occupancies differs by at most max|r| times the gap
    r = rng.normal(size=(9, 4))
    assert abs((r * expert).sum() - (r * learnt).sum()) <= np.abs(r).max() * gap + 1e-12


def test_an_interrupted_final_fit_keeps_its_best_point_and_the_table(data):
    """Ctrl-C (here a callback raising KeyboardInterrupt) in the final fit of the chosen pair: the
    estimator keeps that fit's best point and the whole validation table, warns and re-raises."""
    mdp, F, demos = data

    def stop(iteration, loss):
        if iteration == 1:
            raise KeyboardInterrupt

    model = fo.FactIRL(rng=0, max_iter=4, features=F, n_primitives="auto", residual_penalty="auto", callback=stop)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(KeyboardInterrupt):
            model.fit(mdp, demos)
    message = [str(w.message) for w in caught if issubclass(w.category, InterruptedFitWarning)]
    assert len(message) == 1 and "kept the best of 1 outer iterations" in message[0]
    assert model.status_ == "interrupted" and model.n_iter_ == 1
    assert [r["chosen"] for r in _table(model)].count(True) == 1
    chosen = next(r for r in _table(model) if r["chosen"])
    assert (model.n_primitives_, model.residual_penalty_) == (chosen["n_primitives"], chosen["residual_penalty"])
    assert model.dictionary_.shape == (4, model.n_primitives_) and model.rewards_.shape == (6, 9, 4)
    model.callback = None
    assert model.transfer(mdp, [d[:1] for d in demos[:2]]).shape == (2, model.n_primitives_)


def test_an_interrupted_search_keeps_the_best_candidate_fitted_so_far(data, monkeypatch):
    """Ctrl-C during the search (here at the third candidate's score): the estimator keeps the fit of
    the best candidate scored so far, on its fold's training tasks, and the table of the candidates
    scored; interrupted before any candidate was fitted, it stays unfitted."""
    mdp, F, demos = data
    calls = []
    score = scores._score

    def interrupted(*args, **kw):
        calls.append(1)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return score(*args, **kw)

    monkeypatch.setattr(search, "_score", interrupted)
    model = fo.FactIRL(rng=0, max_iter=4, features=F, n_primitives="auto", residual_penalty="auto", sharing_search=RACE)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(KeyboardInterrupt):
            model.fit(mdp, demos)
    message = [str(w.message) for w in caught if issubclass(w.category, InterruptedFitWarning)]
    assert len(message) == 1 and "the best candidate scored so far, fitted on 4 of the 6 tasks" in message[0]
    rows = _table(model)
    assert len(rows) == 2 and [r["chosen"] for r in rows].count(True) == 1  # the two candidates scored
    chosen = next(r for r in rows if r["chosen"])
    assert chosen["score"] == min(r["score"] for r in rows)
    assert (model.n_primitives_, model.residual_penalty_) == (chosen["n_primitives"], chosen["residual_penalty"])
    assert model.status_ == "interrupted" and model.rewards_.shape == (4, 9, 4)
    assert model.transfer(mdp, [d[:1] for d in demos[:2]]).shape == (2, model.n_primitives_)

    calls.clear()
    monkeypatch.setattr(search, "_score", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt()))
    model = fo.FactIRL(rng=0, max_iter=2, features=F, n_primitives="auto", sharing_search=RACE)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        with pytest.raises(KeyboardInterrupt):
            model.fit(mdp, demos)
    assert any("kept the fit of (1, inf), the last candidate fitted (none was scored yet)" in str(w.message)
               for w in caught)
    assert not hasattr(model, "cv_results_") and model.n_primitives_ == 1 and model.rewards_.shape == (4, 9, 4)


def test_a_fixed_fit_after_an_auto_fit_drops_the_search(data):
    mdp, F, demos = data
    model = _fit(mdp, demos, features=F, n_primitives=2, residual_penalty="auto")
    assert hasattr(model, "cv_results_")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.set_params(residual_penalty=np.inf).fit(mdp, demos)
    assert not hasattr(model, "cv_results_") and not hasattr(model, "validation_") and model.residual_penalty_ == np.inf
    with pytest.raises(ValidationError, match=r"has no cv_results_"):
        selection.plot_validation(model)


def test_flat_rewards_of_the_wrong_shape_are_refused_before_the_search(data):
    mdp, F, demos = data
    flat = np.zeros((6, 9, 4))
    for bad in (flat[:4], flat[:, :8]):
        with pytest.raises(ValidationError, match=r"flat_rewards must have shape \(n, S, A\) = \(6, 9, 4\); got"):
            fo.FactIRL(n_primitives="auto", features=F).fit(mdp, demos, flat_rewards=bad)
    with pytest.raises(ValidationError, match=r"flat_rewards must be finite"):
        fo.FactIRL(residual_penalty="auto", features=F).fit(mdp, demos, flat_rewards=flat + np.nan)
    mdps = [fo.GridWorld(size=3, p_success=0.7, gamma=0.9) for _ in range(6)]
    with pytest.raises(ValidationError, match=r"flat_rewards must hold one \(S_i, A\) array per task \(6\); got 4"):
        fo.FactIRL(n_primitives="auto", features=F).fit(mdps, demos, flat_rewards=flat[:4])


def test_plot_validation_names_a_missing_key_of_an_edited_table(auto):
    matplotlib = pytest.importorskip("matplotlib")
    matplotlib.use("Agg")
    import copy

    edited = copy.copy(auto)
    edited.cv_results_ = dict(auto.cv_results_)
    del edited.cv_results_["std_test_score"]
    with pytest.raises(ValidationError, match=r"cv_results_ has no key 'std_test_score'"):
        selection.plot_validation(edited)
    edited.cv_results_ = dict(auto.cv_results_, mean_test_score=auto.cv_results_["mean_test_score"][:2])
    with pytest.raises(ValidationError, match=r"cv_results_\['mean_test_score'\] must have one entry per candidate"):
        selection.plot_validation(edited)
    # the deprecated table, set by hand, is checked as it is set
    rows = _table(auto)
    del rows[1]["score_std"]
    with pytest.raises(ValidationError, match=r"validation_\[1\] has no key 'score_std'"):
        edited.validation_ = rows
    with pytest.raises(ValidationError, match=r"validation_\[0\] must be a dict with keys"):
        edited.validation_ = [1.0]
    with pytest.raises(ValidationError, match=r"validation_ must be a non-empty list"):
        edited.validation_ = []


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_the_held_out_scores_refuse_non_finite_rewards(data, bad):
    mdp, F, demos = data
    R = np.zeros((mdp.n_states, mdp.n_actions))
    R[2, 1] = bad
    with pytest.raises(ValidationError, match=r"rewards must be finite; found .* at index \(2, 1\)"):
        selection.held_out_nll(mdp, demos[0], R, fo.FactIRL())
    with pytest.raises(ValidationError, match=r"rewards must be finite"):
        selection.held_out_occupancy_gap(mdp, demos[0], R)
    with pytest.raises(ValidationError, match=r"rewards must be one task's reward"):
        selection.held_out_nll(mdp, demos[0], np.zeros((2, 9, 4)), fo.FactIRL())
    with pytest.raises(ValidationError, match=r"rewards must have shape \(S, A\)"):
        selection.held_out_occupancy_gap(mdp, demos[0], np.zeros((9, 3)))
