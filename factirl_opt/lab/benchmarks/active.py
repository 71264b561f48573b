"""Active demonstration requests: deviation after 1 to 8 demonstrations from requested, random or max-entropy starts.

For each world and seed, one process learns the dictionary on the training tasks (FactIRL with
the preset's solvers and budgets, policy matching), then gives each test task its one
demonstration and adds demonstrations one at a time, each from the start chosen by one of
the strategies below, and after each transfer records the test tasks' mean deviation (of the
transferred rewards, ``transfer_rewards_``, and of the posterior's mean, the MAP):

- ``requested``: ``FactIRL.request_starts`` with its defaults (expected information gain, docs/maths.md §10);
- ``requested-value``: the same posterior and expected curvature, ranked by the expected
  reduction of the posterior variance of the state values (``criterion="value"``);
- ``requested-regret``: ranked by the expected reduction of the linearised regret of acting on
  the posterior mean (``criterion="regret"``);
- ``requested-value-skip``: ``requested-value`` with the states already demonstrated adding no
  information (``demonstrated="skip"``: a greedy expert repeats its action there);
- ``random``: a uniformly random state;
- ``entropy``: the state where the model's policy at the posterior mean has the highest
  entropy (Lopes, Melo & Montesano 2009);
- ``requested-marginal``: the information gain averaged over the posterior's dictionaries
  (``request_starts(marginal=True)``; a model fitted with ``--posterior-dictionaries`` B > 0,
  else the same as ``requested``);
- ``requested-marginal-noise``: the same with ``posterior__noise="misfit"`` (each task's noise
  level scaled by its misfit);
- ``requested-noise``: ``requested`` with ``posterior__noise="misfit"`` (no marginalisation).
  The last three are not in the default line-up (``--strategies`` names them).

Every demonstration is the greedy expert's of the task's true reward, ``demo_length`` steps from
the chosen start, its random transitions drawn from common random numbers: a generator seeded by
(seed, task, step) alone (:func:`demonstration_rng`), the same whatever the strategy, so two
strategies requesting the same start get the same demonstration and the comparison measures the
strategy, not the draw. Worlds: ``grid`` (the paper's 10x10 grid with ``--grid-preset``'s solvers,
dictionary learnt from ``--n-train`` training tasks x 10 demonstrations) and
``objectworld-per-task-quick`` (a map per task, 8x8, the preset's training tasks). It also
measures the CPU time (``time.process_time``) of one request for one task (building its
posterior and ranking every state) against one transfer of that task, task by task over the
first ``--cost-tasks`` test tasks, and, with
``--calibration``, on the grid's test tasks (one demonstration each): how often the 90%
upper bound on regret (``sample_regrets``) covers the true deviation of the posterior mean,
and the Spearman rank correlation between the expected regret and that deviation.
``--quick``: a small configuration for tests.
"""

from __future__ import annotations

import statistics
import time
from typing import Any

import numpy as np
from scipy.stats import spearmanr

from ...parallel import limit_blas_threads
from ...evaluation import deviation
from ...learners.active import policy_entropy_starts, request_starts
from ...learners.dictionary_ensemble import PosteriorSettings
from ...learners.factirl import FactIRL
from ...tasks.demonstrations import sample_demonstrations
from ..arguments import integer, real
from ..experiments.learner_solvers import factorial_options
from ..experiments.presets import PRESETS
from ..experiments.worlds import make_ground_truth
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "world", "strategy_run", "demonstration_rng", "STRATEGIES", "REQUESTS", "WORLDS", "DEFAULTS"]

STRATEGIES = ("requested", "requested-value", "random", "entropy", "requested-regret", "requested-value-skip",
              "requested-marginal", "requested-marginal-noise", "requested-noise")
#: the requested strategies' options of ``request_starts`` (``"requested"``: its defaults)
REQUESTS = {"requested": {}, "requested-value": {"criterion": "value"}, "requested-regret": {"criterion": "regret"},
            "requested-value-skip": {"criterion": "value", "demonstrated": "skip"},
            "requested-marginal": {"marginal": True}, "requested-marginal-noise": {"marginal": True}, "requested-noise": {}}
