"""Policies for new tasks without planning: generalised policy improvement over a model's library.

A factorial model's rewards are linear in its primitives: task ``h`` has ``R_h = Phi D h``, so
with the primitive rewards ``phi = Phi D`` (k, S, A) as reward features every fixed policy's
action values on every task in the dictionary's span are ``Q^pi_h = psi^pi h``, ``psi^pi`` its
successor features (:mod:`factirl_opt.planning.successor_features`, docs/maths.md §11). The
paper notes that the factorial model gives policies only for the tasks it observed; with a
library of policies ``Pi`` and their successor features, generalised policy improvement (GPI,
Barreto et al. 2017) gives a new task's policy without planning:
``pi(s) = argmax_a max_{pi in Pi} psi^pi(s, a) h``, at least as good as every policy of the
library on that task (Theorem 1), and optionally improved by exact policy-improvement steps.

The library (:data:`LIBRARY_PARTS`), on each environment the model was fitted on:

- ``"primitives"``: the optimal policies of the k primitive rewards ``phi_j``;
- ``"negatives"``: those of ``-phi_j``;
- ``"tasks"``: those of the training tasks' learnt rewards ``rewards_`` on that environment
  (a model whose ``dictionary_`` was set by hand has none);
- ``"other-tasks"`` (not in the default library): with one environment per training task (a
  map per task), the other training tasks' learnt weights ``w_j = D h_j + delta_j`` carried to
  this environment, ``Phi_m w_j``: the training tasks as they would be on this map (none on a
  model fitted on one environment, where every training task is already under ``"tasks"``).

"Optimal" follows the model's objective: greedy on ``Q*`` for policy matching (eq. 5 acts on
``Q*``), the soft-optimal (Boltzmann) policy of the soft Bellman equation at the model's
``beta`` for ``"mce"`` (docs/maths.md §6). Either way the GPI policy is greedy and values are
the ordinary discounted returns ``rho^T V^pi_h`` (what :func:`~factirl_opt.deviation` measures).

The library's policies and successor features are cached on the model per environment (keyed by
a digest of what they depend on: the environment, ``Phi D``, the training rewards, the kind of
policy and the parts) and saved with it by :func:`~factirl_opt.save_model`; libraries of an
earlier learnt state (a refit, a dictionary set anew) are dropped when a new one is cached.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._threads import blas_limited
from .._validation import check_array, check_int, check_mdp, check_start
from ..exceptions import NotFittedError, ValidationError
from ..mdp.environments import is_environment_sequence
from ..mdp.tabular import check_signature
from ..objectives import get_objective
from ..objectives.mce import soft_values
from ..planning import get_planner, plan
from ..planning.engine import greedy_values
from ..planning.successor_features import gpi_actions, improve_policies, library_values, policy_successor_features
from ..tasks.basis import RewardBasis, matrix_digest
from ..tasks.task_set import features_per_task, per_task_features, reward_basis

__all__ = ["GPIReport", "generalised_policy_improvement", "gpi_library", "LIBRARY_PARTS", "DEFAULT_PARTS",
           "successor_feature_cache",
           "set_successor_feature_cache"]

#: the parts a GPI library can be made of (module docstring)
LIBRARY_PARTS = ("primitives", "negatives", "tasks", "other-tasks")
#: the parts of the default library (those the model has)
DEFAULT_PARTS = ("primitives", "negatives", "tasks")
#: planning memory of one chunk of new tasks evaluated at once (improvement steps, reported values)
EVALUATION_CHUNK_BYTES = 256 * 2**20


@dataclasses.dataclass
class GPIReport:
    """What :meth:`FactIRL.gpi_policies` found, per new task (``FactIRL.gpi_report_``).

    Values are ``rho^T V^pi_h``: the expected discounted return of a policy on the task's reward
    ``Phi D h`` from the start distribution ``rho`` (uniform by default, as in eq. 13).

    Attributes
    ----------
    library : list of str, or list of n such lists
        The labels of the library's policies (``"primitive j"``, ``"-primitive j"``, ``"task i"``,
        i a training task); one list per new task when their environments have different libraries.
    library_values : ndarray, shape (n, L), or list of n arrays (L_i,)
        Every library policy's value on every task, from its successor features (no solve).
    best_library_value : ndarray, shape (n,)
    best_library_policy : list of str
        The label of the best library policy per task.
    gpi_value : ndarray, shape (n,), or None
        The GPI policy's exact value (one policy evaluation per task); at least
        ``best_library_value`` up to round-off (Barreto et al. 2017, Theorem 1). None when not
        evaluated (``evaluate=False`` and no improvement step).
    value : ndarray, shape (n,), or None
        The value of the returned policies (after ``improvement_steps``); None when not evaluated.
    improvement_steps : int
    """

    library: list
    library_values: Any
    best_library_value: NDArray[np.float64]
    best_library_policy: list
    gpi_value: NDArray[np.float64] | None
    value: NDArray[np.float64] | None
    improvement_steps: int


# -- the cache on the model ------------------------------------------------------------------------

def successor_feature_cache(model: Any) -> dict[str, dict[str, Any]]:
    """The model's cached libraries: digest -> ``{"labels", "policies", "psi", "state"}`` (created empty;
    ``state``: the digest of the model's learnt state the library was built from)."""
    cache = model.__dict__.get("_successor_features")
    if cache is None:
        cache = model.__dict__["_successor_features"] = {}
    return cache


