"""Time FactIRL fits with policy matching and with MCE side by side, on Objectworld with a map per task.

ELIRL's protocol (Mendez et al. 2018; preset ``objectworld-per-task``): a 32x32 Objectworld,
every training task on its own map, 32 demonstrations of 16 steps per task, k = 5, the
learners on each map's feature weights (:mod:`factirl_opt.lab.experiments.per_task`). For each
``--objectives`` entry, in one process and on the same draw, one ``FactIRL.fit`` from scratch
(``init="pca"``: its own flat fit on features, then the factorial fit), with the preset's
budgets, solvers and outer scheme as the experiment runner builds them
(:func:`~factirl_opt.lab.experiments.learner_solvers.factorial_options`: an objective without
residuals, MCE, takes L-BFGS where the preset names a Gauss-Newton solver), and the flat
start with the solver of the preset's flat fits on features
(:func:`~factirl_opt.lab.experiments.learner_solvers.flat_features_solver`), as the line-up's
FactIRL rows start from the ``flat, features`` row's weights. For ``objectworld-per-task``:
an L-BFGS flat start and the joint scheme.

Prints, per objective: wall time of the fit and the process's CPU time (with one BLAS thread,
the fit's own work: on a shared machine it does not grow with the other processes' load, the
wall time does), batched planning evaluations, outer iterations,
status, final loss, the mean train deviation (eq. 13, each task on its own map), and the
planning work counted by a wrapping planner (:class:`CountingPlanner`): task systems
built (a new sparse factorisation per task for a stochastic policy; a deterministic one may be
served from the planner's cache or updated at low rank), forward solves (Newton steps of the
soft Bellman equation for MCE, policy-evaluation sweeps and Jacobian products for policy
matching) and transposed (adjoint) solves, in task systems and in batched calls per evaluation.
``ratio_mce_over_pm`` divides MCE's wall time by policy matching's, ``cpu_ratio_mce_over_pm``
their CPU times, ``deviation_ratio_mce_over_pm`` their deviations. ``--repeats`` fits each
objective that many times, alternating, and keeps each one's fastest times (the counts do not
change between repeats; the model of the first is transferred).

``--flat-solvers`` fits FactIRL once per objective and flat-start solver (FactIRL's
``flat_solver``: ``default`` is the preset's, as above; e.g. ``armijo``, FactIRL's own, or
``newton``, the second-order solver), side by side in the same process on the same draw;
``--h-solvers`` likewise compares H-step solvers (``default``: the preset's, or L-BFGS where it
names a Gauss-Newton solver for MCE); ``--schemes`` likewise compares FactIRL's outer schemes
(``default``: the preset's; ``alternating``, the paper's; ``joint``: quasi-Newton steps of the
D-step solver on the dictionary and coefficients together,
:func:`~factirl_opt.learners.factorial.fit_factorial`). An entry is keyed by its objective, then
by what differs from the preset's fit: ``", flat <solver>"``, ``", H <solver>"``,
``", <scheme>"``; ``"policy-matching"`` and ``"mce"`` are the preset's fits, and the entries
naming the same fit twice (``default`` and the preset's solver) are fitted once. The fit
before the full-size Objectworld presets took L-BFGS flat starts and the joint scheme,
FactIRL's own Armijo start and the alternation, is ``--flat-solvers armijo default --schemes
alternating default``'s ``"<objective>, flat armijo, alternating"``. Each entry records its
flat-start solver and scheme by name (``flat_solver``, ``scheme``) and the H-step solver as
asked (``h_solver``). Every entry also scores the training tasks' learnt weights on fresh maps of
their tasks (``mean_new_maps_deviation``, the experiments' ``new_maps_deviation`` of the train
split). ``--flat-tol`` sets every fit's ``FactIRL(flat_tol=...)``, the tolerance of its flat
start. With ``--n-test-tasks`` (default 10), every fitted
model is also transferred (``FactIRL.transfer``, its H-step solver) to that many test tasks, each
on a new map of its own with one demonstration, and the entry gets their mean deviation
(``mean_transfer_deviation``) and the transfer's CPU time and evaluations (the planning counts are
the fit's only).

``--quick`` is a tiny configuration for tests (options given explicitly keep their value).
"""

import dataclasses
import time

import numpy as np
import solvers

from ...parallel import limit_blas_threads
from ...evaluation import deviation
from ...exceptions import ValidationError
from ..experiments.learner_solvers import factorial_options, factorial_scheme, flat_features_solver
from ..experiments.presets import PRESETS, get_preset
from ..experiments.worlds import objectworld_per_task
from ...learners.factirl import FactIRL
from ...learners.solver_settings import SolverSettings
from ...learners.factorial import SCHEMES
from ...datasets.objectworld import state_action_rewards
from ...tasks.features import feature_rewards
from ...planning import CountingPlanner, get_planner
from ..arguments import integer, real
from . import add_option, resolve_settings

