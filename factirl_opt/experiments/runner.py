"""The one experiment runner: plan the runs of a preset, execute them (in parallel, resumably),
and write tidy tables.

A *run* is one ``(n_tasks, demos_per_task, seed)`` point of a preset: generate the ground truth
(:func:`.ground_truth.make_ground_truth`), fit every learner on the training tasks (figure 1),
transfer to the test tasks (figure 2), and score every learner by the mean deviation
(:func:`factirl_opt.deviation`) over the run's tasks.

Learners, named as in the paper:

train tasks (``split = "train"``)
    ``flat`` (GradIRL, tabular); ``flat, ground truth`` (GradIRL with the true dictionary as
    features); ``flat, PCA features`` (GradIRL with the first ``n_pca_components`` components
    of the uncentred PCA of the flat rewards); ``factorial`` (FactIRL initialised by that PCA,
    the paper's heuristic, reusing the flat rewards); ``factorial, random init``.
test tasks (``split = "test"``, one demonstration each)
    ``flat`` (from scratch); ``factorial`` (``FactIRL.transfer`` with the dictionary learnt by
    ``factorial``); ``flat, features from ex.`` (GradIRL with ``n_features_from_examples``
    learnt flat training rewards, chosen at random, as features); ``flat, PCA features`` (the
    training PCA components); ``flat, ground truth`` (the floor).

Output directory layout::

    OUT/runs/<key>.json   one file per finished run (written atomically: tmp + os.replace)
    OUT/results.csv       one row per (run, split, learner); deterministic columns only
    OUT/summary.csv       mean and standard deviation over seeds per (split, learner, point)
    OUT/timings.csv       fit time of every learner in every run (varies from run to run)
    OUT/figure3.json      value functions of 4 test tasks (default point, first seed)
    OUT/manifest.json     preset, seeds, solver, versions, command, wall time

A rerun into the same directory loads the finished runs and computes only the missing ones, so
an interrupted sweep loses at most the runs in flight; tables are sorted, and every run is
single-threaded with its own random streams, so they are identical whatever ``--jobs`` is.
"""

import csv
import dataclasses
import json
import os
import platform
import sys
import tempfile
import time

import numpy as np

import solvers

from ..evaluation import deviation
from ..exceptions import ValidationError, translate_solver_errors
from ..factirl import FactIRL, pca_dictionary
from ..gradirl import GradIRL
from ..planning import optimal_q
from .._threads import limit_blas_threads
from .ground_truth import make_ground_truth
from .presets import Preset, get_preset

__all__ = [
    "RunSpec",
    "TRAIN_LEARNERS",
    "TEST_LEARNERS",
    "RESULT_COLUMNS",
    "plan_runs",
    "run_one",
    "run_sweep",
    "write_tables",
    "read_csv",
]

TRAIN_LEARNERS = ("flat", "flat, ground truth", "flat, PCA features", "factorial", "factorial, random init")
TEST_LEARNERS = ("flat", "factorial", "flat, features from ex.", "flat, PCA features", "flat, ground truth")
SPLITS = ("train", "test")
RESULT_COLUMNS = (
    "split", "learner", "n_tasks", "demos_per_task", "seed", "h_solver",
    "n_scored_tasks", "deviation", "deviation_std", "loss", "n_evaluations",
)
SUMMARY_COLUMNS = ("split", "learner", "n_tasks", "demos_per_task", "h_solver", "n_seeds", "deviation_mean", "deviation_std")
TIMING_COLUMNS = ("split", "learner", "n_tasks", "demos_per_task", "seed", "h_solver", "fit_time")
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


def _check_int(value, name, minimum):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum:
        raise ValidationError(f"{name} must be an integer >= {minimum}; got {value!r}")
    return int(value)


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
    seeds = [_check_int(s, "seed", 0) for s in seeds]
    if not seeds or len(set(seeds)) != len(seeds):
        raise ValidationError(f"seeds must be a non-empty list of distinct integers; got {list(seeds)!r}")
    return sorted(RunSpec(n, m, s, h_solver) for (n, m) in preset.points() for s in seeds)


