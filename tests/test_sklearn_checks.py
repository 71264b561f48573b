"""scikit-learn's own checks on the three estimators (factirl_opt.learners.estimator), and its
parameter protocol: nested parameters under ``<parameter>__<name>``, ``sklearn.base.clone`` and
:func:`~factirl_opt.learners.estimator.clone` with scikit-learn's check that the constructor
stores each parameter unchanged, and the repr.

Only the checks that do not need ``fit(X, y)`` apply: the estimators fit an MDP and
demonstrations, not a design matrix.
"""

import warnings

import numpy as np
import pytest
import sklearn.base
from sklearn.utils import estimator_checks

import factirl_opt as fo
from factirl_opt import _deprecation
from factirl_opt.exceptions import DeprecatedNameWarning, UnknownSolverError, ValidationError
from factirl_opt.learners.estimator import Estimator, clone

SETTINGS = fo.SolverSettings("gn-qp-osqp", {"alpha": 0.03}, d_solver="lbfgs")
CASES = {
    "GradIRL": lambda: fo.GradIRL(),
    "GradIRL-settings": lambda: fo.GradIRL(2.0, solver=fo.SolverSettings("lbfgs", {"initial_step": 0.5})),
    "FactIRL": lambda: fo.FactIRL(),
    "FactIRL-settings": lambda: fo.FactIRL(3, features=np.ones((9, 2)), rng=np.random.default_rng(0), solver=SETTINGS),
    "MultiIntentIRL": lambda: fo.MultiIntentIRL(2),
    "MultiIntentIRL-settings": lambda: fo.MultiIntentIRL("auto", n_intentions_range=(1, 3), solver=SETTINGS),
}
#: scikit-learn's checks that need no fit(X, y) (check_estimators_overwrite_params and the other
#: fit-based checks do); clone and repr by its own check_estimator_cloneable and check_estimator_repr
SKLEARN_CHECKS = ["check_parameters_default_constructible", "check_get_params_invariance", "check_set_params",
                  "check_no_attributes_set_in_init", "check_estimator_cloneable", "check_estimator_repr",
                  "check_do_not_raise_errors_in_init_or_set_params"]


@pytest.fixture(autouse=True)
def fresh_warnings(monkeypatch):
    """Each test sees the once-per-process deprecation warnings afresh."""
    monkeypatch.setattr(_deprecation, "_warned", set())


@pytest.mark.parametrize("check", SKLEARN_CHECKS)
@pytest.mark.parametrize("case", CASES)
def test_sklearn_estimator_checks_pass(case, check):
    est = CASES[case]()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # check_set_params only warns when set_params refuses a value
        getattr(estimator_checks, check)(type(est).__name__, est)


@pytest.mark.parametrize("case", CASES)
def test_sklearn_clone_and_repr(case):
    est = CASES[case]()
    for twin in (sklearn.base.clone(est), clone(est)):
        assert type(twin) is type(est) and twin is not est
        assert repr(twin) == repr(est) and "__" not in repr(est)
        assert twin.get_params(deep=True).keys() == est.get_params(deep=True).keys()
        for name, value in est.get_params(deep=False).items():
            other = twin.get_params(deep=False)[name]
            if isinstance(value, np.ndarray):
                assert other is not value and np.array_equal(other, value)
            elif isinstance(value, np.random.Generator):
                assert other is not value and other.bit_generator.state == value.bit_generator.state
            else:
                assert other == value, name


# --- nested parameters ------------------------------------------------------------------------


@pytest.mark.parametrize("cls, kw", [(fo.GradIRL, {}), (fo.FactIRL, {}), (fo.MultiIntentIRL, {"n_intentions": 2})],
                         ids=["GradIRL", "FactIRL", "MultiIntentIRL"])
def test_get_params_deep_gives_the_solver_settings_fields(cls, kw):
    settings = fo.SolverSettings("lbfgs", {"initial_step": 0.5})
    est = cls(**kw, solver=settings)
    shallow, deep = est.get_params(deep=False), est.get_params(deep=True)
    assert not any("__" in key for key in shallow) and shallow.items() <= deep.items()
    assert {key: deep[key] for key in deep.keys() - shallow.keys()} == {
        "solver__h_solver": "lbfgs", "solver__h_solver_options": '{"initial_step":0.5}', "solver__d_solver": "",
        "solver__d_solver_options": "", "solver__flat_solver": "", "solver__flat_solver_options": "",
        "solver__transfer_solver": "", "solver__transfer_solver_options": ""}
    assert cls(**kw).get_params(deep=True) == cls(**kw).get_params(deep=False)  # a solver name has no parameters


@pytest.mark.parametrize("cls, kw", [(fo.GradIRL, {}), (fo.FactIRL, {}), (fo.MultiIntentIRL, {"n_intentions": 2})],
                         ids=["GradIRL", "FactIRL", "MultiIntentIRL"])
def test_set_params_sets_the_solver_settings_fields(cls, kw):
    settings = fo.SolverSettings("lbfgs", {"initial_step": 0.5})
    est = cls(**kw, solver=settings)
    assert est.set_params(solver__h_solver="armijo", solver__h_solver_options=None, max_iter=7) is est
    assert est.solver == fo.SolverSettings("armijo") and est.max_iter == 7
    assert settings == fo.SolverSettings("lbfgs", {"initial_step": 0.5})  # frozen: a new value replaced it
    est.set_params(solver=fo.SolverSettings("gn-qp-osqp"), solver__h_solver_options={"alpha": 0.1})
    assert est.solver == fo.SolverSettings("gn-qp-osqp", {"alpha": 0.1})  # nested keys apply to the new value
    assert est.get_params()["solver__h_solver_options"] == '{"alpha":0.1}'
    est.set_params(solver="armijo", solver__d_solver="lbfgs")  # a solver name is the H-step's settings
    assert est.solver == fo.SolverSettings("armijo", d_solver="lbfgs")