__all__ = ["add_arguments", "run", "OBJECTIVES", "benchmark_preset", "resolved_run", "fit_once", "fit_entry",
           "transfer_entry", "new_maps_deviation"]

#: the objectives compared (policy matching the reference of the ratios)
OBJECTIVES = ("policy-matching", "mce")
DEFAULTS = {"preset": "objectworld-per-task", "size": 32, "n_tasks": 10, "n_demos": 32, "length": 16, "n_primitives": 5,
            "max_iter": None, "flat_max_iter": None, "objectives": list(OBJECTIVES), "repeats": 1, "seed": 0,
            "blas_threads": 1, "flat_solvers": ["default"], "h_solvers": ["default"], "schemes": ["default"],
            "flat_tol": None, "n_test_tasks": 10}
QUICK = {"size": 8, "n_tasks": 4, "n_demos": 4, "length": 8, "n_primitives": 2, "max_iter": 3, "flat_max_iter": 10,
         "n_test_tasks": 2}
#: the entry of ``--flat-solvers``, ``--h-solvers`` and ``--schemes`` meaning the preset's
DEFAULT_FLAT = "default"


def add_arguments(parser):
    def opt(*flags, **kw):
        add_option(parser, *flags, defaults=DEFAULTS, quick=QUICK, **kw)

    opt("--preset", choices=sorted(n for n, p in PRESETS.items() if p.world == "objectworld-per-task"), help="preset of the budgets and solvers (a world with a map per task)")
    opt("--size", type=integer(2), help="grid side")
    opt("--n-tasks", type=integer(1), help="training tasks, each on its own map")
    opt("--n-demos", type=integer(1), help="demonstrations per task")
    opt("--length", type=integer(1), help="steps per demonstration")
    opt("-k", "--n-primitives", type=integer(1), help="primitives, true (inner colours) and learnt")
    opt("--max-iter", type=integer(0), help="FactIRL outer iterations (None: the preset's)")
    opt("--flat-max-iter", type=integer(0), help="iterations of FactIRL's flat start (None: the preset's)")
    opt("--objectives", nargs="+", choices=OBJECTIVES, metavar="NAME", help="objectives fitted, in this order")
    opt("--repeats", type=integer(1), help="fits per objective, alternating; the fastest is kept")
    opt("--flat-solvers", nargs="+", choices=[DEFAULT_FLAT, *solvers.available_solvers()], metavar="NAME",
        help="FactIRL flat-start solvers compared, a fit per objective and solver ('default': the preset's flat solver "
             "on features)")
    opt("--h-solvers", nargs="+", choices=[DEFAULT_FLAT, *solvers.available_solvers()], metavar="NAME",
        help="FactIRL H-step solvers compared, a fit per objective, flat solver and H solver ('default': the preset's)")
    opt("--schemes", nargs="+", choices=[DEFAULT_FLAT, *SCHEMES], metavar="NAME",
        help="FactIRL outer schemes compared, a fit per objective, flat solver, H solver and scheme ('default': the preset's)")
    opt("--flat-tol", type=real(low=0.0), help="tolerance of FactIRL's flat start (None: FactIRL's own, 1e-5)")
    opt("--n-test-tasks", type=integer(0), help="test tasks on new maps (one demonstration each) transferred to; 0: none")
    opt("--seed", type=integer(0), help="seed of the maps and demonstrations")
    opt("--blas-threads", type=integer(0), help="OpenBLAS threads (0: leave as is)")
    parser.add_argument("--quick", action="store_true",
                        help="tiny configuration for tests; options given explicitly keep their value")


def benchmark_preset(s):
    """The preset with the benchmark's size, primitives, demonstration length and budgets."""
    preset = get_preset(s["preset"])
    if preset.world != "objectworld-per-task":
        per_task = sorted(name for name, p in PRESETS.items() if p.world == "objectworld-per-task")
        raise ValidationError(f"bench mce: preset {s['preset']!r} is not a world with a map per task; use one of "
                              f"{', '.join(per_task)}")
    for key in ("size", "n_tasks", "n_demos", "length", "n_primitives", "repeats"):
        if s[key] < 1:
            raise ValidationError(f"bench mce: --{key.replace('_', '-')} must be at least 1; got {s[key]}")
    if s["n_test_tasks"] < 0:
        raise ValidationError(f"bench mce: --n-test-tasks must be at least 0; got {s['n_test_tasks']}")
    changes = dict(grid_size=s["size"], n_primitives=s["n_primitives"], demo_length=s["length"],
                   n_test_tasks=max(1, s["n_test_tasks"]))
    for key, field in (("max_iter", "fact_max_iter"), ("flat_max_iter", "flat_max_iter")):
        if s[key] is not None:
            changes[field] = s[key]
    return dataclasses.replace(preset, **changes)