def _values(mdp, rewards):
    """Optimal value functions V*(s) = max_a Q*(s, a) of a batch of rewards, (n, S)."""
    Q, _ = optimal_q(mdp, rewards)
    return Q.max(axis=-1)


def run_one(preset, spec, progress=None):
    """Execute one run: fit and score every learner.

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
    mdp, D = gt.mdp, gt.dictionary
    S, A = mdp.n_states, mdp.n_actions
    common = dict(n_tasks=spec.n_tasks, demos_per_task=spec.demos_per_task, seed=spec.seed, h_solver=spec.h_solver)
    rows, timings, learnt = [], [], {}

    def fit(split, learner, fn):
        progress(f"{split}: {learner}")
        t0 = time.perf_counter()
        rewards, loss, n_eval = fn()
        elapsed = time.perf_counter() - t0
        true = gt.train_rewards if split == "train" else gt.test_rewards
        dev = deviation(mdp, true, rewards)
        rows.append(dict(split=split, learner=learner, **common, n_scored_tasks=len(dev), deviation=float(np.mean(dev)),
                         deviation_std=float(np.std(dev)), loss=float(np.mean(loss)), n_evaluations=int(n_eval)))
        timings.append(dict(split=split, learner=learner, **common, fit_time=elapsed))
        learnt[split, learner] = rewards

    def gradirl(demos, features=None):
        def fn():
            g = GradIRL(beta=preset.beta, features=features, max_iter=preset.flat_max_iter).fit(mdp, demos)
            return g.rewards_, g.loss_, g.n_evaluations_
        return fn

    k = preset.n_primitives
    fact_kw = dict(n_primitives=k, beta=preset.beta, max_iter=preset.fact_max_iter, inner_steps=preset.inner_steps,
                   h_solver=spec.h_solver, flat_max_iter=preset.flat_max_iter, transfer_max_iter=preset.transfer_max_iter)
    pca_rng, random_init_rng, examples_rng = gt.learner_rng.spawn(3)

    # --- training tasks (figure 1)
    fit("train", "flat", gradirl(gt.train_demos))
    flat_train = learnt["train", "flat"]
    fit("train", "flat, ground truth", gradirl(gt.train_demos, D))
    D_pca, _ = pca_dictionary(flat_train.reshape(spec.n_tasks, S * A), min(preset.n_pca_components, S * A), rng=pca_rng)
    fit("train", "flat, PCA features", gradirl(gt.train_demos, D_pca))
    factorial = FactIRL(init="pca", rng=pca_rng, **fact_kw)

    def fit_factorial():
        factorial.fit(mdp, gt.train_demos, flat_rewards=flat_train)
        return factorial.rewards_, factorial.loss_, factorial.n_evaluations_

    fit("train", "factorial", fit_factorial)

    def fit_random():
        f = FactIRL(init="random", rng=random_init_rng, **fact_kw).fit(mdp, gt.train_demos)
        return f.rewards_, f.loss_, f.n_evaluations_

    fit("train", "factorial, random init", fit_random)

    # --- test tasks, one demonstration each (figure 2)
    fit("test", "flat", gradirl(gt.test_demos))

    def transfer():
        factorial.transfer(mdp, gt.test_demos)
        return factorial.transfer_rewards_, factorial.transfer_loss_, factorial.transfer_n_evaluations_

    fit("test", "factorial", transfer)
    n_ex = min(preset.n_features_from_examples, spec.n_tasks)
    chosen = np.sort(examples_rng.choice(spec.n_tasks, size=n_ex, replace=False))
    fit("test", "flat, features from ex.", gradirl(gt.test_demos, flat_train[chosen].reshape(n_ex, S * A).T))
    fit("test", "flat, PCA features", gradirl(gt.test_demos, D_pca))
    fit("test", "flat, ground truth", gradirl(gt.test_demos, D))

    record = dict(key=spec.key(preset), spec=dataclasses.asdict(spec), preset=preset.to_dict(), rows=rows, timings=timings)
    if (spec.n_tasks, spec.demos_per_task) == (preset.default_tasks, preset.default_demos):
        j = slice(0, N_FIGURE3_TASKS)
        record["figure3"] = dict(
            grid_size=preset.grid_size,
            seed=spec.seed,
            true=_values(mdp, gt.test_rewards[j]).tolist(),
            flat=_values(mdp, learnt["test", "flat"][j]).tolist(),
            factorial=_values(mdp, learnt["test", "factorial"][j]).tolist(),
            demos=[d[0].tolist() for d in gt.test_demos[j]],
            deviation_flat=deviation(mdp, gt.test_rewards[j], learnt["test", "flat"][j]).tolist(),
            deviation_factorial=deviation(mdp, gt.test_rewards[j], learnt["test", "factorial"][j]).tolist(),
        )
    return record


def _atomic_write(path, text):
    d = os.path.dirname(path) or "."
    fd, tmp = tempfile.mkstemp(dir=d, prefix=".tmp-", suffix=os.path.basename(path))
    try:
        with os.fdopen(fd, "w", newline="") as fh:
            fh.write(text)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def _load_record(path, key):
    """A finished run's record, or None if the file is missing, truncated or another run's."""
    try:
        with open(path) as fh:
            rec = json.load(fh)
    except (OSError, ValueError):
        return None
    return rec if isinstance(rec, dict) and rec.get("key") == key and "rows" in rec else None


def _csv_text(rows, columns):
    import io

    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), lineterminator="\n", extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({c: repr(r[c]) if isinstance(r[c], float) else r[c] for c in columns})
    return buf.getvalue()


def read_csv(path):
    """Rows of a table written by the runner, with numbers parsed back."""
    out = []
    with open(path, newline="") as fh:
        for r in csv.DictReader(fh):
            for c, v in r.items():
                if c in ("n_tasks", "demos_per_task", "seed", "n_scored_tasks", "n_evaluations", "n_seeds"):
                    r[c] = int(v)
                elif c in ("deviation", "deviation_std", "loss", "fit_time", "deviation_mean"):
                    r[c] = float(v)
            out.append(r)
    return out


def _order(row):
    learners = TRAIN_LEARNERS if row["split"] == "train" else TEST_LEARNERS
    return (SPLITS.index(row["split"]), row["h_solver"], row["n_tasks"], row["demos_per_task"],
            learners.index(row["learner"]), row.get("seed", 0))


def write_tables(out, records):
    """Write results.csv, summary.csv, timings.csv (and figure3.json) from run records.

    Rows are sorted (split, solver, n_tasks, demos_per_task, learner, seed), so the tables depend
    only on the set of records, not on the order runs finished in.
    """
    rows = sorted((r for rec in records for r in rec["rows"]), key=_order)
    timings = sorted((r for rec in records for r in rec["timings"]), key=_order)
    groups = {}
    for r in rows:
        groups.setdefault((r["split"], r["learner"], r["n_tasks"], r["demos_per_task"], r["h_solver"]), []).append(r["deviation"])
    summary = [
        dict(split=s, learner=lr, n_tasks=n, demos_per_task=m, h_solver=h, n_seeds=len(v),
             deviation_mean=float(np.mean(v)), deviation_std=float(np.std(v, ddof=1)) if len(v) > 1 else 0.0)
        for (s, lr, n, m, h), v in groups.items()
    ]
    summary.sort(key=_order)
    _atomic_write(os.path.join(out, "results.csv"), _csv_text(rows, RESULT_COLUMNS))
    _atomic_write(os.path.join(out, "summary.csv"), _csv_text(summary, SUMMARY_COLUMNS))
    _atomic_write(os.path.join(out, "timings.csv"), _csv_text(timings, TIMING_COLUMNS))
    fig3 = sorted((rec for rec in records if "figure3" in rec), key=lambda rec: (rec["spec"]["h_solver"], rec["spec"]["seed"]))
    if fig3:
        _atomic_write(os.path.join(out, "figure3.json"), json.dumps(fig3[0]["figure3"]))
    return rows


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


def _execute(preset, todo, jobs, backend, scheduler, bar):
    """Yield run records as runs finish (sequentially, or through joblib)."""
    if jobs == 1 and backend == "loky":
        for spec in todo:
            key = spec.key(preset)
            yield run_one(preset, spec, progress=lambda label, key=key: bar.set_postfix_str(f"{key} | {label}", refresh=True))
        return
    import joblib

    calls = (joblib.delayed(run_one)(preset, spec) for spec in todo)
    if backend == "dask":
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
                yield from joblib.Parallel(n_jobs=jobs, return_as="generator_unordered")(calls)
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
    else:
        yield from joblib.Parallel(n_jobs=jobs, backend="loky", return_as="generator_unordered")(calls)


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
    from tqdm.auto import tqdm

    t0 = time.perf_counter()
    preset = get_preset(preset)
    n_seeds = preset.n_seeds if seeds is None else _check_int(seeds, "seeds", 1)
    base_seed = _check_int(base_seed, "base seed", 0)
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs == 0 or jobs < -1:
        raise ValidationError(f"jobs must be a positive integer or -1 (every core); got {jobs!r}")
    if backend not in ("loky", "dask"):
        raise ValidationError(f"backend must be 'loky' or 'dask'; got {backend!r}")
    if scheduler is not None and backend != "dask":
        raise ValidationError("a scheduler address is only used with backend 'dask'")
    if jobs == -1:
        jobs = os.cpu_count() or 1
    h_solver = _check_h_solver(h_solver)
    seeds_list = list(range(base_seed, base_seed + n_seeds))
    specs = plan_runs(preset, seeds_list, h_solver)
    out = os.fspath(out)
    if os.path.exists(out) and not os.path.isdir(out):
        raise ValidationError(f"output directory {out!r} exists and is not a directory")
    runs_dir = os.path.join(out, "runs")
    os.makedirs(runs_dir, exist_ok=True)

    records, todo = {}, []
    for spec in specs:
        key = spec.key(preset)
        rec = _load_record(os.path.join(runs_dir, key + ".json"), key)
        if rec is None:
            todo.append(spec)
        else:
            records[key] = rec
    bar = tqdm(total=len(specs), initial=len(records), desc=f"{preset.name} runs", unit="run", file=sys.stderr,
               disable=not progress, dynamic_ncols=True)
    try:
        if todo and jobs > 1:
            bar.set_postfix_str(f"{len(todo)} to run on {jobs} {backend} workers", refresh=True)
        for rec in _execute(preset, todo, jobs, backend, scheduler, bar):
            _atomic_write(os.path.join(runs_dir, rec["key"] + ".json"), json.dumps(rec))
            records[rec["key"]] = rec
            bar.update(1)
            bar.set_postfix_str(f"done {rec['key']}", refresh=True)
    finally:
        bar.close()
    ordered = [records[s.key(preset)] for s in specs]
    rows = write_tables(out, ordered)
    wall = time.perf_counter() - t0
    manifest = dict(
        preset=preset.to_dict(), seeds=seeds_list, h_solver=h_solver, jobs=jobs, backend=backend,
        command=command, n_runs=len(specs), n_computed=len(todo), wall_time_seconds=round(wall, 1),
        cpu_count=os.cpu_count(), platform=platform.platform(), versions=_versions(),
        finished_utc=time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    )
    _atomic_write(os.path.join(out, "manifest.json"), json.dumps(manifest, indent=2) + "\n")
    return dict(rows=rows, n_runs=len(specs), n_computed=len(todo), wall_time=wall, out=out)


def load_preset_from_manifest(out):
    """The :class:`Preset` recorded in ``out/manifest.json``."""
    path = os.path.join(os.fspath(out), "manifest.json")
    try:
        with open(path) as fh:
            return Preset.from_dict(json.load(fh)["preset"])
    except (OSError, ValueError, KeyError) as exc:
        raise ValidationError(f"{path} is missing or unreadable ({exc}); run `factirl-opt reproduce --out DIR` first") from None
