"""Fitted estimators in the configurations persistence must handle (shared by this folder)."""

import numpy as np
import pytest

import factirl_opt as fo


@pytest.fixture(scope="session")
def grid_tasks():
    mdp = fo.GridWorld(size=4)
    rng = np.random.default_rng(3)
    D = fo.random_dictionary(mdp.n_params, 2, rng=rng)
    rewards = fo.task_rewards(D, fo.random_coefficients(4, 2, rng=rng), mdp.n_states, mdp.n_actions)
    demos = fo.sample_demonstrations(mdp, rewards, n_demos=3, length=6, rng=rng)
    new_rewards = fo.task_rewards(D, fo.random_coefficients(2, 2, rng=rng), mdp.n_states, mdp.n_actions)
    new_demos = fo.sample_demonstrations(mdp, new_rewards, n_demos=2, length=6, rng=rng)
    state_features = rng.standard_normal((mdp.n_states, 5))
    action_features = rng.standard_normal((mdp.n_params, 6))
    return mdp, demos, new_demos, state_features, action_features


@pytest.fixture(scope="session")
def fitted_models(grid_tasks):
    """name -> fitted estimator: tabular, with features, and after transfer."""
    mdp, demos, new_demos, state_features, action_features = grid_tasks
    small = dict(max_iter=3, inner_steps=2, flat_max_iter=5, transfer_max_iter=5)
    models = {
        "gradirl-tabular": fo.GradIRL(max_iter=5).fit(mdp, demos),
        "gradirl-features": fo.GradIRL(features=action_features, max_iter=5).fit(mdp, demos),
        "factirl-tabular": fo.FactIRL(n_primitives=2, rng=1, **small).fit(mdp, demos),
        "factirl-features": fo.FactIRL(n_primitives=2, features=state_features, rng=2, **small).fit(mdp, demos),
        "factirl-transfer": fo.FactIRL(n_primitives=2, init="random", rng=np.random.default_rng(4), **small).fit(mdp, demos),
        "factirl-features-transfer": fo.FactIRL(n_primitives=2, features=action_features, rng=5, **small).fit(mdp, demos),
    }
    models["factirl-transfer"].transfer(mdp, new_demos)
    models["factirl-features-transfer"].transfer(mdp, new_demos)
    return models