def resolved_run(preset, objective, flat_solver=DEFAULT_FLAT, h_solver=DEFAULT_FLAT, scheme=DEFAULT_FLAT):
    """The flat-start solver and the scheme of a fit, by name: ``"default"`` is the preset's
    (:func:`~factirl_opt.lab.experiments.learner_solvers.flat_features_solver`,
    :func:`~factirl_opt.lab.experiments.learner_solvers.factorial_scheme` with the H-step solver
    ``h_solver`` unless ``"default"``)."""
    if flat_solver == DEFAULT_FLAT:
        flat_solver = flat_features_solver(preset, objective)
    if scheme == DEFAULT_FLAT:
        settings = preset.solvers if h_solver == DEFAULT_FLAT else preset.solvers.with_overrides(h_solver=h_solver)
        scheme = factorial_scheme(preset, settings, objective)[0]
    return flat_solver, scheme


def fit_once(preset, gt, objective, seed, flat_solver=DEFAULT_FLAT, h_solver=DEFAULT_FLAT, scheme=DEFAULT_FLAT,
             flat_tol=None):
    """One FactIRL fit from scratch with ``objective`` (``flat_solver``, ``h_solver`` and ``scheme``:
    the preset's where ``"default"``, :func:`resolved_run`; ``flat_tol`` FactIRL's where None): its
    model, wall time, CPU time and counting planner (the benchmark's unit of work;
    ``results/mce-speed/profile_fit.py`` and ``results/fit-speed/profile_fit.py`` profile it)."""
    mdps = gt.mdps("train")
    planner = CountingPlanner(get_planner(mdps[0], preset.planner))
    kw = factorial_options(preset, preset.solvers, objective)
    kw["execution"] = kw["execution"].set_params(planner=planner)
    flat, kw["scheme"] = resolved_run(preset, objective, flat_solver, h_solver, scheme)
    settings = SolverSettings.of(kw["solver"]).set_params(flat_solver=flat)
    kw["solver"] = settings.set_params(h_solver=h_solver) if h_solver != DEFAULT_FLAT else settings
    if flat_tol is not None:
        kw["start"] = kw["start"].set_params(flat_tol=flat_tol)
    model = FactIRL(rng=np.random.default_rng(seed), features=list(gt.task_maps["train"].features), **kw)
    planner.clear_cache()
    t0, c0 = time.perf_counter(), time.process_time()
    model.fit(mdps, gt.train_demos)
    return model, time.perf_counter() - t0, time.process_time() - c0, planner


def transfer_entry(model, gt, preset, n_test):
    """Mean deviation of the model's transfer to the first ``n_test`` test tasks (each on its own
    map), the transfer's CPU time and evaluations; an empty dict without test tasks."""
    if n_test == 0:
        return {}
    mdps = gt.mdps("test")[:n_test]
    model.set_params(execution__planner=preset.planner)  # the counting planner is bound to the training maps' MDP
    c0 = time.process_time()
    model.transfer(mdps, gt.test_demos[:n_test], features=list(gt.task_maps["test"].features)[:n_test])
    cpu = time.process_time() - c0
    dev = deviation(mdps, gt.test_rewards[:n_test], np.asarray(model.transfer_rewards_), planner=preset.planner)
    return {"mean_transfer_deviation": float(np.mean(dev)), "transfer_cpu_s": cpu,
            "transfer_n_evaluations": int(model.transfer_n_evaluations_)}


def new_maps_deviation(model, gt, preset):
    """Mean deviation (eq. 13) of the training tasks' learnt weights ``D h_i`` on fresh maps of
    their tasks (:meth:`~factirl_opt.lab.experiments.worlds.GroundTruth.fresh`): what the
    experiments report as the train split's ``new_maps_deviation``."""
    fresh = gt.fresh("train")
    mdps = list(fresh.mdps)
    true = state_action_rewards(fresh.rewards, mdps[0].n_actions)
    weights = model.coefficients_ @ model.dictionary_.T + model.residuals_
    learnt = feature_rewards(list(fresh.features), weights, mdps)
    return float(np.mean(deviation(mdps, true, learnt, planner=preset.planner)))


