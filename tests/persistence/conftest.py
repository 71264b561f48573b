"""Fitted estimators in the configurations persistence must handle (shared by this folder)."""

import subprocess

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
    """name -> fitted estimator: tabular, with features, after transfer, and MultiIntentIRL's EM."""
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
    episodes = [ep for task in demos for ep in task]
    em = dict(max_iter=2, m_step_max_iter=3)
    models["multi-intent-flat"] = fo.MultiIntentIRL(2, rng=0, **em).fit(mdp, episodes)
    models["multi-intent-shared"] = fo.MultiIntentIRL(2, 2, features=state_features, rng=np.random.default_rng(6),
                                                      **em).fit(mdp, episodes)
    models["multi-intent-auto"] = fo.MultiIntentIRL("auto", n_intentions_range=(1, 2), selection="bic",
                                                    features=action_features, rng=7, **em).fit(mdp, episodes)
    return models



def _mount(*args):
    """Run ``mount args``; skip the test when mounting is not permitted here."""
    try:
        done = subprocess.run(["mount", *args], capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.SubprocessError) as exc:
        pytest.skip(f"cannot run mount here ({exc}): a real full or read-only file system needs it")
    if done.returncode != 0:
        pytest.skip(f"mounting is not permitted here (mount: {done.stderr.strip()}): needs root with CAP_SYS_ADMIN")


class Tmpfs:
    """Small tmpfs file systems mounted under a test's tmp_path, unmounted at teardown."""

    def __init__(self, root):
        self.root, self.mounted = root, []

    def mount(self, name, size="64k"):
        directory = self.root / name
        directory.mkdir()
        _mount("-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(directory))
        self.mounted.append(directory)
        return directory

    @staticmethod
    def read_only(directory):
        _mount("-o", "remount,ro", str(directory))

    def unmount_all(self):
        for directory in reversed(self.mounted):
            subprocess.run(["umount", str(directory)], capture_output=True, timeout=30)


@pytest.fixture()
def tmpfs(tmp_path):
    """A :class:`Tmpfs`: real full and read-only file systems (the test skips if it cannot mount)."""
    mounts = Tmpfs(tmp_path)
    yield mounts
    mounts.unmount_all()
