"""The one experiment runner: plan the runs of a preset and execute them (in parallel, resumably).

A *run* is one ``(n_tasks, demos_per_task, seed)`` point of a preset: generate the ground truth
in the preset's world (:func:`.worlds.make_ground_truth`), build every learner of the preset's
line-up (:mod:`.learners`: fits on the training tasks, figure 1; transfers to the test tasks,
figure 2), and score each by the mean deviation (:func:`factirl_opt.deviation`) over the run's
tasks. The tables are written by :mod:`.tables`.

Output directory layout::

    OUT/runs/<key>.json   one file per finished run (written atomically)
    OUT/results.csv, summary.csv, timings.csv, figure3.json   (:mod:`.tables`)
    OUT/manifest.json     preset, seeds, solver, versions, command, wall time

A rerun into the same directory loads the finished runs and computes only the missing ones, so
an interrupted sweep loses at most the runs in flight; tables are sorted, and every run is
single-threaded with its own random streams, so they are identical whatever ``--jobs`` is.
"""

import dataclasses
import json
import os
import platform
import sys
import time

import numpy as np

import solvers

from .._threads import limit_blas_threads
from .._validation import check_int
from ..evaluation import deviation
from ..exceptions import ValidationError, translate_solver_errors
from ..planning import optimal_q
from .learners import RunContext, get_lineup
from .presets import get_preset
from .tables import write_atomic, write_tables
from .worlds import make_ground_truth

__all__ = ["RunSpec", "plan_runs", "run_one", "run_sweep"]

#: test tasks whose value functions figure 3 shows
N_FIGURE3_TASKS = 4


@dataclasses.dataclass(frozen=True, order=True)
class RunSpec:
    """One run: a point of the sweeps, a seed, the factorial learner's H-step solver."""

    n_tasks: int
    demos_per_task: int
    seed: int
    h_solver: str = "armijo"

    def key(self, preset):
        """File stem of the run, unique per preset configuration (fingerprint)."""
        return f"n{self.n_tasks:03d}-m{self.demos_per_task:02d}-seed{self.seed}-{self.h_solver}-{preset.fingerprint()}"


def _check_h_solver(h_solver):
    if not isinstance(h_solver, str) or not h_solver:
        raise ValidationError(f"h_solver must be a registered solver name; got {h_solver!r}")
    with translate_solver_errors():
        solvers.get_solver(h_solver)  # UnknownSolverError lists the available names
    return h_solver


