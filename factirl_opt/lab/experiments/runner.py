"""The one experiment runner: plan the runs of a preset and execute them (in parallel, resumably).

The experiment path, each stage taking the previous stage's output: preset (:mod:`.presets`)
-> :func:`plan_sweep` -> :class:`SweepPlan` -> :func:`run_plan` (execution, :mod:`.store`,
:mod:`.tables`) -> claims and figures (:mod:`.claims`, :mod:`.figures`, from the output
directory). :func:`run_sweep` plans and runs in one call.

A *run* is one ``(n_tasks, demos_per_task, seed)`` point of a preset with the factorial
learner's solver settings: generate the ground truth in the preset's world
(:func:`.worlds.make_ground_truth`), build every learner of the preset's line-up
(:mod:`.learners`: fits on the training tasks, figure 1; transfers to the test tasks, figure 2),
and score each by the mean deviation (:func:`factirl_opt.deviation`) over the run's tasks (in a
world with a map per task, also on fresh maps: :func:`.per_task.add_new_map_scores`).

Output directory layout::

    OUT/runs/<key>.json   one record per finished run, checked before reuse (:mod:`.store`)
    OUT/results.csv, summary.csv, timings.csv, figure3.json   (:mod:`.tables`)
    OUT/manifest.json     every run of the tables and every invocation (:mod:`.store`)
    OUT/.lock             while a sweep writes (a second one is refused)
    OUT/claims.md, OUT/figures/   drawn from the tables (``factirl-opt plot``); a sweep that
                          rewrites the tables removes those of earlier tables (:data:`DERIVED_OUTPUTS`)

A rerun into the same directory reuses the finished runs and computes only the missing (or
rejected) ones, so an interrupted sweep loses at most the runs in flight; tables are sorted, and
every run is single-threaded with its own random streams, so they are identical whatever
``--jobs`` is. Runs execute in this process (``jobs=1``), in worker processes that never outlive
it (:mod:`.workers`), or on a Dask cluster.
"""

from __future__ import annotations

import collections
import contextlib
import dataclasses
import functools
import os
import sys
import time
import warnings
from collections.abc import Callable, Generator, Iterable
from typing import Any

import numpy as np

from ...parallel import limit_blas_threads
from ...validation import check_int
from ...evaluation import deviation
from ...parallel import BACKENDS  # how shards and sweep runs are served (``"loky"`` is the former name of ``"processes"``)
from ...exceptions import MaxIterWarning, PersistenceError, ValidationError
from ...files import os_error
from ...planning import optimal_q
from ...learners.solver_settings import SolverSettings
from . import store
from .claims import CLAIMS_FILE
from .figures import figure_files
from .learners import Lineup, RunContext, get_lineup, substitutions
from .per_task import add_new_map_scores
from .presets import Preset, get_preset
from .tables import write_tables
from .workers import imap_unordered, sigterm_raises
from .worlds import make_ground_truth

__all__ = ["RunSpec", "SweepPlan", "Execution", "DERIVED_OUTPUTS", "SolverSubstitutionWarning",
           "plan_sweep", "plan_runs", "run_cost", "run_one", "run_plan", "run_sweep"]

#: test tasks whose value functions figure 3 shows
N_FIGURE3_TASKS = 4
#: files drawn from the tables (relative to the output directory): removed when a sweep rewrites them
DERIVED_OUTPUTS = (CLAIMS_FILE, *(os.path.relpath(path, "OUT") for path in figure_files("OUT")))


class SolverSubstitutionWarning(UserWarning):
    """A learner of the line-up takes another solver than the one named (see :func:`.learners.substitutions`)."""


