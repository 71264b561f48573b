"""The defaults study: ``FactIRL`` fitted from scratch, as a user calls it, with each named setting
of ``candidates.json`` (the settings the presets tune), on one benchmark world, both objectives.

One process fits, for each ``--objectives`` entry and each ``--candidates`` name (in that
order, ``--repeats`` times, alternating), ``FactIRL(n_primitives=k, features=<the world's>,
objective=..., rng=seed + 1, **settings)`` on the training tasks, then transfers it
(``FactIRL.transfer``, the setting's H-step solver) to the world's test tasks (one demonstration
each, on maps never seen where the world has a map per task). A Gauss-Newton solver named by a
setting is replaced by L-BFGS for MCE (``learner_solvers.factorial_solvers``, as the harness does).

Worlds (``SCENARIO``):

``walled-maps``
    The issue's acceptance draw: ``--n-tasks`` (12) tasks, each on its own ``--size`` (24) square
    Objectworld map with ``--n-blocked`` (30) blocked cells, ``--n-demos`` (24) demonstrations
    of ``--length`` (16) steps, k = 5, the maps' state features
    (``results/fit-speed/walled_maps.py``); test tasks: ``--n-test`` new walled maps
    (``draw`` at ``seed + 1000``), one demonstration each. Runs unchanged on older code
    (commit e87d706) for the ``defaults`` setting.
``per-task``
    ``bench mce``'s draw (``objectworld-per-task`` at 32x32: ``objectworld_per_task``), its
    ``--n-test`` test tasks on maps of their own.
``grid``
    The paper's world (``paper`` preset: 10x10 noisy grid, tabular rewards, k = 5).
``objectworld``
    ELIRL's Objectworld on one 32x32 map (``objectworld`` preset), its discrete state features.
``babyai``
    BabyAI-GoToLocal-v0 (``babyai`` preset, k = 8), a layout per task, scored by the success
    rate of the learnt policies in the environment (``success_rate``) and the deviation.

Prints one JSON line per fit as it ends (and appends it to ``--out``): CPU time of the fit
(``time.process_time``; run with one BLAS thread; its user and system parts, the minor page
faults, and the process's peak resident size after it, from ``getrusage``), evaluations, outer iterations, status, final
loss, mean train deviation (eq. 13), the transfer's CPU time, evaluations and the warnings it
raised, the mean test deviation and the per-task test deviations (for paired comparisons).

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python results/defaults/defaults_study.py \
        walled-maps --candidates defaults joint-2 --out results/defaults/walled_maps.jsonl
"""

import argparse
import dataclasses
import json
import os
import resource
import sys
import time
import warnings

import numpy as np

import factirl_opt as fo

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "fit-speed"))

#: the worlds, with their default sizes (tasks, demonstrations per task, test tasks)
SCENARIOS = {"walled-maps": (12, 24, 24), "per-task": (30, 32, 30), "grid": (100, 10, 100), "objectworld": (20, 32, 50),
             "babyai": (30, 4, 100)}


def load_candidates():
    with open(os.path.join(HERE, "candidates.json")) as f:
        return json.load(f)


@dataclasses.dataclass
class World:
    """What a fit and its transfer need: ``fit_args``/``transfer_args`` for ``fit``/``transfer``,
    ``features`` for the constructor, ``k`` and ``score(split, rewards) -> (deviations, extra)``."""
    fit_args: tuple
    transfer_args: tuple
    transfer_kwargs: dict
    features: object
    k: int
    beta: float
    score: object
    digest: str


def _digest(demos):
    """A digest of the demonstrations (arrays, or lists of episodes of different lengths)."""
    import hashlib
    h = hashlib.sha256()

    def add(d):
        try:
            h.update(np.ascontiguousarray(d, dtype=np.int64).tobytes())
        except ValueError:  # episodes of different lengths
            for e in d:
                add(e)

    for d in demos:
        add(d)
    return h.hexdigest()[:12]


def walled_maps_world(args):
    from walled_maps import draw
    train = argparse.Namespace(size=args.size, n_tasks=args.n_tasks, n_demos=args.n_demos, length=args.length,
                               n_blocked=args.n_blocked, seed=args.seed, label="")
    preset, maps, mdps, R, demos = draw(train)
    rewards, transfer_args, transfer_kwargs = {"train": (mdps, R)}, (), {}
    if args.n_test:
        test = argparse.Namespace(**dict(vars(train), n_tasks=args.n_test, n_demos=1, seed=args.seed + 1000))
        _, tmaps, tmdps, tR, tdemos = draw(test)
        rewards["test"] = (tmdps, tR)
        transfer_args, transfer_kwargs = (tmdps, tdemos), dict(features=list(tmaps.features))

    def score(split, learnt):
        m, true = rewards[split]
        return fo.deviation(m, true, np.asarray(learnt), planner=preset.planner), {}

    return World((mdps, demos), transfer_args, transfer_kwargs, list(maps.features),
                 preset.n_primitives, preset.beta, score, _digest(demos))


