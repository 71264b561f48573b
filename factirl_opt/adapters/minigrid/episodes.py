"""Episodes in the real MiniGrid/BabyAI environment: the BabyAI bot's demonstrations, and
greedy policies of learnt rewards run in the simulator (success judged by the environment).

Both functions take an environment object or a gymnasium id (then made, and closed after),
and an optional ``seed`` (then ``env.reset(seed=seed)`` draws the layout; otherwise the
environment is used as it is, after the caller's reset). Steps go through ``env.step`` of the
object given, wrappers included.
"""

from __future__ import annotations

import dataclasses
import importlib
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..._validation import check_int
from ...exceptions import ValidationError
from .features import DEFAULT_THRESHOLDS, grid_objects
from .model import ACTIONS, MiniGridModel, agent_state, base_env, from_minigrid, make_env, require_minigrid

__all__ = ["BotDemonstration", "PolicyRun", "bot_demonstration", "run_policy"]


@dataclasses.dataclass(frozen=True, eq=False)
class BotDemonstration:
    """One episode of the BabyAI bot, in a model's numbering (see :func:`bot_demonstration`).

    Attributes
    ----------
    model : MiniGridModel
        The layout's model, built at the episode's start.
    demonstration : ndarray of int64, shape (L, 2)
        Rows ``(state, action)`` for the L steps taken; the state reached by the last one is
        ``next_states[-1]`` (no pair: the episode ended there).
    next_states : ndarray of int64, shape (L,)
        The state the environment reached after each step.
    mission : str
    success : bool
        The environment ended the episode with a positive reward.
    reward : float
        The environment's reward at the last step.
    """

    model: MiniGridModel
    demonstration: np.ndarray
    next_states: np.ndarray
    mission: str
    success: bool
    reward: float

    @property
    def demonstrations(self) -> list[np.ndarray]:
        """The episode as the library's demonstrations of one task: a list of one (L, 2) array."""
        return [self.demonstration]


@dataclasses.dataclass(frozen=True, eq=False)
class PolicyRun:
    """A policy run in the environment (see :func:`run_policy`).

    Attributes
    ----------
    success : bool
        The environment terminated the episode with a positive reward.
    reward : float
        The environment's reward at the last step.
    states : ndarray of int64, shape (L + 1,)
        The states visited, from the start, in the model's numbering.
    actions : ndarray of int64, shape (L,)
    """

    success: bool
    reward: float
    states: np.ndarray
    actions: np.ndarray


def _layout(env: Any, seed: int | None) -> tuple[Any, bool]:
    """The environment (made from an id if need be, then owned) after the optional reset."""
    require_minigrid("running MiniGrid episodes")
    owned = isinstance(env, str)
    if owned:
        env = make_env(env)
    elif not all(callable(getattr(env, name, None)) for name in ("reset", "step")):
        hint = (" (a model read from an environment: pass the environment itself, or its id and a seed)"
                if isinstance(env, MiniGridModel) or hasattr(env, "n_states") else "")
        raise ValidationError(f"env must be a MiniGrid/BabyAI environment (a gymnasium.Env with reset and step) or its id; "
                              f"got {type(env).__name__}{hint}")
    if seed is not None:
        env.reset(seed=check_int(seed, "seed", minimum=0))
    return env, owned


def _check_step(model: MiniGridModel, s: int, a: int, nxt: tuple[int, int, int], terminated: bool, t: int) -> int:
    """The observed next state's number, checked against the model's row ``s * A + a``."""
    if nxt not in model.lookup:
        raise ValidationError(f"step {t}: the environment reached {nxt}, which is not a state of the model")
    n = model.lookup[nxt]
    P = model.mdp.transition_matrix
    row = s * len(ACTIONS) + a
    predicted = P.indices[P.indptr[row]:P.indptr[row + 1]]
    if predicted.tolist() != [n] or bool(model.terminal[n]) != terminated:
        raise ValidationError(
            f"step {t}: the environment went from {tuple(model.states[s].tolist())} by {ACTIONS[a]!r} to {nxt} "
            f"(terminated={terminated}); the model predicts state(s) {model.states[predicted].tolist()}"
        )
    return n


