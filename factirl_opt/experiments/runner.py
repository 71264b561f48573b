"""The one experiment runner: plan the runs of a preset and execute them (in parallel, resumably).

A *run* is one ``(n_tasks, demos_per_task, seed)`` point of a preset with the factorial
learner's solver settings: generate the ground truth in the preset's world
(:func:`.worlds.make_ground_truth`), build every learner of the preset's line-up
(:mod:`.learners`: fits on the training tasks, figure 1; transfers to the test tasks, figure 2),
and score each by the mean deviation (:func:`factirl_opt.deviation`) over the run's tasks.

Output directory layout::

    OUT/runs/<key>.json   one record per finished run, checked before reuse (:mod:`.store`)
    OUT/results.csv, summary.csv, timings.csv, figure3.json   (:mod:`.tables`)
    OUT/manifest.json     every run of the tables and every invocation (:mod:`.store`)
    OUT/.lock             while a sweep writes (a second one is refused)

A rerun into the same directory reuses the finished runs and computes only the missing (or
rejected) ones, so an interrupted sweep loses at most the runs in flight; tables are sorted, and
every run is single-threaded with its own random streams, so they are identical whatever
``--jobs`` is. Runs execute in this process (``jobs=1``), in worker processes that never outlive
it (:mod:`.workers`), or on a Dask cluster.
"""

import collections
import contextlib
import dataclasses
import hashlib
import os
import sys
import time

import numpy as np

from .._threads import limit_blas_threads
from .._validation import check_int
from ..evaluation import deviation
from ..exceptions import ValidationError
from ..planning import optimal_q
from . import store
from .learners import RunContext, decode_options, get_lineup, solver_settings
from .presets import get_preset
from .tables import write_tables
from .workers import imap_unordered, sigterm_raises
from .worlds import make_ground_truth

__all__ = ["RunSpec", "BACKENDS", "solver_settings", "plan_runs", "run_cost", "run_one", "run_sweep"]

#: test tasks whose value functions figure 3 shows
N_FIGURE3_TASKS = 4
#: execution backends (``"loky"`` is accepted as the former name of ``"processes"``)
BACKENDS = ("processes", "dask")


@dataclasses.dataclass(frozen=True, order=True)
class RunSpec:
    """One run: a point of the sweeps, a seed, the factorial learner's solver settings.

    ``h_solver_options`` and ``d_solver_options`` are canonical JSON (``""``: none);
    ``d_solver`` is ``""`` for FactIRL's default D-step. Build specs with :func:`plan_runs`.
    """

    n_tasks: int
    demos_per_task: int
    seed: int
    h_solver: str = "armijo"
    h_solver_options: str = ""
    d_solver: str = ""
    d_solver_options: str = ""

    def h_options(self):
        """The H-step solver's options, a dict."""
        return decode_options(self.h_solver_options)

    def d_options(self):
        """The D-step solver's options, a dict."""
        return decode_options(self.d_solver_options)

    def solver_label(self):
        """The ``h_solver`` column of the tables: the H-step solver's name, then its options and
        the D-step solver when they differ from the defaults (e.g. ``gn-qp-osqp-sparse {"alpha":0.03}``)."""
        label = " ".join(x for x in (self.h_solver, self.h_solver_options) if x)
        if self.d_solver:
            label += " | d: " + " ".join(x for x in (self.d_solver, self.d_solver_options) if x)
        return label

    def key(self, preset):
        """File stem of the run, unique per preset configuration (fingerprint) and solver settings."""
        extra = (self.h_solver_options, self.d_solver, self.d_solver_options)
        tag = self.h_solver + (f"-{hashlib.sha256(repr(extra).encode()).hexdigest()[:8]}" if any(extra) else "")
        return f"n{self.n_tasks:03d}-m{self.demos_per_task:02d}-seed{self.seed}-{tag}-{preset.fingerprint()}"


def _with_preset_solvers(preset, h_solver, h_solver_options, d_solver, d_solver_options):
    """The solver settings of a call, the preset's where the call names none.

    A solver not named (None) is the preset's, with the given options or else the preset's; a
    named solver takes only the options given with it.
    """
    if h_solver is None:
        h_solver = preset.h_solver
        h_solver_options = preset.h_options() if h_solver_options is None else h_solver_options
    if d_solver is None and preset.d_solver:
        d_solver = preset.d_solver
        d_solver_options = preset.d_options() if d_solver_options is None else d_solver_options
    return h_solver, h_solver_options, d_solver, d_solver_options


