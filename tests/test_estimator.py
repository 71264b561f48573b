"""The estimators in the scikit-learn manner (factirl_opt.learners.estimator): parameters from ``__init__``,
get_params/set_params, clone, repr, keyword-only parameters, the shared names and execution
settings, deprecated names, and the solver settings as one value."""

import inspect
import pickle
import warnings

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt import _deprecation
from factirl_opt.learners.estimator import Estimator, clone
from factirl_opt.learners.solver_settings import estimator_solvers
from factirl_opt.exceptions import DeprecatedNameWarning, SolverOptionError, ValidationError

ESTIMATORS = [(fo.GradIRL, {}), (fo.FactIRL, {"n_primitives": 2}), (fo.MultiIntentIRL, {"n_intentions": 2})]
IDS = [cls.__name__ for cls, _ in ESTIMATORS]
SHARED = {"features", "reward", "objective", "max_iter", "tol", "solver", "execution"}
EXECUTION = {"n_jobs", "backend", "client", "planner", "planner_options", "verbose", "callback"}
#: the constructor parameters at most (scikit-learn's largest estimators take 18 to 23)
MOST_PARAMS = {"GradIRL": 12, "FactIRL": 20, "MultiIntentIRL": 18}


@pytest.fixture(autouse=True)
def fresh_warnings(monkeypatch):
    """Each test sees the once-per-process deprecation warnings afresh."""
    monkeypatch.setattr(_deprecation, "_warned", set())


@pytest.fixture(scope="module")
def tasks():
    mdp = fo.GridWorld(size=3)
    R = np.random.default_rng(0).normal(size=(3, mdp.n_states, mdp.n_actions))
    demos = fo.sample_demonstrations(mdp, R, n_demos=3, length=5, rng=1)
    return mdp, demos, [ep for task in demos for ep in task]


# --- parameters -------------------------------------------------------------------------------


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_get_params_lists_init_and_rebuilds_the_estimator(cls, kw):
    est = cls(**kw)
    params = est.get_params()
    assert list(params) == [p for p in inspect.signature(cls).parameters] == cls.param_names()
    assert est.get_params(deep=False) == params
    twin = cls(**params)
    assert type(twin) is cls and twin.get_params() == params


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_init_only_stores_its_arguments(cls, kw):
    values = {name: object() for name in cls.param_names()}  # no validation, no conversion in __init__
    est = cls(**values)
    assert all(est.get_params()[name] is value for name, value in values.items())


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_set_params_round_trip_returns_self(cls, kw):
    est = cls(**kw)
    F = np.ones((36, 2))
    assert est.set_params(max_iter=7, tol=0.5, features=F) is est
    params = est.get_params()
    assert params["max_iter"] == 7 and params["tol"] == 0.5 and params["features"] is F
    assert cls(**params).get_params()["max_iter"] == 7
    assert est.set_params() is est and est.get_params() == params


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_set_params_refuses_unknown_names_and_sets_nothing(cls, kw):
    est = cls(**kw)
    with pytest.raises(ValidationError, match=rf"'n_components' is not a parameter of {cls.__name__}; its parameters are "
                                              rf"{list(est.get_params())[0]}, "):
        est.set_params(max_iter=9, n_components=3)
    assert est.max_iter != 9 and not hasattr(est, "n_components")


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_the_same_names_and_execution_settings_on_every_estimator(cls, kw):
    names = set(cls.param_names())
    assert SHARED <= names, SHARED - names
    assert set(fo.Execution().get_params()) == EXECUTION and not EXECUTION & names
    assert not {"h_solver", "h_solver_options", "solver_options", "d_solver", "d_solver_options"} & names
    assert len(names) <= MOST_PARAMS[cls.__name__]


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_the_former_flat_names_set_the_groups_with_one_warning(cls, kw):
    from factirl_opt import _deprecation
    from factirl_opt.exceptions import DeprecatedNameWarning

    _deprecation._warned.clear()
    with pytest.warns(DeprecatedNameWarning) as record:
        est = cls(**kw, n_jobs=2, planner="dense")
    assert len(record) == 2  # one per former name
    assert est.execution == fo.Execution(n_jobs=2, planner="dense")
    with pytest.warns(DeprecatedNameWarning) as record:
        est.callback = print
    assert len(record) == 1 and est.execution.callback is print
    with pytest.warns(DeprecatedNameWarning) as record:
        assert est.verbose is False
    assert len(record) == 1
    with pytest.warns(DeprecatedNameWarning) as record:
        est.set_params(backend="dask")
    assert len(record) == 1 and est.execution.backend == "dask" and est.execution.n_jobs == 2
    twin = clone(est)
    assert twin.get_params(deep=True) == est.get_params(deep=True) and twin.execution is not est.execution