def set_successor_feature_cache(model: Any, entries: dict[str, dict[str, Any]]) -> None:
    """Give ``model`` these cached libraries (``load_model``)."""
    model.__dict__["_successor_features"] = dict(entries)


# -- environments ----------------------------------------------------------------------------------

@dataclasses.dataclass
class _Environment:
    """One environment of new tasks: its MDP, primitive rewards (k, S, A) and training rows on it."""

    mdp: Any
    phi: NDArray[np.float64]
    train: list[int]
    basis: Any = None  # the model's RewardBasis on this environment
    others: list[int] = dataclasses.field(default_factory=list)  # training tasks of other environments


def _policy_kind(model: Any) -> str:
    return "soft" if get_objective(model.objective).name == "mce" else "greedy"


def _check_parts(library: Any, has_tasks: bool) -> tuple[str, ...]:
    if library is None:
        return DEFAULT_PARTS if has_tasks else DEFAULT_PARTS[:2]
    parts = (library,) if isinstance(library, str) else tuple(library)
    if not parts or any(not isinstance(p, str) or p not in LIBRARY_PARTS for p in parts) or len(set(parts)) != len(parts):
        raise ValidationError(f"library must be a non-empty selection of distinct parts among {LIBRARY_PARTS}; got {library!r}")
    if ("tasks" in parts or "other-tasks" in parts) and not has_tasks:
        raise ValidationError("library includes training tasks, but this model has no training tasks (its dictionary_ was set "
                              "by hand, or it was not fitted): use library=('primitives', 'negatives')")
    return tuple(p for p in LIBRARY_PARTS if p in parts)


def _train_rewards(model: Any, rows: list[int]) -> NDArray[np.float64]:
    R = model.rewards_
    return np.stack([np.asarray(R[j], dtype=np.float64) for j in rows]) if rows else np.empty((0,))


def _basis_primitives(model: Any, mdp: Any, features: Any, D: NDArray[np.float64]) -> tuple[NDArray[np.float64], Any]:
    """The primitive rewards ``Phi D`` (k, S, A) of the model's dictionary on ``mdp``, and the basis ``Phi``."""
    k = D.shape[1]
    basis = reward_basis(mdp, features, model.reward, min_columns=k)
    if D.shape[0] != basis.n_params:
        raise ValidationError(f"dictionary_ must have shape (p, k) with p = {basis.n_params} (the reward dimension on "
                              f"this environment); got {D.shape}")
    return np.asarray(basis.factorial_rewards(D, np.eye(k)), dtype=np.float64).reshape(k, mdp.n_states, mdp.n_actions), basis


def _same_matrix(a: Any, b: Any) -> bool:
    return a is b or (np.shape(a) == np.shape(b) and np.array_equal(np.asarray(a), np.asarray(b)))