#: the model's posterior settings a strategy runs with, restored after it (the others: the model's own)
POSTERIOR_SETTINGS = {"requested-marginal-noise": {"posterior__noise": "misfit"}, "requested-noise": {"posterior__noise": "misfit"}}
WORLDS = ("grid", "objectworld-per-task-quick")
DEFAULTS = {"worlds": list(WORLDS), "seeds": [0, 1, 2], "grid_preset": "fast", "n_train": 100, "n_test": 30,
            "max_demos": 8, "strategies": list(STRATEGIES[:6]), "calibration": False, "n_samples": 200, "cost_tasks": 10, "cost_repeats": 3,
            "blas_threads": 1, "transfer_stol": None, "posterior_dictionaries": 0, "posterior_resampling": "bootstrap"}
QUICK = {"worlds": ["grid"], "seeds": [0], "grid_preset": "tiny", "n_train": 6, "n_test": 3, "max_demos": 2,
         "n_samples": 20, "cost_tasks": 2, "cost_repeats": 1}


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--worlds", nargs="+", choices=WORLDS, help="worlds to run")
    opt("--seeds", type=integer(0), nargs="+", metavar="SEED", help="seeds of the ground truth")
    opt("--grid-preset", choices=sorted(n for n, p in PRESETS.items() if p.world == "grid"),
        help="the grid world's preset (its size, dynamics, solvers and budgets)")
    opt("--n-train", type=integer(2), help="training tasks of the grid world (10 demonstrations each)")
    opt("--n-test", type=integer(1), help="test tasks per world and seed (at most the preset's)")
    opt("--max-demos", type=integer(1), help="demonstrations per test task at the end")
    opt("--strategies", nargs="+", choices=STRATEGIES, help="how the next start is chosen")
    parser.add_argument("--calibration", action="store_true", default=None,
                        help="also measure the regret bound's coverage and rank correlation on the grid's test tasks")
    opt("--n-samples", type=integer(1), help="posterior samples per task for the calibration")
    opt("--cost-tasks", type=integer(1), help="test tasks whose request cost is measured, one at a time")
    opt("--cost-repeats", type=integer(1), help="repeats of the request-cost measurement (median per task)")
    opt("--blas-threads", type=integer(1), help="BLAS threads")
    opt("--transfer-stol", type=real(0.0), help="FactIRL's transfer_stol (default: the library's)")
    opt("--posterior-dictionaries", type=integer(0),
        help="FactIRL's posterior.n_dictionaries: refitted dictionaries the posterior marginalises over")
    opt("--posterior-resampling", choices=("bootstrap", "folds"), help="FactIRL's posterior.resampling")
    parser.add_argument("--quick", action="store_true", help="a small configuration for tests")


def world(name, s, seed):
    """One world of the benchmark: (preset, ground truth, train mdp(s), train features, test mdp(s), test features).

    ``name`` is ``"grid"`` or a preset name, ``s`` the settings (:data:`DEFAULTS` updated), ``seed`` the
    ground truth's seed; features are None on the grid (one MDP shared by every task)."""
    if name == "grid":
        preset = PRESETS[s["grid_preset"]]
        gt = make_ground_truth(preset, s["n_train"], 10 if s["grid_preset"] != "tiny" else preset.default_demos, seed)
        return preset, gt, gt.mdp, None, gt.mdp, None
    preset = PRESETS[name]
    gt = make_ground_truth(preset, preset.default_tasks, preset.default_demos, seed)
    return (preset, gt, gt.mdps("train"), list(gt.task_maps["train"].features), gt.mdps("test"),
            list(gt.task_maps["test"].features))


def _task_mdp(mdps, i):
    return mdps[i] if isinstance(mdps, list) else mdps


def _take(x, n):
    return None if x is None else x[:n]


#: the first word of the demonstrations' seeds, apart from every other stream of the benchmark
_DEMO_STREAM = 0x64656D6F