@pytest.mark.parametrize("cls, kw", ESTIMATORS, ids=IDS)
def test_at_most_two_positional_parameters(cls, kw):
    params = list(inspect.signature(cls).parameters.values())
    positional = [p.name for p in params if p.kind == p.POSITIONAL_OR_KEYWORD]
    assert len(positional) == 2 and all(p.kind == p.KEYWORD_ONLY for p in params[2:])
    args = [kw.get(positional[0], 5.0), None, 100]
    with pytest.raises(TypeError, match="takes from .* positional arguments but 4 were given"):
        cls(*args)


def test_a_subclass_must_name_its_parameters():
    class Loose(fo.GradIRL):
        def __init__(self, **kw):
            super().__init__(**kw)

    with pytest.raises(TypeError, match=r"Loose.__init__ must name its parameters \(no \*kw\)"):
        Loose(beta=2.0).get_params()
    assert repr(Loose()).startswith("<")  # the repr falls back rather than raising


# --- clone and repr ---------------------------------------------------------------------------


def test_clone_copies_data_shares_objects_and_drops_the_fit(tasks):
    mdp, demos, _ = tasks
    F, calls = np.random.default_rng(2).random((mdp.n_states, 2)), []
    rng = np.random.default_rng(3)
    model = fo.FactIRL(2, features=F, rng=rng, solver=fo.SolverSettings("armijo", {"initial_step": 0.5}), max_iter=2,
                       start=fo.Start(flat_max_iter=3),
                       execution=fo.Execution(callback=lambda it, loss: calls.append(it))).fit(mdp, demos)
    twin = clone(model)
    assert type(twin) is fo.FactIRL and not hasattr(twin, "dictionary_") and not hasattr(twin, "loss_")
    assert twin.features is not F and np.array_equal(twin.features, F)
    assert twin.solver == model.solver and twin.start == model.start and twin.execution == model.execution
    assert twin.rng is not rng and twin.rng.bit_generator.state == rng.bit_generator.state
    assert twin.execution.callback is model.execution.callback
    assert twin.get_params().keys() == model.get_params().keys()
    labels = np.arange(4) % 2
    em = fo.MultiIntentIRL(2, start=fo.IntentionStart(init=labels))
    assert clone(em).start.init is not labels and np.array_equal(clone(em).start.init, labels)  # data in a group copied
    for est in (fo.GradIRL(beta=2.0), fo.MultiIntentIRL("auto", n_intentions_range=(1, 3))):
        assert repr(clone(est)) == repr(est)
    with pytest.raises(ValidationError, match="clone takes an estimator .*; got dict"):
        clone({"beta": 1.0})


def test_sklearn_clone_works_without_sklearn_being_a_dependency():
    base = pytest.importorskip("sklearn.base")
    twin = base.clone(fo.FactIRL(3, solver="lbfgs"))
    assert type(twin) is fo.FactIRL and twin.solver == "lbfgs"


