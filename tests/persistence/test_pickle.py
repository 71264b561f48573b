"""Fitted estimators round-trip through pickle and copy.deepcopy (as joblib and Dask need)."""

import copy
import pickle

import numpy as np
import pytest

import factirl_opt as fo

CONFIGURATIONS = ["gradirl-tabular", "gradirl-features", "factirl-tabular", "factirl-features", "factirl-transfer",
                  "factirl-features-transfer", "multi-intent-flat", "multi-intent-shared", "multi-intent-auto"]
PLAIN = (np.ndarray, int, float, str, bool, list, tuple, dict, type(None), np.random.Generator, fo.SolverSettings,
         fo.Execution, fo.Start, fo.IntentionStart)


def record_loss(iteration, loss):
    """A module-level callback: pickled by name."""


def _assert_same(a, b):
    assert type(a) is type(b) and set(vars(a)) == set(vars(b))
    for key, value in vars(a).items():
        got = getattr(b, key)
        if key == "_transfer":  # the last transfer's tasks: the copy builds the same posterior from them
            for pa, pb in zip(a.transfer_posterior_ or [], b.transfer_posterior_ or []):
                np.testing.assert_array_equal(pa.mean, pb.mean)
                np.testing.assert_array_equal(pa.covariance, pb.covariance)
            continue
        if isinstance(value, np.ndarray):
            assert got.dtype == value.dtype
            np.testing.assert_array_equal(got, value, err_msg=key)
        elif isinstance(value, np.random.Generator):
            assert got.bit_generator.state == value.bit_generator.state
        else:
            assert got == value, key


@pytest.mark.parametrize("name", CONFIGURATIONS)
@pytest.mark.parametrize("how", ["pickle", "deepcopy"])
def test_fitted_models_round_trip(fitted_models, name, how):
    model = fitted_models[name]
    held = {k: v for k, v in vars(model).items() if k != "_transfer"}  # a transfer keeps its task set, privately
    assert all(isinstance(v, PLAIN) for v in held.values()), "an estimator holds only plain values (no MDP, no cache)"
    copied = pickle.loads(pickle.dumps(model)) if how == "pickle" else copy.deepcopy(model)
    _assert_same(model, copied)
    for key, value in vars(model).items():
        if isinstance(value, np.ndarray):
            assert not np.shares_memory(value, getattr(copied, key)), key


def test_a_copied_model_transfers_identically(fitted_models, grid_tasks):
    mdp, _, new_demos, _, _ = grid_tasks
    model = fitted_models["factirl-features-transfer"]
    copied = pickle.loads(pickle.dumps(model))
    np.testing.assert_array_equal(copied.transfer(mdp, new_demos), model.transfer_coefficients_)


def test_callbacks_in_pickle_and_deepcopy(fitted_models):
    model = copy.deepcopy(fitted_models["gradirl-tabular"])
    model.callback = record_loss
    assert pickle.loads(pickle.dumps(model)).callback is record_loss
    model.callback = lambda iteration, loss: None  # pickle's own error, naming the function (documented)
    with pytest.raises((pickle.PicklingError, AttributeError), match=r"[Cc]an't pickle .*lambda"):
        pickle.dumps(model)
    assert copy.deepcopy(model).callback is model.callback
