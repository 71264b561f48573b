"""Audit: arrays and matrices a model hands out cannot be used to change the model.

Variants beyond setting attributes and writing into ``transitions``: turning the write flag
back on, reassigning or resizing the CSR matrix returned by ``transition_matrix``/``csr()``,
and the dense copy a sparse model builds on request.
"""

import copy
import pickle

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo


def models(grid3):
    dense = fo.TabularMDP(np.array(grid3.transitions), 0.9)
    sparse = fo.TabularMDP(sp.csr_matrix(dense.transition_matrix), 0.9)
    return {"dense": dense, "sparse": sparse, "grid": grid3}


@pytest.fixture(params=["dense", "sparse", "grid"])
def mdp(request, grid3):
    return models(grid3)[request.param]


def unchanged(mdp, before, rewards):
    assert mdp.signature() == before["signature"]
    np.testing.assert_array_equal(fo.optimal_q(mdp, rewards)[0], before["q"])
    np.testing.assert_array_equal(pickle.loads(pickle.dumps(mdp)).transitions, before["P"])


def snapshot(mdp, rewards):
    return {"signature": mdp.signature(), "q": fo.optimal_q(mdp, rewards)[0], "P": np.array(mdp.transitions)}


@pytest.mark.parametrize("getter", ["transitions", "transition_matrix"])
def test_write_flag_cannot_be_turned_back_on(mdp, getter, rng):
    R = rng.normal(size=(2, 9, 4))
    before = snapshot(mdp, R)
    arr = getattr(mdp, getter)
    if sp.issparse(arr):
        arr = arr.data
    with pytest.raises(ValueError):
        arr.setflags(write=True)
    with pytest.raises(ValueError):
        arr[(0,) * arr.ndim] = 1.0
    unchanged(mdp, before, R)


@pytest.mark.parametrize("getter", ["csr", "transition_matrix"])
@pytest.mark.parametrize("attack", ["data", "indices", "resize", "shape"])
def test_the_csr_matrix_handed_out_is_not_the_models(mdp, getter, attack, rng):
    R = rng.normal(size=(2, 9, 4))
    before = snapshot(mdp, R)
    P = mdp.csr() if getter == "csr" else mdp.transition_matrix
    if not sp.issparse(P):
        pytest.skip("a dense model's transition_matrix is an ndarray")
    if attack == "data":
        P.data = np.full_like(P.data, 1.0 / 9)
    elif attack == "indices":
        P.indices = P.indices[::-1].copy()
    elif attack == "resize":
        P.resize((36, 10))
    else:
        P.indptr = np.zeros_like(P.indptr)
    unchanged(mdp, before, R)
    assert mdp.csr().shape == (36, 9)


def test_deep_copies_and_pickles_of_a_model_handed_out_matrix(grid3):
    sparse = models(grid3)["sparse"]
    P = sparse.transition_matrix
    P2 = copy.deepcopy(P)
    P2.data = P2.data.copy()
    P2.data[:] = 0  # a copy may be changed freely
    assert sparse.csr().data.sum() == pytest.approx(36.0)


def test_the_array_transfer_returns_is_not_the_models(grid3, rng):
    demos = fo.sample_demonstrations(grid3, rng.normal(size=(2, 9, 4)), 2, 4, rng)
    model = fo.FactIRL(n_primitives=2, max_iter=2, rng=0).fit(grid3, demos)
    h = model.transfer(grid3, demos)
    kept = model.transfer_coefficients_.copy()
    h *= 0.0
    np.testing.assert_array_equal(model.transfer_coefficients_, kept)


def test_the_arrays_fit_keeps_are_not_the_callers(grid3, rng):
    demos = fo.sample_demonstrations(grid3, rng.normal(size=(2, 9, 4)), 2, 4, rng)
    D0, H0 = rng.normal(size=(36, 2)), rng.normal(size=(2, 2))
    model = fo.FactIRL(n_primitives=2, max_iter=1, init=(D0, H0)).fit(grid3, demos)
    before = model.dictionary_.copy()
    D0[:] = 0.0
    H0[:] = 0.0
    np.testing.assert_array_equal(model.dictionary_, before)