def test_repr_shows_the_parameters_that_differ_from_their_defaults():
    assert repr(fo.GradIRL()) == "GradIRL()"
    assert repr(fo.GradIRL(5.0, max_iter=100, tol=np.float64(1e-5))) == "GradIRL()"
    assert repr(fo.GradIRL(beta=2, reward="state")) == "GradIRL(beta=2, reward='state')"
    assert repr(fo.FactIRL(3, features=np.ones((9, 4)), solver="lbfgs", rng=np.random.default_rng(0))) == (
        "FactIRL(n_primitives=3, features=<array (9, 4)>, solver='lbfgs', rng=Generator(PCG64))")
    assert repr(fo.MultiIntentIRL(2, features=[np.ones((9, 2))] * 3, execution=fo.Execution(callback=print))) == (
        "MultiIntentIRL(n_intentions=2, features=<list of 3 arrays>, execution=Execution(callback=<built-in function "
        "print>))")
    settings = fo.SolverSettings("armijo", d_solver="lbfgs")
    assert repr(fo.FactIRL(solver=settings)) == f"FactIRL(solver={settings!r})"


# --- deprecated names -------------------------------------------------------------------------


def test_old_solver_names_of_factirl_warn_once_and_set_the_new_ones(tasks):
    with pytest.warns(DeprecatedNameWarning, match="FactIRL: the parameter 'h_solver' is now called 'solver'"):
        model = fo.FactIRL(2, h_solver="lbfgs", max_iter=1, flat_max_iter=2)
    assert model.solver == "lbfgs" and "h_solver" not in model.get_params() and "h_solver" not in vars(model)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # once per process: no second warning
        again = fo.FactIRL(2, h_solver="armijo")
        assert again.h_solver == "armijo"  # the old attribute name reads the new one (already warned)
    with pytest.warns(DeprecatedNameWarning, match=r"'h_solver_options' is now the field 'h_solver_options' of "
                                                   r"solver=SolverSettings\(...\) \(set_params\(solver__h_solver_options"):
        model.set_params(h_solver_options={"memory": 3})
    assert model.solver_options == {"memory": 3}
    model.h_solver = "lbfgs"
    assert model.solver == "lbfgs"
    mdp, demos, _ = tasks
    h = model.fit(mdp, demos).transfer(mdp, demos[:1], h_solver="lbfgs", max_iter=2)
    assert h.shape == (1, 2)
    with pytest.raises(TypeError, match="got both 'h_solver' and 'solver'"):
        fo.FactIRL(h_solver="lbfgs", solver="armijo")


def test_a_pickle_with_the_old_names_or_without_new_parameters_loads():
    model = fo.MultiIntentIRL(2)
    state = dict(vars(model))
    del state["execution"]  # pickled before this parameter existed
    # a FactIRL pickled before the groups, with the names of before the renames
    old_state = {k: v for k, v in vars(fo.FactIRL(3)).items() if k not in ("solver", "start", "execution")}
    old_state.update(h_solver="lbfgs", h_solver_options={"memory": 2}, d_solver="armijo", n_jobs=None, verbose=False,
                     init="random", flat_max_iter=7, planner="dense")
    back, old_back = fo.MultiIntentIRL.__new__(fo.MultiIntentIRL), fo.FactIRL.__new__(fo.FactIRL)
    back.__setstate__(state)
    old_back.__setstate__(old_state)
    assert back.execution is None
    assert old_back.solver == fo.SolverSettings("lbfgs", {"memory": 2}, d_solver="armijo")
    assert old_back.start == fo.Start(init="random", flat_max_iter=7)
    assert old_back.execution == fo.Execution(planner="dense")
    assert pickle.loads(pickle.dumps(old_back)).get_params() == old_back.get_params()


