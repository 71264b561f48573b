"""MultiIntentIRL saves and loads: its parameters and learnt attributes exactly, and every check."""

import json

import numpy as np
import pytest

import factirl_opt as fo
import solvers
from factirl_opt.exceptions import PersistenceError

EM_MODELS = ["multi-intent-flat", "multi-intent-shared", "multi-intent-auto"]
RUNTIME = tuple(f"execution__{name}" for name in ("n_jobs", "backend", "client", "planner_options", "callback"))


def _learnt(model):
    return {k: v for k, v in vars(model).items() if k.endswith("_") and not k.startswith("_")}


def _rewrite(src, dst, edit):
    with np.load(src, allow_pickle=False) as npz:
        header = json.loads(str(npz["__header__"][()]))
        arrays = {k: npz[k] for k in npz.files if k != "__header__"}
    edit(header, arrays)
    np.savez(dst, __header__=np.array(json.dumps(header)), **arrays)
    return dst


def _same_params(a, b):
    pa, pb = a.get_params(), b.get_params()
    assert pa.keys() == pb.keys()
    for key, value in pa.items():
        got = pb[key]
        if isinstance(value, np.ndarray):
            np.testing.assert_array_equal(got, value, err_msg=key)
        elif isinstance(value, np.random.Generator):
            assert got.bit_generator.state == value.bit_generator.state, key
        elif isinstance(value, tuple):
            assert list(got) == list(value), key  # JSON gives tuples back as lists
        else:
            assert got == value, key


@pytest.mark.parametrize("name", EM_MODELS)
def test_fitted_em_round_trips_exactly(fitted_models, name, tmp_path):
    model = fitted_models[name]
    loaded = fo.load_model(fo.save_model(model, tmp_path / "em.npz"))
    assert type(loaded) is fo.MultiIntentIRL
    _same_params(model, loaded)
    attributes = _learnt(model)
    assert {"labels_", "responsibilities_", "rewards_", "mixture_weights_", "log_likelihood_", "converged_"} <= set(attributes)
    assert set(_learnt(loaded)) == set(attributes)
    for key, value in attributes.items():
        got = getattr(loaded, key)
        if isinstance(value, np.ndarray):
            assert got.dtype == value.dtype and got.shape == value.shape, key
            np.testing.assert_array_equal(got, value, err_msg=key)
        else:
            assert got == value and type(got) is type(value), key
    if name == "multi-intent-auto":
        assert loaded.n_intentions == "auto" and list(loaded.n_intentions_range) == [1, 2]
        np.testing.assert_array_equal(loaded.n_intentions_candidates_, [1, 2])


def test_a_loaded_em_fits_and_transfers_as_the_saved_one(fitted_models, grid_tasks, tmp_path):
    mdp, demos, new_demos, _, _ = grid_tasks
    episodes = [ep for task in demos for ep in task]
    model = fo.MultiIntentIRL(2, 2, rng=3, max_iter=2, m_step_max_iter=3, init="frequencies")
    loaded = fo.load_model(fo.save_model(model, tmp_path / "unfitted.npz"))
    assert not hasattr(loaded, "labels_")
    a, b = model.fit(mdp, episodes), loaded.fit(mdp, episodes)
    for key in ("labels_", "responsibilities_", "rewards_", "dictionary_"):
        np.testing.assert_array_equal(getattr(b, key), getattr(a, key), err_msg=key)
    shared = fo.load_model(fo.save_model(fitted_models["multi-intent-shared"], tmp_path / "shared.npz"))
    h = shared.to_factirl().transfer(mdp, new_demos)
    np.testing.assert_array_equal(h, fitted_models["multi-intent-shared"].to_factirl().transfer(mdp, new_demos))


def test_given_starts_solver_settings_and_execution_settings(grid_tasks, tmp_path):
    mdp, demos, _, _, _ = grid_tasks
    episodes = [ep for task in demos for ep in task]
    labels = np.arange(len(episodes)) % 2
    settings = fo.SolverSettings("armijo", {"initial_step": 0.5}, d_solver="lbfgs")
    for init in (labels, np.eye(2)[labels]):
        execution = fo.Execution(n_jobs=1, planner_options={"max_bytes": 10**9}, callback=print)
        model = fo.MultiIntentIRL(2, 2, start=fo.IntentionStart(init=init), solver=settings, execution=execution,
                                  max_iter=2, m_step_max_iter=2).fit(mdp, episodes)
        path = fo.save_model(model, tmp_path / "given.npz")
        with np.load(path, allow_pickle=False) as npz:
            header = json.loads(str(npz["__header__"][()]))
        assert header["class"] == "MultiIntentIRL" and header["array_params"] == ["start__init"]
        assert not set(RUNTIME) & set(header["params"])
        loaded = fo.load_model(path)
        np.testing.assert_array_equal(loaded.start.init, init)
        assert loaded.solver == settings and loaded.execution == fo.Execution()  # runtime fields left out
        np.testing.assert_array_equal(loaded.labels_, model.labels_)


def test_objects_are_refused_by_name(tmp_path):
    with pytest.raises(PersistenceError, match="d_solver given as a ArmijoSolver object.*registry name"):
        fo.save_model(fo.MultiIntentIRL(2, solver=fo.SolverSettings(d_solver=solvers.ArmijoSolver())), tmp_path / "x.npz")
    with pytest.raises(PersistenceError, match="parameter start__init: it is not a numeric array"):
        fo.save_model(fo.MultiIntentIRL(2, start=fo.IntentionStart(init=[None, 1])), tmp_path / "x.npz")


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda h, a: a.update({"attr/labels_": a["attr/labels_"].astype(float)}),
         "attribute labels_ must be a 1-d integer array; got float64"),
        (lambda h, a: a.update({"attr/labels_": -a["attr/labels_"] - 1}), "attribute labels_ must hold integers >= 0"),
        (lambda h, a: a.update({"attr/labels_": a["attr/labels_"][:-1]}),
         r"responsibilities_ of shape \(12, 2\) disagrees with axis 0 of labels_ \(shape \(11,\)\)"),
        (lambda h, a: a.update({"attr/mixture_weights_": np.ones(3)}), r"axis 0 \(K\) has length 3, not 2"),
        (lambda h, a: h["attributes"].update(converged_="yes"), "attribute converged_ must be True or False; got 'yes'"),
        (lambda h, a: h["attributes"].update(best_log_likelihood_=None), "attribute best_log_likelihood_ must be a finite number"),
        (lambda h, a: h["attributes"].update(transfer_loss_=[1.0]), "'transfer_loss_' is not a learnt attribute of MultiIntentIRL"),
        (lambda h, a: h["params"].update(execution__n_jobs=2), "'execution__n_jobs' is never saved"),
        (lambda h, a: h["params"].update(solver={"solver_settings": {"h_solver": "nope"}}),
         "the solver settings of parameter solver are not valid here"),
        (lambda h, a: h["params"].update(solver={"name": "armijo"}), "parameter solver must be a name or"),
        (lambda h, a: (h["array_params"].append("start__init"), a.update({"param/start__init": np.zeros((2, 2, 2))})),
         r"parameter start__init must be a 1-d \(labels\) or 2-d \(responsibilities\) array"),
        (lambda h, a: h["array_params"].append("beta"), r"'beta' is not an array parameter \(known: features, start__init\)"),
    ],
)
def test_crafted_em_files_are_refused(fitted_models, tmp_path, edit, match):
    path = fo.save_model(fitted_models["multi-intent-flat"], tmp_path / "em.npz")
    with pytest.raises(PersistenceError, match=match):
        fo.load_model(_rewrite(path, tmp_path / "bad.npz", edit))