def demonstration_rng(seed, task, step):
    """The generator of the random transitions of test task ``task``'s demonstration added at ``step``.

    Common random numbers: it depends on (``seed``, ``task``, ``step``) only, not on the strategy,
    so strategies that request the same start at the same step get the same demonstration.
    ``step`` counts from 1 (the demonstration added after the step-th transfer)."""
    return np.random.default_rng([_DEMO_STREAM, seed, task, step])


def _deviations(model, gt, mdps, n, posts):
    true = gt.test_rewards[:n]
    m = mdps[:n] if isinstance(mdps, list) else mdps
    dev = deviation(m, true, model.transfer_rewards_)
    dev_map = deviation(m, true, np.stack([p.mean_rewards() for p in posts])) if posts is not None else None
    return np.asarray(dev), (None if dev_map is None else np.asarray(dev_map))


def strategy_run(model, gt, preset, mdps, feats, n, strategy, s, seed, *, policy="boltzmann", start_rng=None,
                 **request_options):
    """Mean deviations after 1..max_demos demonstrations with starts chosen by ``strategy``.

    ``model`` is fitted on the training tasks; the first ``n`` test tasks of ``gt`` (on ``mdps``,
    ``feats`` as :func:`world` returns them) start from one demonstration each, and each step adds one
    from the start ``strategy`` (one of :data:`STRATEGIES`) picks; ``policy`` is passed to
    :func:`~factirl_opt.learners.active.request_starts` by the requested strategies, with any other
    ``request_options`` (they replace the strategy's own, :data:`REQUESTS`). Returns a dict of
    lists: ``deviation``, ``map_deviation`` (posterior mean), ``starts``. The random starts are drawn
    from ``start_rng`` (default: a generator seeded by ``seed`` and the strategy), the demonstrations'
    transitions from :func:`demonstration_rng` (common to every strategy)."""
    rng = np.random.default_rng([seed, STRATEGIES.index(strategy)]) if start_rng is None else start_rng
    demos = [np.asarray(d) for d in gt.test_demos[:n]]
    L = demos[0].shape[1]
    m_list, f_list = (mdps[:n] if isinstance(mdps, list) else mdps), _take(feats, n)
    out: dict[str, list] = {"deviation": [], "map_deviation": [], "starts": []}
    options = {**REQUESTS.get(strategy, {}), **request_options}
    settings = POSTERIOR_SETTINGS.get(strategy, {})
    before = {"posterior": model.posterior} if settings else {}
    if settings:
        model.set_params(**settings)
    try:
        return _run_steps(model, gt, mdps, n, strategy, s, seed, rng, demos, L, m_list, f_list, out, options, policy)
    finally:
        if settings:
            model.set_params(**before)


def _run_steps(model, gt, mdps, n, strategy, s, seed, rng, demos, L, m_list, f_list, out, options, policy):
    for step in range(1, s["max_demos"] + 1):
        model.transfer(m_list, demos, features=f_list)
        posts = model.transfer_posterior_
        dev, dev_map = _deviations(model, gt, mdps, n, posts)
        out["deviation"].append(float(dev.mean()))
        out["map_deviation"].append(float(dev_map.mean()))
        if step == s["max_demos"]:
            break
        if strategy.startswith("requested"):
            starts = [int(r[0]) for r in request_starts(model, m_list, demos, 1, features=f_list, policy=policy, **options)]
        elif strategy == "entropy":
            starts = [int(r[0]) for r in policy_entropy_starts(posts, "policy-matching", model.beta)]
        else:
            starts = [int(rng.integers(_task_mdp(mdps, i).n_states)) for i in range(n)]
        out["starts"].append(starts)
        for i in range(n):
            new = sample_demonstrations(_task_mdp(mdps, i), gt.test_rewards[i][None], 1, L,
                                        rng=demonstration_rng(seed, i, step), start=starts[i])[0]
            demos[i] = np.concatenate([demos[i], np.asarray(new)], axis=0)
    return out