@dataclasses.dataclass(frozen=True, order=True)
class RunSpec:
    """One run: a point of the sweeps, a seed, the factorial learner's solver settings.

    Build specs with :func:`plan_sweep` (or :func:`plan_runs`).
    """

    n_tasks: int
    demos_per_task: int
    seed: int
    solvers: SolverSettings = SolverSettings()

    def solver_label(self) -> str:
        """The ``h_solver`` column of the tables (:meth:`SolverSettings.label`)."""
        return self.solvers.label()

    def key(self, preset: Preset) -> str:
        """File stem of the run, unique per preset configuration (fingerprint) and solver settings."""
        return (f"n{self.n_tasks:03d}-m{self.demos_per_task:02d}-seed{self.seed}-{self.solvers.key_part()}-"
                f"{preset.fingerprint()}")

    def to_dict(self) -> dict[str, Any]:
        """The run as plain values, the solver settings flattened (a run record's ``spec``)."""
        return dict(n_tasks=self.n_tasks, demos_per_task=self.demos_per_task, seed=self.seed, **self.solvers.fields())


@dataclasses.dataclass(frozen=True)
class SweepPlan:
    """The planned runs of a sweep: what :func:`run_plan` executes.

    Attributes
    ----------
    preset : Preset
    lineup : Lineup
        The preset's line-up.
    solvers : SolverSettings
        The factorial learner's solvers of every run.
    seeds : tuple of int
    runs : tuple of RunSpec
        Sorted: points of both sweeps x seeds.
    keys : tuple of str
        The runs' keys (file stems of their records), in the order of ``runs``.
    substitutions : tuple of str
        Solvers the line-up's learners take instead of those named (:func:`.learners.substitutions`).
    """

    preset: Preset
    lineup: Lineup
    solvers: SolverSettings
    seeds: tuple
    runs: tuple
    keys: tuple
    substitutions: tuple = ()

    def costs(self) -> dict[str, float]:
        """``{key: estimated cost}`` of every run (:func:`run_cost`)."""
        return {k: run_cost(self.preset, s) for k, s in zip(self.keys, self.runs)}