def _start_at(env: Any, start: Any, gamma: float, thresholds: tuple[float, ...]) -> MiniGridModel:
    """The layout's model (read at the environment's start); then move the agent to ``start``.

    ``start`` must be a non-terminal state of the model: every state reachable from it is then
    a state of the model too (the model holds all states reachable from the environment's
    start without passing through a terminal state).
    """
    model = from_minigrid(env, gamma, thresholds)
    if start is None:
        return model
    try:
        x, y, d = (int(v) for v in start)
    except (TypeError, ValueError):
        raise ValidationError(f"start must be an (x, y, direction) triple of integers; got {start!r}") from None
    if model.terminal[model.index(x, y, d)]:
        raise ValidationError(f"start {(x, y, d)} is a terminal state of the mission {model.mission!r}")
    base = base_env(env)
    base.agent_pos, base.agent_dir = (x, y), d
    return model


def bot_demonstration(env: Any, seed: int | None = None, *, start: tuple[int, int, int] | None = None,
                      gamma: float = 0.9, thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS) -> BotDemonstration:
    """Roll ``minigrid.utils.baby_ai_bot.BabyAIBot`` in a BabyAI level, in a model's numbering.

    The bot is asked for an action at every step until the environment terminates or
    truncates the episode (its own ``max_steps``). Every step is checked against the model:
    the observed next state must be the model's, and the environment's termination the
    model's terminal flag. The bot's 'done' action is never reached in GoTo levels (the
    verifier ends the episode as soon as the agent faces its target, before the bot would say
    'done'); any action outside left/right/forward, 'done' included, raises.

    Parameters
    ----------
    env : gymnasium.Env or str
        A BabyAI environment (with ``unwrapped.instrs``) or its id, e.g. "BabyAI-GoToLocal-v0".
    seed : int, optional
        Reset the environment with this seed first (required with an id).
    start : (x, y, direction), optional
        Start the bot from this non-terminal state of the layout's model instead of the
        environment's start (the agent is moved there after the reset). The model is still
        the layout's, read at the environment's start, so ``model.start`` is not ``start``.
    gamma, thresholds
        Passed to :func:`~factirl_opt.adapters.minigrid.model.from_minigrid`.

    Returns
    -------
    episode : BotDemonstration
        ``episode.demonstrations`` is the library's layout for one task (a list of one (L, 2)
        array). An episode truncated by the environment is returned with ``success=False``.

    Raises
    ------
    MissingDependencyError
        minigrid is not installed.
    ValidationError
        ``env`` is an id that is not registered (named, with gymnasium's reason), the level is
        not modelled (see :func:`from_minigrid`), is not a BabyAI level, ``start``
        is not a reachable non-terminal state, or the bot takes a step outside the model
        (pick-up, toggle, drop, done, or a transition the model does not predict).
    """
    if isinstance(env, str) and seed is None:
        raise ValidationError(f"a seed is needed to reset a new {env!r} environment")
    env, owned = _layout(env, seed)
    try:
        if not hasattr(base_env(env), "instrs"):
            raise ValidationError(f"the BabyAI bot needs a BabyAI level (env.unwrapped.instrs); got {type(env.unwrapped).__name__}")
        model = _start_at(env, start, gamma, thresholds)
        bot = importlib.import_module("minigrid.utils.baby_ai_bot").BabyAIBot(env)
        pairs: list[tuple[int, int]] = []
        nexts: list[int] = []
        terminated = truncated = False
        reward = 0.0
        while not (terminated or truncated):
            action = int(bot.replan())
            s = model.state_of(env)
            if action not in range(len(ACTIONS)):
                name = base_env(env).actions(action).name
                raise ValidationError(f"step {len(pairs)}: the bot chose action {action} ({name!r}) in state "
                                      f"{tuple(model.states[s].tolist())}; only {ACTIONS} (0, 1, 2) are modelled")
            _, reward, terminated, truncated, _ = env.step(action)
            nexts.append(_check_step(model, s, action, agent_state(base_env(env)), bool(terminated), len(pairs)))
            pairs.append((s, action))
    finally:
        if owned:
            env.close()
    demo = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    success = bool(terminated and float(reward) > 0)
    return BotDemonstration(model, demo, np.array(nexts, dtype=np.int64), model.mission, success, float(reward))