def test_saved_files_with_the_old_names_load_without_a_warning(tmp_path):
    import json

    path = fo.save_model(fo.FactIRL(3, solver="lbfgs", start=fo.Start(flat_max_iter=7)), tmp_path / "m.npz")
    with np.load(path, allow_pickle=False) as npz:
        header = json.loads(str(npz["__header__"][()]))
        arrays = {k: npz[k] for k in npz.files if k != "__header__"}
    params = header["params"]
    params["h_solver"] = params.pop("solver")  # the names of before the renames, and of before the groups
    params.update(h_solver_options={"memory": 2}, d_solver="armijo", d_solver_options=None, flat_solver="armijo")
    params.update({key.partition("__")[2]: params.pop(key) for key in list(params) if "__" in key})
    del params["execution"]
    params.update(planner="auto", verbose=False)
    np.savez(tmp_path / "old.npz", __header__=np.array(json.dumps(header)), **arrays)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        loaded = fo.load_model(tmp_path / "old.npz")
    assert loaded.solver == fo.SolverSettings("lbfgs", {"memory": 2}, d_solver="armijo", flat_solver="armijo")
    assert loaded.start == fo.Start(flat_max_iter=7) and loaded.execution == fo.Execution()


# --- solver settings as one value -------------------------------------------------------------


def test_solver_settings_as_one_value_fit_as_the_names(tasks):
    mdp, demos, episodes = tasks
    settings = fo.SolverSettings("armijo", {"initial_step": 0.5}, d_solver="lbfgs")
    kw = dict(max_iter=2, flat_max_iter=3, init="random", rng=0)
    a = fo.FactIRL(2, solver=settings, **kw).fit(mdp, demos)
    b = fo.FactIRL(2, solver="armijo", solver_options={"initial_step": 0.5}, d_solver="lbfgs", **kw).fit(mdp, demos)
    np.testing.assert_array_equal(a.dictionary_, b.dictionary_)
    np.testing.assert_array_equal(a.transfer(mdp, demos[:1]), b.transfer(mdp, demos[:1]))
    np.testing.assert_array_equal(a.transfer(mdp, demos[:1], solver=fo.SolverSettings("lbfgs")),
                                  b.transfer(mdp, demos[:1], solver="lbfgs"))
    flat = fo.GradIRL(solver=fo.SolverSettings("armijo", {"initial_step": 0.5}), max_iter=3).fit(mdp, demos)
    flat_names = fo.GradIRL(solver="armijo", solver_options={"initial_step": 0.5}, max_iter=3).fit(mdp, demos)
    np.testing.assert_array_equal(flat.weights_, flat_names.weights_)
    em = dict(max_iter=2, m_step_max_iter=2, rng=0)
    c = fo.MultiIntentIRL(2, 2, solver=fo.SolverSettings("armijo", d_solver="lbfgs"), **em).fit(mdp, episodes)
    d = fo.MultiIntentIRL(2, 2, solver="armijo", d_solver="lbfgs", **em).fit(mdp, episodes)
    np.testing.assert_array_equal(c.dictionary_, d.dictionary_)


def test_solver_settings_and_names_together_are_refused(tasks):
    mdp, demos, episodes = tasks
    settings = fo.SolverSettings("armijo", d_solver="lbfgs")
    with pytest.raises(ValidationError, match="either as one SolverSettings in solver or per name.*d_solver='gn-cg'"):
        fo.FactIRL(2, solver=settings, d_solver="gn-cg").fit(mdp, demos)
    with pytest.raises(ValidationError, match="either as one Execution in execution or per name.*n_jobs=2"):
        fo.FactIRL(2, execution=fo.Execution(), n_jobs=2)
    with pytest.raises(ValidationError, match="solver_options="):
        fo.MultiIntentIRL(2, solver=settings, solver_options={"c": 0.1}).fit(mdp, episodes)
    with pytest.raises(ValidationError, match="GradIRL has no D-step: .* got 'armijo | d: lbfgs'"):
        fo.GradIRL(solver=settings).fit(mdp, demos)
    model = fo.FactIRL(2, max_iter=1, flat_max_iter=2).fit(mdp, demos)
    with pytest.raises(ValidationError, match="solver_options given with solver settings 'armijo'"):
        model.transfer(mdp, demos[:1], solver=fo.SolverSettings(), solver_options={"c": 0.1})