def plan_sweep(preset: Preset | str, seeds: Iterable[int], solvers: SolverSettings | None = None) -> SweepPlan:
    """Plan every run of a preset for the given seeds and solver settings.

    Parameters
    ----------
    preset : Preset or str
    seeds : iterable of int
        Distinct seeds >= 0.
    solvers : SolverSettings, optional
        Default: the preset's (``preset.solvers``); see :meth:`SolverSettings.with_overrides`
        to change some of them.

    Returns
    -------
    SweepPlan
    """
    preset = get_preset(preset)
    seeds = [check_int(s, "seed", minimum=0) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValidationError(f"seeds must be a non-empty list of distinct integers; got {list(seeds)!r}")
    solvers = preset.solvers if solvers is None else solvers
    if not isinstance(solvers, SolverSettings):
        raise ValidationError(f"solvers must be a SolverSettings; got {solvers!r}")
    runs = tuple(sorted(RunSpec(n, m, s, solvers) for (n, m) in preset.points() for s in seeds))
    lineup = get_lineup(preset.lineup)
    return SweepPlan(preset, lineup, solvers, tuple(seeds), runs, tuple(s.key(preset) for s in runs),
                     tuple(substitutions(lineup, preset, solvers)))


def plan_runs(preset: Preset | str, seeds: Iterable[int], solvers: SolverSettings | None = None) -> list[RunSpec]:
    """Every run of a preset for the given seeds and solver settings, sorted (:func:`plan_sweep`'s runs)."""
    return list(plan_sweep(preset, seeds, solvers).runs)


def run_cost(preset: Preset, spec: RunSpec) -> float:
    """A run's estimated cost, in relative units (the progress bar's weight of the run).

    Batched Q* evaluations times (tasks in the batch + 20, a per-batch overhead), summed over the
    learners of the paper's line-up, times the number of states: the factorial fits (about
    ``2 x 2 x inner_steps`` evaluations per outer iteration) dominate, so a run with 100 training
    tasks weighs about 3 runs with 5. Only ratios between the runs of one sweep matter.
    """
    train = (3 * preset.flat_max_iter + 4 * preset.fact_max_iter * preset.inner_steps) * (spec.n_tasks + 20)
    test = (4 * preset.flat_max_iter + preset.transfer_max_iter) * (preset.n_test_tasks + 20)
    return float((train + test) * preset.grid_size ** 2)


def _values(mdp, rewards, planner):
    """Optimal value functions V*(s) = max_a Q*(s, a) of a batch of rewards, (n, S)."""
    Q, _ = optimal_q(mdp, rewards, planner=planner)
    return Q.max(axis=-1)


def run_one(preset: Preset, spec: RunSpec, progress: Callable[[str], Any] | None = None,
            reuse: dict | None = None) -> dict[str, Any]:
    """Execute one run: build and score every learner of the preset's line-up.

    Parameters
    ----------
    preset : Preset
    spec : RunSpec
    progress : callable, optional
        Called with the learner's label (e.g. ``"train: flat"``) before each fit.
    reuse : dict, optional
        Fits of the line-up's ``per_seed`` rows (:class:`.learners.Learner`), shared by the
        runs of one sweep: a row whose fit is there (same preset fingerprint, seed, learner and
        builder version) is scored without refitting (its timing is that of the fit that made
        it), and a new one is added. The record is the same as without it.

    Returns
    -------
    record : dict
        ``key``, ``spec``, ``preset``, ``rows`` (result rows), ``timings`` and, for the default
        point's first seed, ``figure3`` (value functions of 4 test tasks).
    """
    with limit_blas_threads(1), warnings.catch_warnings():
        warnings.simplefilter("ignore", MaxIterWarning)  # the presets' budgets are fixed, as the paper's
        return _run_one(preset, spec, progress or (lambda label: None), reuse)


#: per-seed fits kept by a worker process for the runs it executes (see :func:`_run_in_worker`)
_WORKER_FITS: collections.OrderedDict = collections.OrderedDict()
#: per-seed fits a worker keeps (the most recent; a sweep's runs of one seed share them)
WORKER_FITS_KEPT = 16


def _run_in_worker(preset, spec):
    """:func:`run_one` in a worker process, re-using that process's per-seed fits."""
    record = run_one(preset, spec, reuse=_WORKER_FITS)
    while len(_WORKER_FITS) > WORKER_FITS_KEPT:
        _WORKER_FITS.popitem(last=False)
    return record


def _build(learner, gt, preset, ctx, reuse):
    """``(fit, seconds, cpu_seconds)`` of one row: built, or a per-seed fit from ``reuse``.

    ``seconds`` is wall time; ``cpu_seconds`` the CPU time of this process (``time.process_time``:
    every thread of it, no child process), which other load on the machine changes less.
    """
    key = (preset.fingerprint(), ctx.spec.seed, learner.split, learner.name, learner.version)
    if reuse is not None and learner.per_seed and key in reuse:
        return reuse[key]
    t0, c0 = time.perf_counter(), time.process_time()
    fit = learner.build(gt, preset, ctx)
    built = (fit, time.perf_counter() - t0, time.process_time() - c0)
    if reuse is not None and learner.per_seed:
        reuse[key] = built
    return built


def _run_one(preset, spec, progress, reuse):
    gt = make_ground_truth(preset, spec.n_tasks, spec.demos_per_task, spec.seed)
    lineup = get_lineup(preset.lineup)
    ctx = RunContext(gt, spec)
    common = dict(n_tasks=spec.n_tasks, demos_per_task=spec.demos_per_task, seed=spec.seed, h_solver=spec.solver_label())
    rows, timings, fits = [], [], {}
    for learner in lineup.learners:
        progress(f"{learner.split}: {learner.name}")
        ctx.learner = learner
        fit, elapsed, cpu = _build(learner, gt, preset, ctx, reuse)
        dev, extra = (gt.scores(learner.split, fit.rewards, preset.planner) if hasattr(gt, "scores")  # BabyAI: in the env
                      else (deviation(gt.mdps(learner.split), gt.rewards(learner.split), fit.rewards, planner=preset.planner), {}))
        head = dict(split=learner.split, learner=learner.name, **common)
        if learner.adaptive:  # what the validation chose (in the run records, not the CSV tables)
            model = ctx.models[learner.name]
            extra = dict(extra, n_primitives=int(model.n_primitives_), residual_penalty=float(model.residual_penalty_))
        rows.append(dict(head, n_scored_tasks=len(dev), deviation=float(np.mean(dev)), deviation_std=float(np.std(dev)),
                         loss=float(np.mean(fit.loss)), n_evaluations=int(fit.n_evaluations), **extra))
        timings.append(dict(head, fit_time=elapsed, fit_cpu_time=cpu))
        ctx.rewards[learner.split, learner.name], fits[learner.split, learner.name] = fit.rewards, fit
    if gt.task_maps:  # a map per task: the learnt weights are scored on fresh maps too
        add_new_map_scores(gt, preset, fits, rows)
    record = dict(key=spec.key(preset), spec=spec.to_dict(), preset=preset.to_dict(), rows=rows, timings=timings)
    if (spec.n_tasks, spec.demos_per_task) == (preset.default_tasks, preset.default_demos) and lineup.value_maps:
        record["figure3"] = _figure3(gt, preset, spec, ctx, lineup.value_maps)
    return record


def _figure3(gt, preset, spec, ctx, names):
    """Value functions of the first test tasks: the truth and the ``names`` test learners'."""
    j = slice(0, N_FIGURE3_TASKS)
    true, learnt = gt.test_rewards[j], {name: ctx.rewards["test", name][j] for name in names}
    planner = preset.planner
    fig = dict(grid_size=preset.grid_size, seed=spec.seed, true=_values(gt.mdp, true, planner).tolist())
    fig.update({name: _values(gt.mdp, R, planner).tolist() for name, R in learnt.items()})
    fig["demos"] = [d[0].tolist() for d in gt.test_demos[j]]
    fig.update(gt.map_extras)
    fig.update({f"deviation_{name}": deviation(gt.mdp, true, R, planner=planner).tolist() for name, R in learnt.items()})
    return fig


# --- execution -------------------------------------------------------------------------------


@dataclasses.dataclass(frozen=True)
class Execution:
    """Where and how many runs execute at a time.

    Parameters
    ----------
    jobs : int
        Runs executed at the same time; -1 uses every core.
    backend : {"processes", "dask"}
        ``"processes"``: :mod:`.workers` (when ``jobs > 1``). ``"dask"`` connects to
        ``scheduler`` (an address such as ``tcp://host:8786``) or, without one, starts a local
        cluster of ``jobs`` workers. ``"loky"`` is accepted for ``"processes"``.
    scheduler : str, optional
    """

    jobs: int = 1
    backend: str = "processes"
    scheduler: str | None = None

    def __post_init__(self) -> None:
        jobs, backend = self.jobs, "processes" if self.backend == "loky" else self.backend
        if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs == 0 or jobs < -1:
            raise ValidationError(f"jobs must be a positive integer or -1 (every core); got {jobs!r}")
        if backend not in BACKENDS:
            raise ValidationError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
        if self.scheduler is not None and backend != "dask":
            raise ValidationError("a scheduler address is only used with backend 'dask'")
        object.__setattr__(self, "jobs", (os.cpu_count() or 1) if jobs == -1 else int(jobs))
        object.__setattr__(self, "backend", backend)


def _dask_records(preset, todo, jobs, scheduler):
    """Yield run records as runs finish on a Dask cluster (``scheduler``, or a local one)."""
    import joblib

    try:
        from distributed import Client, LocalCluster
    except ImportError:
        raise ValidationError("--backend dask needs dask[distributed]: pip install 'factirl-opt[dask]'") from None
    cluster = None
    if scheduler is None:
        cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=True, dashboard_address=None)
    client = Client(cluster if cluster is not None else scheduler)
    try:
        with joblib.parallel_config(backend="dask"):
            calls = (joblib.delayed(_run_in_worker)(preset, spec) for spec in todo)
            yield from joblib.Parallel(n_jobs=jobs, return_as="generator_unordered")(calls)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _show(bar: Any, key: str, label: str) -> None:
    """Show the run and the learner being fitted on the progress bar."""
    bar.set_postfix_str(f"{key} | {label}", refresh=True)