def _environment(model: Any, m: Any, f: Any, i: int, D: NDArray[np.float64], fitted: bool) -> _Environment:
    """The environment ``(m, f)`` of new task ``i``, checked to be one the model was fitted on."""
    check_mdp(m)
    signature = getattr(model, "mdp_signature_", None)
    mine = model.features
    if isinstance(mine, RewardBasis):
        raise ValidationError("gpi_policies needs the model's features as arrays, not a RewardBasis")
    if per_task_features(mine):  # one matrix per training task: an environment is an MDP and its features
        if not isinstance(signature, list):
            raise ValidationError("this model has one feature matrix per task but no mdp_signature_ (its environments "
                                  "are unknown): fit it before asking for GPI policies")
        if f is None:
            raise ValidationError("this model was fitted with one feature matrix per task: gpi_policies needs each new "
                                  "task's features (features=, the matrix of the fitted task whose map it is on)")
        got = m.signature()
        rows = [j for j, sig in enumerate(signature) if sig == got and _same_matrix(mine[j], f)]
        if not rows:
            raise ValidationError(
                f"gpi_policies works only on the environments the model was fitted on (its library's policies live "
                f"there): the environment of new task {i} (its MDP and features) is none of the {len(signature)} fitted "
                "tasks' environments; plan that task with fo.optimal_q instead")
        phi, basis = _basis_primitives(model, m, f, D)
        others = [j for j in range(len(signature)) if j not in rows] if fitted else []
        return _Environment(m, phi, rows if fitted else [], basis, others)
    if f is not None and not (mine is not None and _same_matrix(mine, f)):
        raise ValidationError("features given for new tasks of a model with shared features must be the model's own "
                              "(its dictionary's environment); leave features=None")
    if isinstance(signature, dict):
        check_signature(signature, m, "this FactIRL model (gpi_policies works only on the environment it was fitted on)")
        rows = list(range(len(model.rewards_))) if fitted else []
    elif isinstance(signature, list):  # several MDPs with one shared feature matrix
        got = m.signature()
        rows = [j for j, sig in enumerate(signature) if sig == got]
        if not rows:
            raise ValidationError(
                f"gpi_policies works only on the environments the model was fitted on: the MDP of new task {i} "
                f"(S = {m.n_states}) is none of the {len(signature)} fitted tasks' MDPs; plan that task with fo.optimal_q")
        rows = rows if fitted else []
    else:
        rows = []
    phi, basis = _basis_primitives(model, m, mine, D)
    others = [j for j in range(len(signature)) if j not in rows] if fitted and isinstance(signature, list) else []
    env = _Environment(m, phi, rows, basis, others)
    digest = getattr(model, "features_sha256_", None)
    if digest is not None and mine is not None and reward_basis(m, mine, model.reward, 1).digest() != digest:
        raise ValidationError("this FactIRL model was fitted with other features than the ones set now: restore them or fit again")
    return env


def _environments(model: Any, mdp: Any, features: Any, n: int, D: NDArray[np.float64],
                  fitted: bool) -> tuple[list[_Environment], NDArray[np.intp]]:
    """The distinct environments of the n new tasks and each task's index among them.

    Raises
    ------
    ValidationError
        An environment the model was not fitted on (libraries live on the fitted environments).
    """
    mdps = list(mdp) if is_environment_sequence(mdp) else [mdp] * n
    if len(mdps) != n:
        raise ValidationError(f"mdp must be one MDP or one per new task ({n}); got {len(mdps)}")
    feats = features_per_task(features, n)
    envs: list[_Environment] = []
    index = np.empty(n, dtype=np.intp)
    seen: dict[tuple[int, int], int] = {}
    for i, (m, f) in enumerate(zip(mdps, feats)):
        key = (id(m), id(f))
        if key not in seen:
            seen[key] = len(envs)
            envs.append(_environment(model, m, f, i, D, fitted))
        index[i] = seen[key]
    return envs, index


# -- the library -----------------------------------------------------------------------------------

def _digest(env: _Environment, train_R: NDArray[np.float64], kind: str, beta: float, parts: tuple[str, ...]) -> str:
    h = hashlib.sha256(json.dumps([env.mdp.signature(), kind, float(beta) if kind == "soft" else None, list(parts),
                                   list(env.phi.shape), list(train_R.shape)]).encode())
    h.update(np.ascontiguousarray(env.phi).tobytes())
    h.update(np.ascontiguousarray(train_R).tobytes())
    return h.hexdigest()


def _model_state(model: Any) -> str:
    """Digest of the model's learnt state that libraries depend on (dictionary, coefficients, residuals,
    objective and beta): a cached library of another state is stale and dropped when a new one is cached."""
    h = hashlib.sha256(json.dumps([_policy_kind(model), float(model.beta)]).encode())
    for name in ("dictionary_", "coefficients_", "residuals_"):
        value = model.__dict__.get(name)
        if value is not None:
            h.update(matrix_digest(value).encode())
    return h.hexdigest()