# --- MultiIntentIRL's solvers and execution settings ------------------------------------------


def test_multi_intent_solvers_reach_its_m_steps(tasks):
    mdp, _, episodes = tasks
    kw = dict(max_iter=2, m_step_max_iter=3, rng=0)
    base = fo.MultiIntentIRL(2, 2, **kw).fit(mdp, episodes)
    same = fo.MultiIntentIRL(2, 2, d_solver="armijo", **kw).fit(mdp, episodes)  # None is the H-step's solver
    np.testing.assert_array_equal(same.dictionary_, base.dictionary_)
    other = fo.MultiIntentIRL(2, 2, d_solver="lbfgs", **kw).fit(mdp, episodes)
    assert not np.array_equal(other.dictionary_, base.dictionary_)
    stepped = fo.MultiIntentIRL(2, solver_options={"initial_step": 0.01}, **kw).fit(mdp, episodes)
    assert not np.array_equal(stepped.weights_, fo.MultiIntentIRL(2, **kw).fit(mdp, episodes).weights_)
    with pytest.raises(SolverOptionError, match="does not accept option"):
        fo.MultiIntentIRL(2, solver_options={"bogus": 1}, **kw).fit(mdp, episodes)
    with pytest.raises(ValidationError, match="d_solver_options given without d_solver"):
        fo.MultiIntentIRL(2, 2, d_solver_options={"memory": 3}, **kw).fit(mdp, episodes)
    fact = other.to_factirl()
    assert fact.solver == fo.SolverSettings("armijo", d_solver="lbfgs")
    assert estimator_solvers(base.to_factirl())[2] == "armijo"  # FactIRL's default D-step


def test_multi_intent_execution_settings(tasks, capsys):
    mdp, _, episodes = tasks
    kw = dict(max_iter=2, m_step_max_iter=3, rng=0, n_init=2)
    seen = []
    a = fo.MultiIntentIRL(2, 2, callback=lambda it, ll: seen.append(it), **kw).fit(mdp, episodes)
    assert seen == [1, 2, 1, 2]  # the iterations of each of the n_init runs
    b = fo.MultiIntentIRL(2, 2, verbose=True, planner_options={"max_bytes": 1}, **kw).fit(mdp, episodes)
    assert "MultiIntentIRL.fit" in capsys.readouterr().err and "log-likelihood" not in capsys.readouterr().out
    np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=1e-9, atol=1e-12)  # the budget: chunked planning
    with pytest.raises(ValidationError, match="verbose must be True or False; got 'yes'"):
        fo.MultiIntentIRL(2, verbose="yes").fit(mdp, episodes)
    with pytest.raises(ValidationError, match="callback must be callable .* got int"):
        fo.MultiIntentIRL(2, callback=3).fit(mdp, episodes)
    with pytest.raises(ValidationError, match="planner_options"):
        fo.MultiIntentIRL(2, planner_options={"bogus": 1}).fit(mdp, episodes)
    with pytest.raises(ValidationError, match="backend"):
        fo.MultiIntentIRL(2, backend="threads", **kw).fit(mdp, episodes)


def test_multi_intent_n_jobs_gives_the_serial_fit(tasks):
    mdp, _, episodes = tasks
    kw = dict(max_iter=2, m_step_max_iter=3, rng=0)
    for k in (None, 2):
        a = fo.MultiIntentIRL(2, k, **kw).fit(mdp, episodes)
        b = fo.MultiIntentIRL(2, k, n_jobs=2, **kw).fit(mdp, episodes)
        np.testing.assert_array_equal(b.labels_, a.labels_)
        np.testing.assert_allclose(b.rewards_, a.rewards_, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(b.log_likelihood_, a.log_likelihood_, rtol=1e-10)


def test_estimator_is_the_base_of_the_three():
    assert all(issubclass(cls, Estimator) for cls, _ in ESTIMATORS)
    assert issubclass(DeprecatedNameWarning, FutureWarning)
