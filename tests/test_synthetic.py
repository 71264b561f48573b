"""Ground-truth generators: random dictionaries, coefficients and task rewards."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError


def test_shapes_and_reproducibility():
    D = fo.random_dictionary(36, 5, rng=3)
    assert D.shape == (36, 5)
    np.testing.assert_array_equal(D, fo.random_dictionary(36, 5, rng=np.random.default_rng(3)))
    H = fo.random_coefficients(7, 5, rng=3)
    assert H.shape == (7, 5)
    R = fo.task_rewards(D, H, 9, 4)
    assert R.shape == (7, 9, 4)
    np.testing.assert_allclose(R.reshape(7, -1), H @ D.T)


def test_distributions(rng):
    D = fo.random_dictionary(4000, 5, rng)
    assert abs(D.mean()) < 0.05 and abs(D.std() - 1) < 0.05
    H = fo.random_coefficients(4000, 5, kind="nonneg", rng=rng)
    assert np.all(H >= 0) and abs(H.mean() - np.sqrt(2 / np.pi)) < 0.03


def test_sparsity_keeps_one_nonzero_per_task(rng):
    H = fo.random_coefficients(500, 5, sparsity=0.95, rng=rng)
    assert np.all(np.count_nonzero(H, axis=1) >= 1)
    assert 0.7 < np.mean(H == 0) < 0.85  # 0.95 zeroed, then one per row restored


@pytest.mark.parametrize(
    "call, fragment",
    [
        (lambda: fo.random_dictionary(0), r"n_params must be an integer >= 1; got 0"),
        (lambda: fo.random_dictionary(10, 2.5), r"n_primitives must be an integer >= \d; got 2\.5"),
        (lambda: fo.random_coefficients(3, 2, kind="uniform"), r"kind must be one of .*got 'uniform'"),
        (lambda: fo.random_coefficients(3, 2, sparsity=1.0), r"sparsity must be a probability in \[0, 1\); got 1\.0"),
        (lambda: fo.task_rewards(np.ones((35, 2)), np.ones((3, 2)), 9, 4), r"dictionary must have shape \(S\*A, k\) = \(36, k\); got \(35, 2\)"),
        (lambda: fo.task_rewards(np.ones((36, 2)), np.ones((3, 3)), 9, 4), r"coefficients must have shape \(n, 2\); got \(3, 3\)"),
    ],
)
def test_validation(call, fragment):
    with pytest.raises(ValidationError, match=fragment):
        call()


def test_overflow_names_the_task_and_the_sizes():
    D = np.ones((36, 2))
    H = np.array([[1.0, 1.0], [1e308, 1e308], [0.0, 1.0]])
    with pytest.raises(ValidationError, match=r"rewards D h_i of task 1 overflow float64 \(largest \|dictionary\| entry 1, "
                       r"largest \|coefficients\[1\]\| entry 1e\+308\).*Phi @ D"):
        fo.task_rewards(D, H, 9, 4)


def test_synthetic_tasks_are_unchanged_by_the_sampler_options(grid3):
    """synthetic_tasks samples with the default start: the same tasks and demonstrations as sampling them."""
    tasks = fo.synthetic_tasks(grid3, 3, 4, 5, n_primitives=2, rng=0, demo_rng=1)
    again = fo.sample_demonstrations(grid3, tasks.rewards, 4, 5, rng=1)
    for x, y in zip(tasks.demos, again):
        np.testing.assert_array_equal(x, y)
