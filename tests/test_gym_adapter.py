"""The Gymnasium toy-text adapter, checked against the environments' documented dynamics."""

import pathlib
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import scipy.sparse as sp

import factirl_opt as fo
from factirl_opt.exceptions import FactIRLError, MissingDependencyError, ValidationError
from factirl_opt.adapters.gymnasium import _tabular_model, from_gymnasium, gymnasium_rewards

gym = pytest.importorskip("gymnasium")

# FrozenLake's documented actions: 0 left, 1 down, 2 right, 3 up.
_FL_MOVES = {0: (0, -1), 1: (1, 0), 2: (0, 1), 3: (-1, 0)}
_FL_4X4 = ["SFFF", "FHFH", "FFFH", "HFFG"]


def _frozenlake_reference(desc, slippery):
    """Transitions and expected rewards built from FrozenLake's documentation, not from env.P.

    The agent moves in the intended direction, or (slippery) in it or one of the two
    perpendicular directions with probability 1/3 each; a move off the grid leaves it in
    place; holes and the goal end the episode (absorbing here); reaching the goal pays 1.
    """
    nrow, ncol = len(desc), len(desc[0])
    S = nrow * ncol
    P = np.zeros((S, 4, S))
    R = np.zeros((S, 4))
    for s in range(S):
        r, c = divmod(s, ncol)
        if desc[r][c] in "HG":
            P[s, :, s] = 1.0
            continue
        for a in range(4):
            dirs = [(a - 1) % 4, a, (a + 1) % 4] if slippery else [a]
            for b in dirs:
                dr, dc = _FL_MOVES[b]
                rr, cc = min(max(r + dr, 0), nrow - 1), min(max(c + dc, 0), ncol - 1)
                P[s, a, rr * ncol + cc] += 1.0 / len(dirs)
                R[s, a] += (desc[rr][cc] == "G") / len(dirs)
    return P, R


@pytest.mark.parametrize("slippery", [True, False])
def test_frozenlake_4x4_matches_documented_dynamics(slippery):
    mdp = from_gymnasium("FrozenLake-v1", map_name="4x4", is_slippery=slippery)
    P_ref, R_ref = _frozenlake_reference(_FL_4X4, slippery)
    assert isinstance(mdp, fo.TabularMDP)
    assert (mdp.n_states, mdp.n_actions, mdp.gamma) == (16, 4, 0.9)
    np.testing.assert_allclose(mdp.transitions, P_ref, atol=1e-12)
    np.testing.assert_allclose(gymnasium_rewards("FrozenLake-v1", map_name="4x4", is_slippery=slippery), R_ref, atol=1e-12)


def test_frozenlake_slippery_details():
    mdp = from_gymnasium(gym.make("FrozenLake-v1", is_slippery=True), gamma=0.95)
    T = mdp.transitions
    assert mdp.gamma == 0.95
    # top-left corner, "left": left and up bump into walls (stay, merged: 2/3), down reaches 4
    assert T[0, 0, 0] == pytest.approx(2 / 3) and T[0, 0, 4] == pytest.approx(1 / 3)
    # next to the goal (state 14), "right": goal, or up to 10, or down (wall) staying at 14
    assert T[14, 2, 15] == pytest.approx(1 / 3) and T[14, 2, 10] == pytest.approx(1 / 3) and T[14, 2, 14] == pytest.approx(1 / 3)
    for terminal in (5, 7, 11, 12, 15):  # holes and goal are absorbing
        np.testing.assert_array_equal(T[terminal, :, terminal], 1.0)
    assert np.count_nonzero(T.sum(axis=(0, 1)) > 0) == 16


def test_absorbing_values_equal_episodic_returns():
    """Values on the absorbing MDP equal the episodic environment's discounted returns."""
    env = gym.make("FrozenLake-v1", map_name="8x8", is_slippery=True)
    gamma = 0.9
    mdp = from_gymnasium(env, gamma=gamma)
    Q, _ = fo.optimal_q(mdp, gymnasium_rewards(env))
    table = env.unwrapped.P
    V = np.zeros(64)
    for _ in range(2000):  # episodic value iteration straight on env.P: no value after termination
        V = np.array([max(sum(p * (r + gamma * (not done) * V[ns]) for p, ns, r, done in table[s][a]) for a in range(4)) for s in range(64)])
    np.testing.assert_allclose(Q.max(axis=1), V, atol=1e-10)
    assert V[0] > 0