def gpi_library(model: Any, env: _Environment, parts: tuple[str, ...]) -> dict[str, Any]:
    """The library of ``env`` (cached on the model): ``labels``, ``policies`` (L, S) int or
    (L, S, A) float, and their successor features ``psi`` (L, S, A, k).

    Its one-off cost: planning the L = k (primitives) + k (negatives) + training rewards
    (exact ``Q*`` by policy iteration, or soft values), then one factorisation per policy
    solved for the k columns of ``phi``.
    """
    kind, beta = _policy_kind(model), float(model.beta)
    train_R = _train_rewards(model, env.train) if "tasks" in parts else np.empty((0,))
    if "other-tasks" in parts and env.others:
        W = np.asarray(model.coefficients_, dtype=np.float64)[env.others] @ np.asarray(model.dictionary_, dtype=np.float64).T
        residuals = model.__dict__.get("residuals_")
        if residuals is not None:
            W = W + np.asarray(residuals, dtype=np.float64)[env.others]
        other_R = np.asarray(env.basis.rewards(W), dtype=np.float64).reshape(len(env.others), *env.phi.shape[1:])
    else:
        other_R = np.empty((0,))
    key = _digest(env, np.concatenate([train_R.ravel(), other_R.ravel()]), kind, beta, parts)
    cache = successor_feature_cache(model)
    if key in cache:
        return cache[key]
    k = env.phi.shape[0]
    rewards, labels = [], []
    if "primitives" in parts:
        rewards.append(env.phi)
        labels += [f"primitive {j}" for j in range(k)]
    if "negatives" in parts:
        rewards.append(-env.phi)
        labels += [f"-primitive {j}" for j in range(k)]
    if "tasks" in parts and env.train:
        rewards.append(train_R)
        labels += [f"task {j}" for j in env.train]
    if other_R.size:
        rewards.append(other_R)
        labels += [f"task {j} (carried)" for j in env.others]
    R = np.concatenate(rewards, axis=0)
    planner = get_planner(env.mdp, model._group("execution").planner)
    policies = plan(planner, R).policy if kind == "greedy" else np.exp(soft_values(planner, R, beta)[2])
    psi = policy_successor_features(planner, np.ascontiguousarray(np.moveaxis(env.phi, 0, 2)), policies)
    state = _model_state(model)
    for stale in [old for old, e in cache.items() if e.get("state") != state]:
        del cache[stale]
    cache[key] = entry = {"labels": labels, "policies": policies, "psi": psi, "state": state}
    return entry


# -- GPI -------------------------------------------------------------------------------------------

def _start_weights(start: Any, n: int, S: int) -> NDArray[np.float64]:
    """``rho``: (S,) for one distribution shared by every task (the default: uniform), else (n, S)."""
    rho = check_start(start, n, S)
    if rho is None:
        return np.full(S, 1.0 / S)
    if isinstance(rho, int):
        out = np.zeros(S)
        out[rho] = 1.0
        return out
    return rho