def fit_entry(model, elapsed, planner, gt, preset):
    """The benchmark's record of one fit: times, evaluations, loss, train deviation (eq. 13) and
    the counting planner's work per evaluation (the keys of ``fits[objective]`` in the output)."""
    counts = planner.counts()
    n_eval = max(int(model.n_evaluations_), 1)
    mdps = gt.mdps("train")
    dev = deviation(mdps, gt.train_rewards, np.asarray(model.rewards_), planner=preset.planner)
    return {"time_s": elapsed, "n_evaluations": int(model.n_evaluations_), "n_iter": int(model.n_iter_),
            "status": model.status_, "final_loss": float(np.sum(model.loss_)), "mean_train_deviation": float(np.mean(dev)),
            "mean_new_maps_deviation": new_maps_deviation(model, gt, preset),
            **counts, "n_linear_solves": counts["n_forward"] + counts["n_transpose"],
            "forward_calls_per_evaluation": counts["n_forward_calls"] / n_eval,
            "forward_solves_per_task_evaluation": counts["n_forward"] / (n_eval * gt.train_rewards.shape[0]),
            "systems_per_evaluation": counts["n_systems"] / n_eval}


def run(args):
    s = resolve_settings(args, DEFAULTS, QUICK)
    preset = benchmark_preset(s)
    objectives = list(dict.fromkeys(s["objectives"]))
    flats = list(dict.fromkeys(s["flat_solvers"]))
    hs = list(dict.fromkeys(s["h_solvers"]))
    schemes = list(dict.fromkeys(s["schemes"]))
    runs, keys = [], {}
    for obj in objectives:
        preset_flat, preset_scheme = resolved_run(preset, obj)
        for flat in flats:
            for h in hs:
                for scheme in schemes:
                    flat_name, scheme_name = resolved_run(preset, obj, flat, h, scheme)
                    run = (obj, flat_name, h, scheme_name)
                    if run not in keys:  # "default" and the preset's solver or scheme name one fit
                        runs.append(run)
                        keys[run] = (obj + ("" if flat_name == preset_flat else f", flat {flat_name}")
                                     + ("" if h == DEFAULT_FLAT else f", H {h}")
                                     + ("" if scheme_name == preset_scheme else f", {scheme_name}"))
    entries, transfers, times, cpus = {}, {}, {keys[r]: [] for r in runs}, {keys[r]: [] for r in runs}
    with limit_blas_threads(s["blas_threads"]) as threads:
        t0 = time.perf_counter()
        gt = objectworld_per_task(preset, s["n_tasks"], s["n_demos"], s["seed"])
        t_data = time.perf_counter() - t0
        for _ in range(s["repeats"]):
            for run in runs:
                name = keys[run]
                model, elapsed, cpu, planner = fit_once(preset, gt, run[0], s["seed"] + 1, run[1], run[2], run[3],
                                                        s["flat_tol"])
                times[name].append(elapsed)
                cpus[name].append(cpu)
                entries[name] = fit_entry(model, elapsed, planner, gt, preset)
                if name not in transfers:  # the repeats fit the same model: it is transferred once
                    transfers[name] = transfer_entry(model, gt, preset, s["n_test_tasks"])
                entries[name].update(flat_solver=run[1], h_solver=run[2], scheme=run[3], **transfers[name])
    for name in entries:
        entries[name]["time_s"], entries[name]["times_s"] = min(times[name]), times[name]
        entries[name]["cpu_s"], entries[name]["cpus_s"] = min(cpus[name]), cpus[name]
    out = {"benchmark": "mce", "fits": entries, "data_time_s": t_data}
    if set(OBJECTIVES) <= set(entries):
        ref, other = entries["policy-matching"], entries["mce"]
        out["ratio_mce_over_pm"] = other["time_s"] / ref["time_s"]
        out["cpu_ratio_mce_over_pm"] = other["cpu_s"] / ref["cpu_s"]
        d = ref["mean_train_deviation"]
        out["deviation_ratio_mce_over_pm"] = other["mean_train_deviation"] / d if d > 0 else float("nan")
    settings = {key: s[key] for key in DEFAULTS}
    settings.update(quick=bool(s["quick"]), blas_threads=threads, objectives=objectives, flat_solvers=flats, h_solvers=hs,
                    schemes=schemes, preset_fits={obj: dict(zip(("flat_solver", "scheme"), resolved_run(preset, obj)))
                                                  for obj in objectives},
                    fact_max_iter=preset.fact_max_iter, flat_max_iter=preset.flat_max_iter)
    out["settings"] = settings
    return out