def plan_runs(preset, seeds, h_solver="armijo"):
    """Every run of a preset for the given seeds, sorted.

    Parameters
    ----------
    preset : Preset or str
    seeds : sequence of int
    h_solver : str

    Returns
    -------
    list of RunSpec
    """
    preset = get_preset(preset)
    seeds = [check_int(s, "seed", minimum=0) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValidationError(f"seeds must be a non-empty list of distinct integers; got {list(seeds)!r}")
    return sorted(RunSpec(n, m, s, h_solver) for (n, m) in preset.points() for s in seeds)


def _values(mdp, rewards):
    """Optimal value functions V*(s) = max_a Q*(s, a) of a batch of rewards, (n, S)."""
    Q, _ = optimal_q(mdp, rewards)
    return Q.max(axis=-1)


def run_one(preset, spec, progress=None):
    """Execute one run: build and score every learner of the preset's line-up.

    Parameters
    ----------
    preset : Preset
    spec : RunSpec
    progress : callable, optional
        Called with the learner's label (e.g. ``"train: flat"``) before each fit.

    Returns
    -------
    record : dict
        ``key``, ``spec``, ``preset``, ``rows`` (result rows), ``timings`` and, for the default
        point's first seed, ``figure3`` (value functions of 4 test tasks).
    """
    with limit_blas_threads(1):
        return _run_one(preset, spec, progress or (lambda label: None))


def _run_one(preset, spec, progress):
    gt = make_ground_truth(preset, spec.n_tasks, spec.demos_per_task, spec.seed)
    lineup = get_lineup(preset.lineup)
    ctx = RunContext(gt, spec)
    common = dict(n_tasks=spec.n_tasks, demos_per_task=spec.demos_per_task, seed=spec.seed, h_solver=spec.h_solver)
    rows, timings = [], []
    for learner in lineup.learners:
        progress(f"{learner.split}: {learner.name}")
        ctx.split = learner.split
        t0 = time.perf_counter()
        fit = learner.build(gt, preset, ctx)
        elapsed = time.perf_counter() - t0
        dev = deviation(gt.mdp, gt.rewards(learner.split), fit.rewards)
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
    fig = dict(grid_size=preset.grid_size, seed=spec.seed, true=_values(gt.mdp, true).tolist())
    fig.update({name: _values(gt.mdp, R).tolist() for name, R in learnt.items()})
    fig["demos"] = [d[0].tolist() for d in gt.test_demos[j]]
    fig.update({f"deviation_{name}": deviation(gt.mdp, true, R).tolist() for name, R in learnt.items()})
    return fig


def _load_record(path, key):
    """A finished run's record, or None if the file is missing, truncated or another run's."""
    try:
        with open(path) as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("key") == key and "rows" in rec else None


def _git_commit():
    """The source tree's git commit (``+dirty`` if modified), or None outside a git checkout."""
    import subprocess

    here = os.path.dirname(os.path.abspath(__file__))
    try:
        head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10)
        if head.returncode != 0:
            return None
        dirty = subprocess.run(["git", "status", "--porcelain", "--", "../.."], cwd=here, capture_output=True,
                               text=True, timeout=10).stdout.strip()
        return head.stdout.strip() + ("+dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError):
        return None


def _versions():
    import importlib.metadata as md

    v = {"python": platform.python_version(), "git_commit": _git_commit()}
    for dist in ("numpy", "scipy", "cvxpy", "joblib", "matplotlib", "factirl-opt"):
        try:
            v[dist] = md.version(dist)
        except md.PackageNotFoundError:
            v[dist] = None
    return v


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
            calls = (joblib.delayed(run_one)(preset, spec) for spec in todo)
            yield from joblib.Parallel(n_jobs=jobs, return_as="generator_unordered")(calls)
    finally:
        client.close()
        if cluster is not None:
            cluster.close()


def _execute(preset, todo, jobs, backend, scheduler, bar):
    """Yield run records as runs finish (sequentially, or through joblib)."""
    if backend == "dask":
        yield from _dask_records(preset, todo, jobs, scheduler)
    elif jobs == 1:
        for spec in todo:
            key = spec.key(preset)
            yield run_one(preset, spec, progress=lambda label, key=key: bar.set_postfix_str(f"{key} | {label}", refresh=True))
    else:
        import joblib

        calls = (joblib.delayed(run_one)(preset, spec) for spec in todo)
        yield from joblib.Parallel(n_jobs=jobs, backend="loky", return_as="generator_unordered")(calls)


def _check_sweep_options(preset, seeds, base_seed, jobs, h_solver, backend, scheduler):
    """Validate run_sweep's options; returns (preset, seeds list, jobs, h_solver)."""
    preset = get_preset(preset)
    n_seeds = preset.n_seeds if seeds is None else check_int(seeds, "seeds", minimum=1)
    base_seed = check_int(base_seed, "base seed", minimum=0)
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs == 0 or jobs < -1:
        raise ValidationError(f"jobs must be a positive integer or -1 (every core); got {jobs!r}")
    if backend not in ("loky", "dask"):
        raise ValidationError(f"backend must be 'loky' or 'dask'; got {backend!r}")
    if scheduler is not None and backend != "dask":
        raise ValidationError("a scheduler address is only used with backend 'dask'")
    jobs = (os.cpu_count() or 1) if jobs == -1 else int(jobs)
    return preset, list(range(base_seed, base_seed + n_seeds)), jobs, _check_h_solver(h_solver)


def _prepare_out(out):
    out = os.fspath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValidationError(f"output directory {out!r} exists and is not a directory")
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    return out


def run_sweep(preset, out, seeds=None, base_seed=0, jobs=1, h_solver="armijo", backend="loky", scheduler=None,
              progress=True, command=None):
    """Run (or resume) every run of a preset into ``out`` and write the tables.

    Parameters
    ----------
    preset : Preset or str
    out : str or path
        Output directory (created). Finished runs found in ``out/runs`` are not recomputed.
    seeds : int, optional
        Number of seeds (default: the preset's); seeds are ``base_seed, base_seed + 1, ...``.
    base_seed : int
    jobs : int
        Runs executed at the same time (joblib); -1 uses every core.
    h_solver : str
        H-step solver of the factorial learner (a name in ``solvers.available_solvers()``).
    backend : {"loky", "dask"}
        joblib backend. ``"dask"`` connects to ``scheduler`` (an address such as
        ``tcp://host:8786``) or, without one, starts a local cluster of ``jobs`` workers.
    scheduler : str, optional
    progress : bool
        Show a tqdm progress bar on stderr (current run and learner).
    command : str, optional
        Recorded in the manifest.

    Returns
    -------
    dict
        ``rows`` (result rows), ``n_runs``, ``n_computed`` (runs computed by this call),
        ``wall_time`` and ``out``.
    """
    t0 = time.perf_counter()
    preset, seeds_list, jobs, h_solver = _check_sweep_options(preset, seeds, base_seed, jobs, h_solver, backend, scheduler)
    specs = plan_runs(preset, seeds_list, h_solver)
    out = _prepare_out(out)
    runs_dir = os.path.join(out, "runs")
    records, todo = {}, []
    for spec in specs:
        rec = _load_record(os.path.join(runs_dir, spec.key(preset) + ".json"), spec.key(preset))
        if rec is None:
            todo.append(spec)
        else:
            records[rec["key"]] = rec
    _compute(preset, todo, records, runs_dir, dict(jobs=jobs, backend=backend, scheduler=scheduler), progress, len(specs))
    rows = write_tables(out, [records[s.key(preset)] for s in specs])
    wall = time.perf_counter() - t0
    manifest = dict(
        preset=preset.to_dict(), seeds=seeds_list, h_solver=h_solver, jobs=jobs, backend=backend,
        command=command, n_runs=len(specs), n_computed=len(todo), wall_time_seconds=round(wall, 1),
        cpu_count=os.cpu_count(), platform=platform.platform(), versions=_versions(),
        finished_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    )
    write_atomic(os.path.join(out, "manifest.json"), json.dumps(manifest, indent=2) + "\n")
    return dict(rows=rows, n_runs=len(specs), n_computed=len(todo), wall_time=wall, out=out)


def _compute(preset, todo, records, runs_dir, execution, progress, n_runs):
    """Execute the runs of ``todo``, saving each record as it finishes."""
    from tqdm.auto import tqdm

    bar = tqdm(total=n_runs, initial=len(records), desc=f"{preset.name} runs", unit="run", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    try:
        if todo and execution["jobs"] > 1:
            bar.set_postfix_str(f"{len(todo)} to run on {execution['jobs']} {execution['backend']} workers", refresh=True)
        for rec in _execute(preset, todo, execution["jobs"], execution["backend"], execution["scheduler"], bar):
            write_atomic(os.path.join(runs_dir, rec["key"] + ".json"), json.dumps(rec))
            records[rec["key"]] = rec
            bar.update(1)
            bar.set_postfix_str(f"done {rec['key']}", refresh=True)
    finally:
        bar.close()