def _request_cost(model, gt, mdps, feats, n, repeats):
    """CPU time of one request for one task against one transfer of that task, over the first ``n`` test tasks.

    Each task alone (one demonstration): ``transfer``, then the request (its posterior, built
    when first read, and the ranking of every state). Per task the median over ``repeats``;
    reported: the ratio of the sums over the tasks and the median and largest per-task ratios.
    """
    transfer, request = np.zeros(n), np.zeros(n)
    for i in range(n):
        m1 = [_task_mdp(mdps, i)] if isinstance(mdps, list) else mdps
        f1 = None if feats is None else [feats[i]]
        t_tr, t_rq = [], []
        for _ in range(repeats):
            demos = [np.asarray(gt.test_demos[i])]
            t = time.process_time()
            model.transfer(m1, demos, features=f1)
            t_tr.append(time.process_time() - t)
            t = time.process_time()
            model.transfer_posterior_
            model.request_starts(m1, demos, 1, features=f1)
            t_rq.append(time.process_time() - t)
        transfer[i], request[i] = statistics.median(t_tr), statistics.median(t_rq)
    ratio = request / transfer
    return {"n_tasks": n, "transfer_cpu_s": float(transfer.sum()), "request_cpu_s": float(request.sum()),
            "request_over_transfer": float(request.sum() / transfer.sum()),
            "median_task_ratio": float(np.median(ratio)), "max_task_ratio": float(ratio.max())}


def _calibration(model, gt, n_samples, seed):
    """Coverage of the 90% regret bound and Spearman(expected regret, deviation) over the grid's test tasks."""
    model.transfer(gt.mdp, gt.test_demos)
    posts = model.transfer_posterior_
    t = time.process_time()
    regrets = np.array([p.sample_regrets(n_samples, np.random.default_rng([seed, i])) for i, p in enumerate(posts)])
    sampling = time.process_time() - t
    dev_map = np.asarray(deviation(gt.mdp, gt.test_rewards, np.stack([p.mean_rewards() for p in posts])))
    dev_transfer = np.asarray(deviation(gt.mdp, gt.test_rewards, model.transfer_rewards_))
    expected, upper = regrets.mean(axis=1), np.quantile(regrets, 0.9, axis=1)
    return {"n_tasks": len(posts), "n_samples": n_samples,
            "coverage_90": float(np.mean(dev_map <= upper)),
            "spearman": float(spearmanr(expected, dev_map).correlation),
            "coverage_90_transferred": float(np.mean(dev_transfer <= upper)),
            "spearman_transferred": float(spearmanr(expected, dev_transfer).correlation),
            "mean_expected_regret": float(expected.mean()), "mean_upper_90": float(upper.mean()),
            "mean_deviation_map": float(dev_map.mean()), "mean_deviation_transferred": float(dev_transfer.mean()),
            "sampling_cpu_s": sampling}


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    result: dict[str, Any] = {"settings": {k: v for k, v in s.items() if k != "quick"}, "worlds": {}}
    with limit_blas_threads(s["blas_threads"]):
        for name in s["worlds"]:
            per_seed = {}
            for seed in s["seeds"]:
                preset, gt, train_mdps, train_feats, test_mdps, test_feats = world(name, s, seed)
                n = min(s["n_test"], len(gt.test_demos))
                t = time.process_time()
                extra = {} if s["transfer_stol"] is None else {"transfer_stol": s["transfer_stol"]}
                posterior = PosteriorSettings(n_dictionaries=s["posterior_dictionaries"], resampling=s["posterior_resampling"])
                options = factorial_options(preset, preset.solvers, "policy-matching", features=train_feats is not None)
                model = FactIRL(rng=seed, features=train_feats, posterior=posterior, **{**options, **extra})
                model.fit(train_mdps, gt.train_demos)
                row: dict[str, Any] = {"fit_cpu_s": time.process_time() - t, "n_test": n,
                                       "n_train": len(gt.train_demos), "k": model.n_primitives_}
                row["strategies"] = {st: strategy_run(model, gt, preset, test_mdps, test_feats, n, st, s, seed)
                                     for st in s["strategies"]}
                row["request_cost"] = _request_cost(model, gt, test_mdps, test_feats, min(n, s["cost_tasks"]),
                                                    s["cost_repeats"])
                if s["calibration"] and name == "grid":
                    row["calibration"] = _calibration(model, gt, s["n_samples"], seed)
                per_seed[str(seed)] = row
            result["worlds"][name] = per_seed
    return result