def test_cliffwalking_shapes_and_dynamics():
    mdp = from_gymnasium("CliffWalking-v1")
    R = gymnasium_rewards("CliffWalking-v1")
    T = mdp.transitions
    assert (mdp.n_states, mdp.n_actions) == (48, 4) and R.shape == (48, 4)
    # documented: actions 0 up, 1 right, 2 down, 3 left; start 36, goal 47; the cliff
    # (37..46) sends the agent back to the start with reward -100 and does not terminate
    assert T[36, 1, 36] == 1.0 and R[36, 1] == -100.0
    assert T[35, 2, 47] == 1.0 and R[35, 2] == -1.0
    np.testing.assert_array_equal(T[47, :, 47], 1.0)
    np.testing.assert_array_equal(R[47], 0.0)
    assert np.array_equal(T.max(axis=2), np.ones((48, 4)))  # deterministic


def test_taxi_shapes_and_terminal_modes():
    env = gym.make("Taxi-v4")
    mdp = from_gymnasium(env)
    kept = from_gymnasium(env, terminal="ignore")
    assert (mdp.n_states, mdp.n_actions) == (500, 6)
    # states entered by a successful drop-off (passenger at its destination) become absorbing
    absorbing = [s for s in range(500) if np.all(mdp.transitions[s, np.arange(6), s] == 1.0)]
    done_targets = sorted({int(ns) for s in env.unwrapped.P for a in range(6) for _, ns, _, d in env.unwrapped.P[s][a] if d})
    assert absorbing == done_targets and len(absorbing) == 4
    # "ignore" keeps the listed dynamics, flags dropped
    P_env = np.zeros((500, 6, 500))
    for s in range(500):
        for a in range(6):
            for p, ns, _, _ in env.unwrapped.P[s][a]:
                P_env[s, a, ns] += p
    np.testing.assert_array_equal(kept.transitions, P_env)
    R = gymnasium_rewards(env, terminal="ignore")
    assert R.shape == (500, 6) and set(np.unique(R)) <= {-1.0, -10.0, 20.0}


def _fake_env(table, n_states=None, n_actions=None):
    base = SimpleNamespace(P=table)
    if n_states is not None:
        base.observation_space = SimpleNamespace(n=n_states)
        base.action_space = SimpleNamespace(n=n_actions)
    return SimpleNamespace(unwrapped=base)