def test_set_params_refuses_bad_nested_keys_and_sets_nothing():
    est = fo.FactIRL(solver=SETTINGS)
    with pytest.raises(ValidationError, match=r"'solver__h_solvr' is not a parameter of FactIRL: its parameter solver "
                                              r"\(SolverSettings\) has the parameters h_solver, h_solver_options, "):
        est.set_params(max_iter=9, solver__h_solvr="lbfgs")
    with pytest.raises(ValidationError, match=r"'max_iter__x' is not a parameter of FactIRL: its parameter "
                                              r"max_iter=100 has no parameters of its own"):
        est.set_params(beta=1.0, max_iter__x=3)
    with pytest.raises(ValidationError, match=r"'objective__x' is not a parameter of FactIRL: its parameter "
                                              r"objective='mce' has no parameters of its own"):
        est.set_params(objective="mce", objective__x=1)
    with pytest.raises(ValidationError, match=r"'bogus__x' is not a parameter of FactIRL; its parameters are "):
        est.set_params(bogus__x=1)
    with pytest.raises(UnknownSolverError, match="no-such-solver"):
        est.set_params(max_iter=9, solver__h_solver="no-such-solver")
    assert est.max_iter == 100 and est.beta == 5.0 and est.solver is SETTINGS


def test_set_params_nested_under_a_deprecated_name_warns_and_sets_the_new_name():
    est = fo.FactIRL(solver=SETTINGS)
    with pytest.warns(DeprecatedNameWarning, match="'h_solver' is now called 'solver'"):
        est.set_params(h_solver__h_solver="gn-qp-clarabel")
    assert est.solver.h_solver == "gn-qp-clarabel" and "h_solver" not in vars(est)


class Wrapper(Estimator):
    """An estimator with an estimator parameter, as a user's meta-estimator would be."""

    def __init__(self, inner=None, alpha=1.0):
        self.inner = inner
        self.alpha = alpha


def test_an_estimator_parameter_nests_and_is_cloned():
    inner = fo.FactIRL(2, solver=SETTINGS)
    outer = Wrapper(inner)
    deep = outer.get_params(deep=True)
    assert deep["inner"] is inner and deep["inner__n_primitives"] == 2 and deep["inner__solver__h_solver"] == "gn-qp-osqp"
    assert outer.set_params(inner__beta=2.0, inner__solver__d_solver="armijo", alpha=0.5) is outer
    assert outer.inner is inner and inner.beta == 2.0 and inner.solver.d_solver == "armijo" and outer.alpha == 0.5
    for twin in (clone(outer), sklearn.base.clone(outer)):
        assert twin.inner is not inner and type(twin.inner) is fo.FactIRL and repr(twin.inner) == repr(inner)
    estimator_checks.check_get_params_invariance("Wrapper", outer)
    estimator_checks.check_set_params("Wrapper", outer)


# --- clone's check of the constructor ---------------------------------------------------------


class Converts(Estimator):
    """A constructor that converts its argument: scikit-learn's clone refuses it."""

    def __init__(self, values=(1, 2), beta=1.0):
        self.values = list(values)
        self.beta = beta


class Validates(Estimator):
    """A constructor that stores a copy of an equal value: not the object given."""

    def __init__(self, beta=1.0, weights=None):
        self.beta = beta
        self.weights = None if weights is None else dict(weights)


@pytest.mark.parametrize("cls, param", [(Converts, "values"), (Validates, "weights")])
def test_clone_refuses_a_constructor_that_changes_a_parameter(cls, param):
    est = cls(**{param: {"a": 1} if cls is Validates else (3, 4)})
    with pytest.raises(RuntimeError, match=rf"cannot clone {cls.__name__}: its __init__ does not store the parameter "
                                           rf"'{param}' as given"):
        clone(est)
    with pytest.raises(RuntimeError, match=param):  # as scikit-learn's own clone does
        sklearn.base.clone(est)


# --- the settings value itself ----------------------------------------------------------------


def test_solver_settings_follow_the_parameter_protocol():
    params = SETTINGS.get_params()
    assert params == SETTINGS.get_params(deep=False)
    first_four = ("h_solver", "h_solver_options", "d_solver", "d_solver_options")
    assert SETTINGS.fields() == {k: params[k] for k in first_four}  # the flat and transfer steps' only when set
    assert not any(params[k] for k in params if k not in first_four)
    rebuilt = fo.SolverSettings(**params)
    assert rebuilt == SETTINGS and all(rebuilt.get_params()[k] is v for k, v in params.items())
    assert sklearn.base.clone(SETTINGS) == SETTINGS
    changed = SETTINGS.set_params(d_solver=None, d_solver_options=None)
    assert changed == fo.SolverSettings("gn-qp-osqp", {"alpha": 0.03}) and SETTINGS.d_solver == "lbfgs"
    with pytest.raises(ValidationError, match="'solver' is not a parameter of SolverSettings; its parameters are "
                                              "h_solver, h_solver_options, d_solver, d_solver_options, flat_solver, "
                                              "flat_solver_options, transfer_solver, transfer_solver_options$"):
        SETTINGS.set_params(solver="lbfgs")
    with pytest.raises(ValidationError, match="d_solver_options given without d_solver"):
        fo.SolverSettings(d_solver="lbfgs", d_solver_options={"memory": 3}).set_params(d_solver=None)