def _execute(preset: Preset, todo: list, execution: Execution, bar: Any) -> Generator[dict, None, None]:
    """Yield run records as runs finish: in this process, in worker processes, or on Dask."""
    if execution.backend == "dask":
        yield from _dask_records(preset, todo, execution.jobs, execution.scheduler)
    elif execution.jobs == 1:
        reuse: dict = {}  # this sweep's per-seed fits
        for spec in todo:
            yield run_one(preset, spec, progress=functools.partial(_show, bar, spec.key(preset)), reuse=reuse)
    else:
        yield from imap_unordered(_run_in_worker, [(preset, spec) for spec in todo], execution.jobs)


def prepare_out(out: str | os.PathLike) -> str:
    """Create the output directory (and its ``runs/``); returns its path.

    Raises
    ------
    PersistenceError
        If ``out`` is a file, or the directory cannot be created (naming the path and the cause).
    """
    out = os.fspath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise PersistenceError(f"output directory {out!r} exists and is not a directory; choose another --out")
    try:
        os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    except OSError as exc:
        raise os_error(exc, "create the output directory", exc.filename or out) from exc
    return out


def remove_derived_outputs(out: str) -> list[str]:
    """Remove the claims and figures drawn from earlier tables (:data:`DERIVED_OUTPUTS`); returns their paths."""
    removed = []
    for name in DERIVED_OUTPUTS:
        path = os.path.join(out, name)
        try:
            os.unlink(path)
        except FileNotFoundError:
            continue
        except OSError as exc:
            raise os_error(exc, "remove the stale output", path) from exc
        removed.append(path)
    return removed