def _check_policy(policy: ArrayLike, model: MiniGridModel) -> np.ndarray:
    arr = np.asarray(policy)
    if arr.shape != (model.n_states,) or arr.dtype.kind not in "iu":
        raise ValidationError(f"policy must be an int array of shape ({model.n_states},) (one action per state); "
                              f"got shape {arr.shape}, dtype {arr.dtype}")
    bad = (arr < 0) | (arr >= len(ACTIONS))
    if bad.any():
        s = int(np.argmax(bad))
        raise ValidationError(f"policy[{s}] = {arr[s]} is not an action of {ACTIONS} (0, 1, 2)")
    return arr.astype(np.int64)


def _check_layout(model: MiniGridModel, env: Any) -> None:
    base = base_env(env)
    same = (str(getattr(base, "mission", "")) == model.mission and agent_state(base) in model.lookup
            and model.lookup[agent_state(base)] == model.start and np.array_equal(grid_objects(base.grid), model.objects))
    if not same:
        raise ValidationError(f"the model (mission {model.mission!r}) is not the environment's current layout "
                              f"(mission {getattr(base, 'mission', '')!r}): reset with the seed the model was read from")


def run_policy(env: Any, policy: ArrayLike, seed: int | None = None, *, model: MiniGridModel | None = None,
               max_steps: int | None = None) -> PolicyRun:
    """Run a deterministic policy in the real environment from its start; success as it judges.

    Parameters
    ----------
    env : gymnasium.Env or str
        A MiniGrid/BabyAI environment or its id.
    policy : array_like of int, shape (S,)
        The action (0 left, 1 right, 2 forward) in each state of ``model``, e.g. the greedy
        policy of a learnt reward on ``model.mdp``.
    seed : int, optional
        Reset the environment with this seed first (required with an id).
    model : MiniGridModel, optional
        The layout's model (read with :func:`from_minigrid` if not given); it must be the
        environment's current layout, at its start.
    max_steps : int, optional
        Stop after this many steps even if the environment has not truncated the episode
        (by default only its own ``max_steps`` ends an unsuccessful run).

    Returns
    -------
    run : PolicyRun
        ``success`` is True when the environment terminated the episode with a positive reward.

    Raises
    ------
    MissingDependencyError
        minigrid is not installed.
    ValidationError
        ``env`` is an id that is not registered, bad ``policy`` (shape, dtype, actions), ``model`` of
        another layout, ``max_steps`` < 1.
    """
    if isinstance(env, str) and seed is None:
        raise ValidationError(f"a seed is needed to reset a new {env!r} environment")
    limit = None if max_steps is None else check_int(max_steps, "max_steps", minimum=1)
    env, owned = _layout(env, seed)
    try:
        if model is None:
            model = from_minigrid(env)
        elif not isinstance(model, MiniGridModel):
            raise ValidationError(f"model must be a MiniGridModel (see from_minigrid); got {type(model).__name__}")
        _check_layout(model, env)
        actions = _check_policy(policy, model)
        states: list[int] = [model.start]
        taken: list[int] = []
        terminated = truncated = False
        reward = 0.0
        while not (terminated or truncated) and (limit is None or len(taken) < limit):
            taken.append(int(actions[states[-1]]))
            _, reward, terminated, truncated, _ = env.step(taken[-1])
            states.append(model.state_of(env))
    finally:
        if owned:
            env.close()
    return PolicyRun(bool(terminated and float(reward) > 0), float(reward), np.array(states, dtype=np.int64),
                     np.array(taken, dtype=np.int64))