def test_duck_typed_env_merges_duplicates_and_needs_no_gymnasium(monkeypatch):
    table = {
        0: {0: [(0.25, 1, 1.0, False), (0.25, 1, 3.0, False), (0.5, 0, 0.0, False)], 1: [(1.0, 2, 10.0, True)]},
        1: {0: [(1.0, 0, 0.0, False)], 1: [(1.0, 1, 0.0, False)]},
        2: {0: [(1.0, 0, 5.0, False)], 1: [(1.0, 0, 5.0, False)]},
    }
    monkeypatch.setitem(sys.modules, "gymnasium", None)  # an env object is read without gymnasium
    mdp = from_gymnasium(_fake_env(table), gamma=0.5)
    np.testing.assert_array_equal(mdp.transitions[0, 0], [0.5, 0.5, 0.0])
    np.testing.assert_array_equal(mdp.transitions[2], [[0, 0, 1], [0, 0, 1]])  # entered terminally: absorbing
    np.testing.assert_array_equal(gymnasium_rewards(_fake_env(table)), [[1.0, 10.0], [0.0, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(gymnasium_rewards(_fake_env(table), terminal="ignore")[2], [5.0, 5.0])


def test_missing_gymnasium_gives_library_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "gymnasium", None)
    with pytest.raises(MissingDependencyError) as info:
        from_gymnasium("FrozenLake-v1")
    assert isinstance(info.value, ImportError) and isinstance(info.value, FactIRLError)
    # the commands of the documented installs: any install, and the editable install from a clone (README)
    assert 'pip install "gymnasium>=0.29"' in str(info.value)
    assert 'pip install -e ".[gymnasium]"' in str(info.value)
    readme = (pathlib.Path(__file__).resolve().parents[1] / "README.md").read_text()
    assert "pip install -e ." in readme and "`.[gymnasium]`" in readme
    pyproject = (pathlib.Path(__file__).resolve().parents[1] / "pyproject.toml").read_text()
    assert 'gymnasium = ["gymnasium>=0.29"]' in pyproject


def test_dynamics_are_read_as_sparse_csr():
    env = gym.make("Taxi-v4")
    P, R, absorbing = _tabular_model(env, "absorbing", {})
    assert sp.issparse(P) and P.format == "csr" and P.shape == (500 * 6, 500)
    assert P.nnz <= 500 * 6  # Taxi is deterministic: one entry per row
    np.testing.assert_allclose(np.asarray(P.sum(axis=1)).ravel(), 1.0)
    np.testing.assert_array_equal(P.toarray().reshape(500, 6, 500), from_gymnasium(env).transitions)
    assert R.shape == (500, 6) and absorbing.sum() == 4
    lake, _, _ = _tabular_model("FrozenLake-v1", "absorbing", {"is_slippery": True})
    assert lake.has_canonical_format  # duplicate outcomes merged into one entry
    assert lake[0 * 4 + 0, 0] == pytest.approx(2 / 3)  # top-left, "left": two outcomes stay in place


@pytest.mark.parametrize(
    "env, match",
    [
        (SimpleNamespace(unwrapped=SimpleNamespace()), "no tabular model"),
        (_fake_env({}), "no tabular model"),
        (_fake_env({0: {0: [(1.0, 0, 0, False)]}, 2: {0: [(1.0, 0, 0, False)]}}), "one entry per state"),
        (_fake_env({0: {0: [(1.0, 0, 0, False)], 1: []}}), r"P\[0\]\[1\] must be a non-empty list .*; got \[\]"),
        (_fake_env({0: {0: [(1.0, 3, 0, False)]}}), "next_state 3"),
        (_fake_env({0: {0: [(1.0, 0, 0)]}}), r"expected \(probability, next_state, reward, terminated\)"),
        (_fake_env({0: {0: [(1.0, 0, 0, False)]}, 1: {1: [(1.0, 0, 0, False)]}}), r"P\[1\] must have one entry per action"),
        (_fake_env({0: {0: [(0.5, 0, 0, False)]}}), "must sum to 1"),
        (_fake_env({0: {0: [(1.0, 0, 0, False)]}}, n_states=2, n_actions=1), "one entry per state 0..1"),
        (_fake_env({0: {0: [("1.0", 0, 0, False)]}}), r"the probability in P\[0\]\[0\] must be a finite number >= 0; got '1.0'"),
        (_fake_env({0: {0: [(-0.5, 0, 0, False), (1.5, 0, 0, False)]}}), r"the probability in P\[0\]\[0\] must be .* got -0.5"),
        (_fake_env({0: {0: [(float("nan"), 0, 0, False)]}}), r"the probability in P\[0\]\[0\] must be a finite number"),
        (_fake_env({0: {0: [(1.0, 0, float("inf"), False)]}}), r"the reward in P\[0\]\[0\] must be a finite number"),
        (_fake_env({0: {0: [(1.0, 0, None, False)]}}), r"the reward in P\[0\]\[0\] must be a finite number"),
    ],
)
def test_malformed_models_are_rejected(env, match):
    with pytest.raises(ValidationError, match=match):
        from_gymnasium(env)


def test_bad_arguments():
    with pytest.raises(ValidationError, match="terminal must be one of"):
        from_gymnasium("FrozenLake-v1", terminal="drop")
    with pytest.raises(ValidationError, match="gamma"):
        from_gymnasium("FrozenLake-v1", gamma=1.0)
    with pytest.raises(ValidationError, match="need an environment id"):
        from_gymnasium(gym.make("FrozenLake-v1"), map_name="8x8")
    with pytest.raises(ValidationError, match="no tabular model"):
        from_gymnasium("CartPole-v1")


def test_frozenlake_8x8_factirl_end_to_end():
    """FactIRL on tasks defined on FrozenLake 8x8 (small settings): learns, transfers, beats chance."""
    mdp = from_gymnasium("FrozenLake-v1", map_name="8x8", is_slippery=True)
    rng = np.random.default_rng(0)
    D = fo.random_dictionary(mdp.n_params, n_primitives=3, rng=rng)
    H = fo.random_coefficients(10, n_primitives=3, rng=rng)
    rewards = fo.task_rewards(D, H, mdp.n_states, mdp.n_actions)
    demos = fo.sample_demonstrations(mdp, rewards, n_demos=5, length=10, rng=rng)
    model = fo.FactIRL(n_primitives=3, max_iter=10, flat_max_iter=20, rng=0).fit(mdp, demos)
    assert model.dictionary_.shape == (256, 3) and model.rewards_.shape == (10, 64, 4)
    assert model.loss_history_[-1] < model.loss_history_[0]
    learnt = fo.deviation(mdp, rewards, model.rewards_).mean()
    chance = fo.deviation(mdp, rewards, np.random.default_rng(1).standard_normal(rewards.shape)).mean()
    assert learnt < chance
    h = model.transfer(mdp, demos[:2], max_iter=10)
    assert h.shape == (2, 3) and np.all(np.isfinite(h))
