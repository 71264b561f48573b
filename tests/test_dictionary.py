"""The dictionary helpers of the factorial model: PCA start, feature weights, shrinking, orientation, norms."""

import numpy as np
import pytest

from factirl_opt.learners.dictionary import (
    feature_weights,
    normalise_dictionary,
    orient_nonneg,
    pca_dictionary,
    shrink_coefficients,
)
from factirl_opt.exceptions import FitInterrupted
from factirl_opt.tasks.features import StateBroadcast


def test_pca_dictionary_is_the_truncated_svd(rng):
    X = rng.standard_normal((6, 3)) @ rng.standard_normal((3, 10))
    D, H = pca_dictionary(X, 3)
    np.testing.assert_allclose(D.T @ D, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(H @ D.T, X, atol=1e-10)


def test_feature_weights_of_state_rewards_are_the_action_means(rng):
    S, A = 5, 3
    X = rng.standard_normal((S * A, 4))
    kron = np.kron(np.eye(S), np.ones((A, 1)))
    np.testing.assert_allclose(feature_weights(StateBroadcast(S, A), X), feature_weights(kron, X), atol=1e-12)
    np.testing.assert_allclose(feature_weights(StateBroadcast(S, A), X), X.reshape(S, A, 4).mean(axis=1), rtol=1e-15)


def test_shrink_coefficients_returns_the_best_halving():
    H = np.ones((2, 1))
    out, j, calls = shrink_coefficients(lambda X: np.array([(X.sum() - 0.5) ** 2]), H)  # an array loss is summed
    assert (j, calls) == (2, 4) and np.all(out == 0.25)


def test_an_interrupted_shrink_carries_its_best_point():
    H = np.ones((2, 1))
    calls = []

    def loss(X):
        calls.append(X)
        if len(calls) == 3:
            raise KeyboardInterrupt
        return (X.sum() - 0.1) ** 2

    with pytest.raises(FitInterrupted) as info:
        shrink_coefficients(loss, H)
    Hs, j, n_calls, best = info.value.result
    assert isinstance(info.value, KeyboardInterrupt)
    assert (j, n_calls) == (1, 2) and np.all(Hs == 0.5) and best == (1.0 - 0.1) ** 2
    with pytest.raises(FitInterrupted) as info:  # interrupted at the first call: the start, no loss
        shrink_coefficients(lambda X: (_ for _ in ()).throw(KeyboardInterrupt), H)
    assert info.value.result[1:] == (0, 0, None)


def test_orient_nonneg_keeps_the_model(rng):
    D, H = rng.standard_normal((6, 3)), rng.standard_normal((4, 3))
    D2, H2 = orient_nonneg(D, H)
    np.testing.assert_allclose(H2 @ D2.T, H @ D.T, rtol=1e-15)
    assert np.all(H2.sum(axis=0) >= 0)
    _, H3 = orient_nonneg(D, H, fold=True)
    np.testing.assert_array_equal(H3, np.abs(H))


def test_normalise_dictionary_only_outside_the_band(rng):
    D, H = rng.standard_normal((6, 3)), rng.standard_normal((4, 3))
    D /= np.linalg.norm(D, axis=0)
    same = normalise_dictionary(1.5 * D, H)
    assert same[0] is not None and np.all(same[0] == 1.5 * D)
    D2, H2 = normalise_dictionary(3.0 * D, H)
    np.testing.assert_allclose(np.linalg.norm(D2, axis=0), 1.0)
    np.testing.assert_allclose(H2 @ D2.T, H @ (3.0 * D).T, rtol=1e-14)
    D3, _ = normalise_dictionary(1.5 * D, H, band=1.0)
    np.testing.assert_allclose(np.linalg.norm(D3, axis=0), 1.0)
    D4, H4 = normalise_dictionary(np.zeros((6, 2)), np.ones((4, 2)), band=1.0)  # zero columns are kept
    assert np.all(D4 == 0) and np.all(H4 == 1)


@pytest.mark.parametrize("edge", [0.5, 2.0])
def test_a_norm_at_a_band_edge_up_to_round_off_takes_one_branch(rng, edge):
    # state rewards with four actions give primitives of norm exactly 1/sqrt(4) = 1/band: two
    # routes to the same dictionary must not rescale it differently over the last bit
    D, H = rng.standard_normal((6, 2)), rng.standard_normal((4, 2))
    D *= edge / np.linalg.norm(D, axis=0)
    for factor in (1.0 - 4e-16, 1.0, 1.0 + 4e-16):
        D2, H2 = normalise_dictionary(D * factor, H)
        np.testing.assert_array_equal(D2, D * factor)
        np.testing.assert_array_equal(H2, H)
    D5, _ = normalise_dictionary(D * (1.0 + 1e-6) ** (1 if edge > 1 else -1), H)  # past the slack: rescaled
    np.testing.assert_allclose(np.linalg.norm(D5, axis=0), 1.0)