def _lab_world(name, args):
    from factirl_opt.lab.experiments.presets import get_preset
    from factirl_opt.lab.experiments import worlds
    preset_name = {"per-task": "objectworld-per-task", "grid": "paper", "objectworld": "objectworld", "babyai": "babyai"}[name]
    preset = dataclasses.replace(get_preset(preset_name), n_test_tasks=args.n_test)
    gt = worlds.make_ground_truth(preset, args.n_tasks, args.n_demos, args.seed)
    if name == "babyai":
        def score(split, learnt):
            dev, extra = gt.scores(split, list(learnt), planner=preset.planner)
            return dev, extra
        return World((gt.mdps("train"), gt.train_demos), (gt.mdps("test"), gt.test_demos),
                     dict(features=gt.features("test")), gt.features("train"), preset.n_primitives, preset.beta, score,
                     _digest(gt.train_demos))

    def score(split, learnt):
        return fo.deviation(gt.mdps(split), gt.rewards(split), np.asarray(learnt), planner=preset.planner), {}

    if name == "per-task":
        return World((gt.mdps("train"), gt.train_demos), (gt.mdps("test"), gt.test_demos),
                     dict(features=list(gt.task_maps["test"].features)), list(gt.task_maps["train"].features),
                     preset.n_primitives, preset.beta, score, _digest(gt.train_demos))
    return World((gt.mdp, gt.train_demos), (gt.mdp, gt.test_demos), {}, gt.features, preset.n_primitives, preset.beta,
                 score, _digest(gt.train_demos))


def settings_for(settings, objective):
    """The setting's keyword arguments for ``objective``: Gauss-Newton H/D solvers become L-BFGS for MCE."""
    kw = dict(settings)
    if objective != "policy-matching" and ("solver" in kw or "d_solver" in kw):
        from factirl_opt.lab.experiments.learner_solvers import factorial_solvers
        used, _ = factorial_solvers(fo.SolverSettings(kw.get("solver", "armijo"), d_solver=kw.get("d_solver", "armijo")),
                                    objective)
        kw["solver"], kw["d_solver"] = used.h_solver, used.d_solver
    return kw


def fit_and_transfer(world, name, settings, objective, seed, n_test):
    kw = settings_for(settings, objective)
    model = fo.FactIRL(world.k, world.beta, features=world.features, objective=objective, rng=seed + 1, **kw)
    with warnings.catch_warnings(record=True) as fit_warnings:
        warnings.simplefilter("always")
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        c0 = time.process_time()
        model.fit(*world.fit_args)
        cpu = time.process_time() - c0
        r1 = resource.getrusage(resource.RUSAGE_SELF)
    train_dev, train_extra = world.score("train", model.rewards_)
    entry = dict(candidate=name, objective=objective, settings=kw, cpu_s=round(cpu, 3),
                 user_s=round(r1.ru_utime - r0.ru_utime, 3), sys_s=round(r1.ru_stime - r0.ru_stime, 3),
                 page_faults=r1.ru_minflt - r0.ru_minflt, process_peak_rss_mb=round(r1.ru_maxrss / 1024),
                 n_evaluations=int(model.n_evaluations_), n_iter=int(model.n_iter_), status=str(model.status_),
                 final_loss=float(np.sum(model.loss_)), mean_train_deviation=float(np.mean(train_dev)),
                 fit_warnings=sorted({type(w.message).__name__ for w in fit_warnings}),
                 **{"train_" + key: value for key, value in train_extra.items()})
    if n_test:
        mdps, demos = world.transfer_args
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            c0 = time.process_time()
            model.transfer(mdps, demos, **world.transfer_kwargs)
            tcpu = time.process_time() - c0
        dev, extra = world.score("test", model.transfer_rewards_)
        names = [type(w.message).__name__ for w in caught]
        entry.update(transfer_cpu_s=round(tcpu, 3), transfer_n_evaluations=int(model.transfer_n_evaluations_),
                     transfer_warnings={n: names.count(n) for n in sorted(set(names))},
                     mean_test_deviation=float(np.mean(dev)), test_deviations=[round(float(d), 5) for d in dev], **extra)
    return entry


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenario", choices=sorted(SCENARIOS))
    parser.add_argument("--candidates", nargs="+", default=["defaults"])
    parser.add_argument("--objectives", nargs="+", default=["policy-matching", "mce"])
    parser.add_argument("--n-tasks", type=int)
    parser.add_argument("--n-demos", type=int)
    parser.add_argument("--n-test", type=int)
    parser.add_argument("--size", type=int, default=24, help="walled-maps: map side")
    parser.add_argument("--length", type=int, default=16, help="walled-maps: steps per demonstration")
    parser.add_argument("--n-blocked", type=int, default=30, help="walled-maps: blocked cells per map")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--label", default="")
    parser.add_argument("--out", help="JSON lines appended here, one per fit")
    args = parser.parse_args(argv)
    n, m, t = SCENARIOS[args.scenario]
    args.n_tasks = n if args.n_tasks is None else args.n_tasks
    args.n_demos = m if args.n_demos is None else args.n_demos
    args.n_test = t if args.n_test is None else args.n_test
    table = load_candidates()
    unknown = [c for c in args.candidates if c not in table]
    if unknown:
        parser.error(f"unknown candidates {unknown}; known: {', '.join(table)}")
    world = walled_maps_world(args) if args.scenario == "walled-maps" else _lab_world(args.scenario, args)
    import subprocess
    try:
        commit = subprocess.run(["git", "-C", os.path.dirname(os.path.dirname(os.path.abspath(fo.__file__))), "rev-parse",
                                 "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    except OSError:
        commit = ""
    for repeat in range(args.repeats):
        for objective in args.objectives:
            for name in args.candidates:
                entry = fit_and_transfer(world, name, table[name]["settings"], objective, args.seed,
                                         args.n_test if repeat == 0 else 0)
                entry = dict(scenario=args.scenario, label=args.label, code=commit, seed=args.seed, repeat=repeat,
                             n_tasks=args.n_tasks, n_demos=args.n_demos, n_test=args.n_test, demos_digest=world.digest,
                             blas_threads=os.environ.get("OPENBLAS_NUM_THREADS"), **entry)
                line = json.dumps(entry)
                print(line, flush=True)
                if args.out:
                    with open(args.out, "a") as f:
                        f.write(line + "\n")


if __name__ == "__main__":
    main()
