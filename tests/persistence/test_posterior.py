"""FactIRL.transfer_posterior_ through save_model / load_model (factirl_opt.persistence.posterior)."""

import json

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import PersistenceError


def _rewrite(src, dst, edit):
    """Copy a model file, editing its header and arrays with ``edit(header, arrays)``."""
    with np.load(src, allow_pickle=False) as z:
        arrays = {k: z[k] for k in z.files}
    header = json.loads(str(arrays.pop("__header__")))
    edit(header, arrays)
    np.savez(dst, __header__=np.array(json.dumps(header)), **arrays)
    return dst


@pytest.fixture(scope="module")
def transferred(grid_tasks):
    mdp, demos, new_demos, _, _ = grid_tasks
    model = fo.FactIRL(n_primitives=2, rng=1, max_iter=3, inner_steps=2, flat_max_iter=5, transfer_max_iter=5)
    model.fit(mdp, demos)
    model.transfer(mdp, new_demos)
    return model


def test_transfer_posterior_round_trips(transferred, tmp_path):
    loaded = fo.load_model(fo.save_model(transferred, tmp_path / "m.npz"))
    before, after = transferred.transfer_posterior_, loaded.transfer_posterior_
    assert len(after) == len(before) == 2
    for a, b in zip(before, after):
        np.testing.assert_array_equal(a.mean, b.mean)
        np.testing.assert_array_equal(a.covariance, b.covariance)
        np.testing.assert_array_equal(a.dictionary, b.dictionary)
        assert (a.scaling, a.n_pairs) == (b.scaling, b.n_pairs)
        np.testing.assert_array_equal(a.sample_rewards(4, 3), b.sample_rewards(4, 3))
        np.testing.assert_allclose(a.sample_regrets(4, 3), b.sample_regrets(4, 3), atol=1e-9)
        assert b.mdp.signature() == a.mdp.signature()
    assert after[0].mdp is after[1].mdp  # one MDP stored once


def test_model_without_transfer_has_no_posterior_after_loading(fitted_models, tmp_path):
    loaded = fo.load_model(fo.save_model(fitted_models["factirl-tabular"], tmp_path / "m.npz"))
    with pytest.raises(AttributeError, match="transferred no tasks"):
        loaded.transfer_posterior_


def test_undefined_posterior_round_trips_as_none(grid_tasks, tmp_path):
    mdp, demos, new_demos, _, _ = grid_tasks
    model = fo.FactIRL(n_primitives=2, rng=1, max_iter=2, inner_steps=2, flat_max_iter=5, transfer_max_iter=5)
    model.fit(mdp, demos[:1])  # one training task: no prior to fit
    model.transfer(mdp, new_demos)
    assert model.transfer_posterior_ is None
    assert fo.load_model(fo.save_model(model, tmp_path / "m.npz")).transfer_posterior_ is None


def test_malformed_posterior_members_are_refused(transferred, tmp_path):
    path = fo.save_model(transferred, tmp_path / "m.npz")

    def drop_header(header, arrays):
        del header["transfer_posterior"]

    def drop_mean(header, arrays):
        del arrays["posterior/mean"]

    def bad_spec(header, arrays):
        header["transfer_posterior"] = [1, 2]

    def nan_cov(header, arrays):
        arrays["posterior/covariance"] = arrays["posterior/covariance"] * np.nan

    for edit, match in ((drop_header, "has no 'transfer_posterior'"), (drop_mean, "incomplete or malformed"),
                        (bad_spec, "must be null or a dict"), (nan_cov, "non-finite")):
        with pytest.raises(PersistenceError, match=match):
            fo.load_model(_rewrite(path, tmp_path / "bad.npz", edit))