# --- the sweep -------------------------------------------------------------------------------


def run_plan(plan: SweepPlan, out: str | os.PathLike, execution: Execution = Execution(), progress: bool = True,
             command: str | None = None) -> dict[str, Any]:
    """Execute (or resume) a planned sweep into ``out``: the runs, the store, the tables.

    Parameters
    ----------
    plan : SweepPlan
        From :func:`plan_sweep`.
    out : str or path
        Output directory (created; locked while the sweep writes). Finished runs found in
        ``out/runs`` are reused if they pass the store's checks (:mod:`.store`), else reported
        and recomputed. The runs to compute start costliest first (:func:`run_cost`), so an
        interrupted sweep has its largest points, and ``--jobs`` workers finish together.
        Claims and figures of earlier tables are removed (:data:`DERIVED_OUTPUTS`).
    execution : Execution
    progress : bool
        Show a tqdm progress bar on stderr, its ETA weighted by :func:`run_cost`.
    command : str, optional
        Recorded in the manifest.

    Returns
    -------
    dict
        ``rows`` (result rows), ``timings`` (the records' timing rows: ``fit_time`` in wall
        seconds and, in records written since it was added, ``fit_cpu_time``, the CPU seconds of
        the process that built the fit), ``n_runs``, ``n_computed`` (runs computed by this call),
        ``rejected`` (``{file: reason}`` of the cached records rejected), ``wall_time``,
        ``out``, ``substitutions`` (the plan's) and ``removed`` (stale outputs removed).

    Raises
    ------
    store.OutputLockedError
        If another live sweep is writing to ``out``.
    PersistenceError
        If ``out`` is a file or cannot be written.
    """
    t0 = time.perf_counter()
    for note in plan.substitutions:
        warnings.warn(note, SolverSubstitutionWarning, stacklevel=2)
    out = prepare_out(out)
    invocation = store.new_invocation(command, dict(plan.solvers.to_dict(), jobs=execution.jobs, backend=execution.backend,
                                                    seeds=list(plan.seeds), substitutions=list(plan.substitutions)))
    with store.locked(out), sigterm_raises():
        records, n_computed, rejected = _resume(plan, out, execution, progress, invocation["id"])
        ordered = [records[k] for k in plan.keys]
        rows = write_tables(out, ordered)
        removed = remove_derived_outputs(out)
        wall = time.perf_counter() - t0
        invocation.update(n_runs=len(plan.runs), n_computed=n_computed, n_reused=len(plan.runs) - n_computed,
                          n_rejected=len(rejected), wall_time_seconds=round(wall, 1),
                          finished_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        store.write_manifest(out, plan.preset, plan.lineup, ordered, invocation, rejected)
    return dict(rows=rows, timings=[t for rec in ordered for t in rec["timings"]], n_runs=len(plan.runs),
                n_computed=n_computed, rejected=rejected, wall_time=wall, out=out,
                substitutions=list(plan.substitutions), removed=removed)


def run_sweep(preset: Preset | str, out: str | os.PathLike, seeds: int | None = None, base_seed: int = 0, jobs: int = 1,
              solvers: SolverSettings | None = None, backend: str = "processes", scheduler: str | None = None,
              progress: bool = True, command: str | None = None) -> dict[str, Any]:
    """Run (or resume) every run of a preset into ``out`` and write the tables.

    :func:`plan_sweep` then :func:`run_plan` with ``Execution(jobs, backend, scheduler)``.

    Parameters
    ----------
    preset : Preset or str
    out, progress, command
        See :func:`run_plan` (which gives the returned dict).
    seeds : int, optional
        Number of seeds (default: the preset's); seeds are ``base_seed, base_seed + 1, ...``.
    base_seed : int
    jobs, backend, scheduler
        See :class:`Execution`.
    solvers : SolverSettings, optional
        The factorial learner's solvers; default: the preset's.
    """
    preset = get_preset(preset)
    n_seeds = preset.n_seeds if seeds is None else check_int(seeds, "seeds", minimum=1)
    base_seed = check_int(base_seed, "base seed", minimum=0)
    execution = Execution(jobs, backend, scheduler)
    plan = plan_sweep(preset, range(base_seed, base_seed + n_seeds), solvers)
    return run_plan(plan, out, execution, progress=progress, command=command)


def _resume(plan: SweepPlan, out: str, execution: Execution, progress: bool, invocation_id: str):
    """Load the reusable records, compute the others; returns (records by key, n computed, rejected)."""
    expected = store.expected_provenance(plan.preset, plan.lineup)
    runs_dir = os.path.join(out, "runs")
    by_key = dict(zip(plan.keys, plan.runs))
    records, todo_keys, rejected = store.load_records(runs_dir, list(plan.keys), expected, plan.lineup)
    costs = plan.costs()
    # costliest first: the default point's runs start at once, and the small runs fill the
    # workers at the end (longest-processing-time order); records do not depend on the order
    todo = sorted((by_key[k] for k in todo_keys), key=lambda s: -costs[s.key(plan.preset)])
    from tqdm.auto import tqdm

    n = len(plan.runs)
    bar = tqdm(total=sum(costs.values()), initial=sum(costs[k] for k in records), desc=f"{plan.preset.name}",
               file=sys.stderr, disable=not progress, dynamic_ncols=True, smoothing=0,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]{postfix}")
    try:
        bar.set_postfix_str(f"{len(records)}/{n} runs done; {len(todo)} to run on {execution.jobs} "
                            f"{'worker' if execution.jobs == 1 else 'workers'}", refresh=True)
        with contextlib.closing(_execute(plan.preset, todo, execution, bar)) as finished:
            for rec in finished:
                rec = store.seal(rec, expected, invocation_id)
                store.write_record(runs_dir, rec)
                records[rec["key"]] = rec
                bar.update(costs[rec["key"]])
                bar.set_postfix_str(f"{len(records)}/{n} runs done; last {rec['key']}", refresh=True)
    finally:
        bar.close()
    return records, len(todo), rejected