def plan_runs(preset, seeds, h_solver=None, h_solver_options=None, d_solver=None, d_solver_options=None):
    """Every run of a preset for the given seeds and solver settings, sorted.

    Parameters
    ----------
    preset : Preset or str
    seeds : sequence of int
    h_solver, h_solver_options, d_solver, d_solver_options
        See :func:`.learners.solver_settings`; a solver left None is the preset's (with the
        options given, or else the preset's).

    Returns
    -------
    list of RunSpec
    """
    preset = get_preset(preset)
    seeds = [check_int(s, "seed", minimum=0) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValidationError(f"seeds must be a non-empty list of distinct integers; got {list(seeds)!r}")
    settings = solver_settings(*_with_preset_solvers(preset, h_solver, h_solver_options, d_solver, d_solver_options))
    return sorted(RunSpec(n, m, s, **settings) for (n, m) in preset.points() for s in seeds)


def run_cost(preset, spec):
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


def run_one(preset, spec, progress=None, reuse=None):
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
    with limit_blas_threads(1):
        return _run_one(preset, spec, progress or (lambda label: None), reuse)


#: per-seed fits kept by a worker process for the runs it executes (see :func:`_run_in_worker`)
_WORKER_FITS = collections.OrderedDict()
#: per-seed fits a worker keeps (the most recent; a sweep's runs of one seed share them)
WORKER_FITS_KEPT = 16


def _run_in_worker(preset, spec):
    """:func:`run_one` in a worker process, re-using that process's per-seed fits."""
    record = run_one(preset, spec, reuse=_WORKER_FITS)
    while len(_WORKER_FITS) > WORKER_FITS_KEPT:
        _WORKER_FITS.popitem(last=False)
    return record


def _build(learner, gt, preset, ctx, reuse):
    """``(fit, seconds)`` of one row: built, or a per-seed fit from ``reuse``."""
    key = (preset.fingerprint(), ctx.spec.seed, learner.split, learner.name, learner.version)
    if reuse is not None and learner.per_seed and key in reuse:
        return reuse[key]
    t0 = time.perf_counter()
    fit = learner.build(gt, preset, ctx)
    built = (fit, time.perf_counter() - t0)
    if reuse is not None and learner.per_seed:
        reuse[key] = built
    return built


def _run_one(preset, spec, progress, reuse):
    gt = make_ground_truth(preset, spec.n_tasks, spec.demos_per_task, spec.seed)
    lineup = get_lineup(preset.lineup)
    ctx = RunContext(gt, spec)
    common = dict(n_tasks=spec.n_tasks, demos_per_task=spec.demos_per_task, seed=spec.seed, h_solver=spec.solver_label())
    rows, timings = [], []
    for learner in lineup.learners:
        progress(f"{learner.split}: {learner.name}")
        ctx.split = learner.split
        fit, elapsed = _build(learner, gt, preset, ctx, reuse)
        dev = deviation(gt.mdp, gt.rewards(learner.split), fit.rewards, planner=preset.planner)
        head = dict(split=learner.split, learner=learner.name, **common)
        rows.append(dict(head, n_scored_tasks=len(dev), deviation=float(np.mean(dev)), deviation_std=float(np.std(dev)),
                         loss=float(np.mean(fit.loss)), n_evaluations=int(fit.n_evaluations)))
        timings.append(dict(head, fit_time=elapsed))
        ctx.rewards[learner.split, learner.name] = fit.rewards
    record = dict(key=spec.key(preset), spec=dataclasses.asdict(spec), preset=preset.to_dict(), rows=rows, timings=timings)
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


def _execute(preset, todo, execution, bar):
    """Yield run records as runs finish: in this process, in worker processes, or on Dask."""
    if execution["backend"] == "dask":
        yield from _dask_records(preset, todo, execution["jobs"], execution["scheduler"])
    elif execution["jobs"] == 1:
        reuse = {}  # this sweep's per-seed fits
        for spec in todo:
            key = spec.key(preset)
            yield run_one(preset, spec, progress=lambda label, key=key: bar.set_postfix_str(f"{key} | {label}", refresh=True),
                          reuse=reuse)
    else:
        yield from imap_unordered(_run_in_worker, [(preset, spec) for spec in todo], execution["jobs"])


def _check_execution(jobs, backend, scheduler):
    """Validate the execution options; returns ``dict(jobs, backend, scheduler)``."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs == 0 or jobs < -1:
        raise ValidationError(f"jobs must be a positive integer or -1 (every core); got {jobs!r}")
    backend = "processes" if backend == "loky" else backend
    if backend not in BACKENDS:
        raise ValidationError(f"backend must be one of {', '.join(BACKENDS)}; got {backend!r}")
    if scheduler is not None and backend != "dask":
        raise ValidationError("a scheduler address is only used with backend 'dask'")
    return dict(jobs=(os.cpu_count() or 1) if jobs == -1 else int(jobs), backend=backend, scheduler=scheduler)


def _prepare_out(out):
    out = os.fspath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValidationError(f"output directory {out!r} exists and is not a directory")
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    return out


def run_sweep(preset, out, seeds=None, base_seed=0, jobs=1, h_solver=None, h_solver_options=None, d_solver=None,
              d_solver_options=None, backend="processes", scheduler=None, progress=True, command=None):
    """Run (or resume) every run of a preset into ``out`` and write the tables.

    Parameters
    ----------
    preset : Preset or str
    out : str or path
        Output directory (created; locked while the sweep writes). Finished runs found in
        ``out/runs`` are reused if they pass the store's checks (:mod:`.store`), else reported
        and recomputed. The runs to compute start costliest first (:func:`run_cost`), so an
        interrupted sweep has its largest points, and ``--jobs`` workers finish together.
    seeds : int, optional
        Number of seeds (default: the preset's); seeds are ``base_seed, base_seed + 1, ...``.
    base_seed : int
    jobs : int
        Runs executed at the same time; -1 uses every core.
    h_solver : str, optional
        H-step solver of the factorial learner (a name in ``solvers.available_solvers()``);
        default: the preset's (``preset.h_solver``).
    h_solver_options : dict, optional
        Its options (e.g. ``{"alpha": 0.03}`` for a sparse solver); default: none for a named
        solver, the preset's for the preset's solver.
    d_solver : str, optional
        D-step solver of the factorial learner; default: the preset's (``preset.d_solver``, or
        FactIRL's default when the preset names none).
    d_solver_options : dict, optional
    backend : {"processes", "dask"}
        ``"processes"``: :mod:`.workers` (when ``jobs > 1``). ``"dask"`` connects to
        ``scheduler`` (an address such as ``tcp://host:8786``) or, without one, starts a local
        cluster of ``jobs`` workers. ``"loky"`` is accepted for ``"processes"``.
    scheduler : str, optional
    progress : bool
        Show a tqdm progress bar on stderr, its ETA weighted by :func:`run_cost`.
    command : str, optional
        Recorded in the manifest.

    Returns
    -------
    dict
        ``rows`` (result rows), ``n_runs``, ``n_computed`` (runs computed by this call),
        ``rejected`` (``{file: reason}`` of the cached records rejected), ``wall_time``, ``out``.

    Raises
    ------
    store.OutputLockedError
        If another live sweep is writing to ``out``.
    """
    t0 = time.perf_counter()
    preset = get_preset(preset)
    n_seeds = preset.n_seeds if seeds is None else check_int(seeds, "seeds", minimum=1)
    base_seed = check_int(base_seed, "base seed", minimum=0)
    execution = _check_execution(jobs, backend, scheduler)
    specs = plan_runs(preset, range(base_seed, base_seed + n_seeds), h_solver, h_solver_options, d_solver, d_solver_options)
    out = _prepare_out(out)
    invocation = store.new_invocation(command, dict(_solver_fields(specs[0]), jobs=execution["jobs"], backend=execution["backend"],
                                                    seeds=list(range(base_seed, base_seed + n_seeds))))
    with store.locked(out), sigterm_raises():
        records, n_computed, rejected = _resume(preset, specs, out, execution, progress, invocation["id"])
        ordered = [records[s.key(preset)] for s in specs]
        rows = write_tables(out, ordered)
        wall = time.perf_counter() - t0
        invocation.update(n_runs=len(specs), n_computed=n_computed, n_reused=len(specs) - n_computed,
                          n_rejected=len(rejected), wall_time_seconds=round(wall, 1),
                          finished_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()))
        store.write_manifest(out, preset, get_lineup(preset.lineup), ordered, invocation, rejected)
    return dict(rows=rows, n_runs=len(specs), n_computed=n_computed, rejected=rejected, wall_time=wall, out=out)


def _solver_fields(spec):
    """The solver settings of a run, as plain values for the manifest."""
    return dict(h_solver=spec.h_solver, h_solver_options=spec.h_options(), d_solver=spec.d_solver or None,
                d_solver_options=spec.d_options())


def _resume(preset, specs, out, execution, progress, invocation_id):
    """Load the reusable records, compute the others; returns (records by key, n computed, rejected)."""
    lineup = get_lineup(preset.lineup)
    expected = store.expected_provenance(preset, lineup)
    runs_dir = os.path.join(out, "runs")
    by_key = {s.key(preset): s for s in specs}
    records, todo_keys, rejected = store.load_records(runs_dir, list(by_key), expected, lineup)
    costs = {s.key(preset): run_cost(preset, s) for s in specs}
    # costliest first: the default point's runs start at once, and the small runs fill the
    # workers at the end (longest-processing-time order); records do not depend on the order
    todo = sorted((by_key[k] for k in todo_keys), key=lambda s: -costs[s.key(preset)])
    from tqdm.auto import tqdm

    bar = tqdm(total=sum(costs.values()), initial=sum(costs[k] for k in records), desc=f"{preset.name}",
               file=sys.stderr, disable=not progress, dynamic_ncols=True, smoothing=0,
               bar_format="{desc}: {percentage:3.0f}%|{bar}| [{elapsed}<{remaining}]{postfix}")
    try:
        bar.set_postfix_str(f"{len(records)}/{len(specs)} runs done; {len(todo)} to run on {execution['jobs']} "
                            f"{'worker' if execution['jobs'] == 1 else 'workers'}", refresh=True)
        with contextlib.closing(_execute(preset, todo, execution, bar)) as finished:
            for rec in finished:
                rec = store.seal(rec, expected, invocation_id)
                store.write_record(runs_dir, rec)
                records[rec["key"]] = rec
                bar.update(costs[rec["key"]])
                bar.set_postfix_str(f"{len(records)}/{len(specs)} runs done; last {rec['key']}", refresh=True)
    finally:
        bar.close()
    return records, len(todo), rejected