def _improve_and_evaluate(planner: Any, phi: NDArray[np.float64], H: NDArray[np.float64], pol: NDArray[np.intp],
                          steps: int, evaluate: bool) -> tuple[NDArray[np.intp], Any, Any]:
    """``steps`` exact improvement steps of the GPI policies ``pol`` on the rewards ``H phi``, chunk by chunk
    of tasks (:data:`EVALUATION_CHUNK_BYTES` of planning memory); the values (n, S) of the GPI policies
    and of the returned ones (None where not computed)."""
    n, S = pol.shape
    k, _, A = phi.shape
    if not steps and not evaluate:
        return pol, None, None
    chunk = max(1, EVALUATION_CHUNK_BYTES // max(planner.task_bytes(), 8 * S * A))
    V_gpi, V_all = np.empty((n, S)), np.empty((n, S))
    pol = pol.copy()
    for lo in range(0, n, chunk):
        sl = slice(lo, lo + chunk)
        R = (H[sl] @ phi.reshape(k, S * A)).reshape(-1, S, A)
        p = pol[sl]
        for step in range(steps):
            p, V = improve_policies(planner, R, p)
            if step == 0:
                V_gpi[sl] = V
        if evaluate:
            V = greedy_values(planner, R, p)[0]
            V_all[sl] = V
            if not steps:
                V_gpi[sl] = V
        pol[sl] = p
    return pol, V_gpi, (V_all if evaluate else None)


@blas_limited
def generalised_policy_improvement(model: Any, mdp: Any, coefficients: ArrayLike, *, features: Any = None,
                                   improvement_steps: int = 0, library: Any = None, start: Any = None,
                                   evaluate: bool = True) -> tuple[NDArray[np.intp], GPIReport]:
    """Greedy policies of new tasks ``h`` by GPI over the model's library (module docstring).

    Parameters
    ----------
    model : FactIRL
        With a ``dictionary_`` (p, k), fitted or set by hand.
    mdp : TabularMDP or sequence of n TabularMDP
        The new tasks' environment(s): for a model fitted on one MDP that MDP; for a model
        fitted on several, each one of them.
    coefficients : array_like, shape (n, k) or (k,)
        The new tasks ``h`` (e.g. from ``FactIRL.transfer``): rewards ``Phi D h``.
    features : array_like or sequence of n array_like, optional
        For a model fitted with one feature matrix per task: each new task's, which must be
        (with its MDP) the environment of a fitted task. Otherwise None (the model's own).
    improvement_steps : int, default=0
        Exact policy-improvement steps after GPI (each one policy evaluation per task).
    library : str or sequence of str, optional
        Parts among :data:`LIBRARY_PARTS`; default :data:`DEFAULT_PARTS` (without ``"tasks"``
        for a model with no training tasks: a dictionary set by hand).
    start : None, int or array_like (S,) or (n, S), optional
        The start distribution of the reported values (default uniform).
    evaluate : bool, default=True
        Evaluate the GPI policies exactly for the report (one policy evaluation per task,
        shared with the first improvement step).

    Returns
    -------
    policies : ndarray of intp, shape (n, S) or (S,)
    report : GPIReport
    """
    if not hasattr(model, "dictionary_"):
        raise NotFittedError("this FactIRL has no dictionary_: call fit first, or set dictionary_ by hand")
    D = check_array(model.dictionary_, "dictionary_", ndim=2)
    k = D.shape[1]
    H = check_array(coefficients, "coefficients")
    single = H.ndim == 1
    H = H[None] if single else H
    if H.ndim != 2 or H.shape[1] != k:
        raise ValidationError(f"coefficients must have shape (n, k) or (k,) with k = {k} (the dictionary's primitives); "
                              f"got {np.shape(coefficients)}")
    if H.shape[0] == 0:
        raise ValidationError("coefficients must hold at least one task; got shape (0, k)")
    steps = check_int(improvement_steps, "improvement_steps", minimum=0)
    if not isinstance(evaluate, (bool, np.bool_)):
        raise ValidationError(f"evaluate must be True or False; got {evaluate!r}")
    fitted = hasattr(model, "rewards_") and getattr(model, "mdp_signature_", None) is not None
    parts = _check_parts(library, fitted)
    n = H.shape[0]
    envs, index = _environments(model, mdp, features, n, D, fitted)
    same_size = len({e.mdp.n_states for e in envs}) == 1
    out_list: list[Any] = [None] * n
    labels_per_task: list[list[str]] = [[] for _ in range(n)]
    lib_values: list[Any] = [None] * n
    best_value, gpi_value, value = np.empty(n), np.full(n, np.nan), np.full(n, np.nan)
    best_label = [""] * n
    for e, env in enumerate(envs):
        rows = np.flatnonzero(index == e)
        Hg = H[rows]
        rho = _start_weights(start, len(rows), env.mdp.n_states)
        entry = gpi_library(model, env, parts)
        values = library_values(entry["psi"], entry["policies"], Hg, rho)
        pol = gpi_actions(entry["psi"], Hg)
        pol, V_gpi, V_out = _improve_and_evaluate(get_planner(env.mdp, model._group("execution").planner), env.phi, Hg, pol, steps, evaluate)
        for j, i in enumerate(rows):
            out_list[i] = pol[j]
            labels_per_task[i] = entry["labels"]
            lib_values[i] = values[j]
            b = int(np.argmax(values[j]))
            best_value[i], best_label[i] = values[j, b], entry["labels"][b]
            r = rho if rho.ndim == 1 else rho[j]
            if V_gpi is not None:
                gpi_value[i] = r @ V_gpi[j]
            if V_out is not None:
                value[i] = r @ V_out[j]
    if same_size:
        policies = np.stack(out_list)
        result: Any = policies[0] if single else policies
    else:
        result = out_list[0] if single else out_list
    one_library = len(envs) == 1
    report = GPIReport(
        library=labels_per_task[0] if one_library else labels_per_task,
        library_values=np.stack(lib_values) if one_library else lib_values,
        best_library_value=best_value, best_library_policy=best_label,
        gpi_value=None if np.isnan(gpi_value).all() else gpi_value,
        value=None if np.isnan(value).all() else value, improvement_steps=steps)
    return result, report
