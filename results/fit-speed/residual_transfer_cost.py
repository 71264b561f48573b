"""CPU time of transfers with a finite residual penalty, before and after the residual's
elimination from the Gauss-Newton step and the reverse-mode Jacobian, side by side in one process.

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/residual_transfer_cost.py POINT [REPEATS] [OUT.json]

``POINT`` is ``objectworld`` (the ``sharing-objectworld-quick`` preset at 20 training tasks, seed
0: one 16x16 map, p = 105 features; a FactIRL with the preset's k = 5, solvers and budgets and
``residual_penalty=1.0`` fitted on two thirds of the tasks, then their held-out third transferred
from one demonstration each, as the search of ``FactIRL(n_primitives="auto",
residual_penalty="auto")`` transfers its held-out tasks) or ``readme`` (the README's grid,
:func:`factirl_opt.lab.benchmarks.auto_cost.readme_grid` seed 0: tabular rewards, p = S*A =
500; ``FactIRL(n_primitives=5, residual_penalty=1.0)`` with its defaults fitted on the 30
tasks, its 10 new tasks transferred from one demonstration with ``solver="gn-qp-clarabel"`` as
the README transfers), or ``objectworld-32`` (the ``objectworld`` preset: one 32x32 map with
Levine's p = 217 features, 9 tasks of which 6 train and 3 are transferred, as ``objectworld``).

Each route transfers the same tasks with the same fitted model, ``REPEATS`` times in turn
(default 3; the median CPU time, ``time.process_time``, is reported):

- ``before``: ``GaussNewtonSolver(ridge="stack")`` (the stacked (m + p + k) x (k + p) system
  QR-factored whole) and ``jacobian_mode("forward")`` (p tangent right-hand sides): the code
  before both changes;
- ``eliminate``: the residual eliminated in closed form, forward Jacobian;
- ``eliminate + auto Jacobian``: and the Jacobian in reverse mode where it has fewer rows at
  visited states than columns (the defaults now).

Also recorded: the largest difference of the transferred rewards from ``before``'s, relative to
their largest magnitude, and each route's transfer steps.
"""
import json
import statistics
import sys
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.benchmarks.auto_cost import readme_grid
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options
from factirl_opt.objectives import jacobian_mode

ROUTES = {"before": ("stack", "forward"), "eliminate": ("eliminate", "forward"),
          "eliminate + auto Jacobian": ("eliminate", "auto")}


def objectworld_point(preset_name="sharing-objectworld-quick", n=20):
    """(model, mdp, new demonstrations, transfer kwargs, description) of the Objectworld point."""
    preset = PRESETS[preset_name]
    gt = make_ground_truth(preset, n, preset.default_demos, 0)
    held = np.sort(np.random.default_rng(0).permutation(n)[: n // 3])
    train = np.setdiff1d(np.arange(n), held)
    kw = factorial_options(preset, preset.solvers, features=True)
    model = fo.FactIRL(rng=0, features=gt.features, **{**kw, "residual_penalty": 1.0})
    model.fit(gt.mdps("train"), [gt.train_demos[i] for i in train])
    about = {"point": f"{preset_name}, {n} tasks, seed 0", "train_tasks": train.tolist(),
             "held_out_tasks": held.tolist(), "p": int(np.shape(gt.features)[1]), "solver": model.solver}
    return model, gt.mdps("train"), [gt.train_demos[i][:1] for i in held], {"solver": model.solver}, about


def readme_point():
    """The same for the README's grid (tabular rewards)."""
    gt = readme_grid(0)
    model = fo.FactIRL(n_primitives=5, residual_penalty=1.0, rng=0).fit(gt.mdp, gt.train_demos)
    about = {"point": "README grid (auto_cost.readme_grid seed 0), 30 tasks x 10 demonstrations, 10 new tasks",
             "p": int(gt.mdp.n_params), "solver": "gn-qp-clarabel (transfer)"}
    return model, gt.mdp, gt.test_demos, {"solver": "gn-qp-clarabel"}, about


def main(argv):
    warnings.simplefilter("ignore")
    which = argv[0]
    repeats = int(argv[1]) if len(argv) > 1 else 3
    out_path = argv[2] if len(argv) > 2 else None
    points = {"objectworld": objectworld_point, "readme": readme_point,
              "objectworld-32": lambda: objectworld_point("objectworld", 9)}
    model, mdp, new_demos, kw, about = points[which]()
    out = {**about, "k": int(model.n_primitives_), "residual_penalty": float(model.residual_penalty_), "repeats": repeats,
           "new_tasks": len(new_demos), "routes": {}}
    times = {name: [] for name in ROUTES}
    rewards, steps = {}, {}
    for _ in range(repeats):
        for name, (ridge, mode) in ROUTES.items():
            with jacobian_mode(mode):
                t0 = time.process_time()
                model.transfer(mdp, new_demos, solver_options={"ridge": ridge}, **kw)
                times[name].append(time.process_time() - t0)
            rewards[name] = np.asarray(model.transfer_rewards_)
            steps[name] = len(model.transfer_loss_history_) - 1
    ref = rewards["before"]
    base = statistics.median(times["before"])
    for name in ROUTES:
        cpu = statistics.median(times[name])
        out["routes"][name] = {"cpu_s": cpu, "cpu_s_all": times[name], "speedup": base / cpu, "steps": steps[name],
                               "max_rel_diff_rewards": float(np.max(np.abs(rewards[name] - ref)) / np.max(np.abs(ref)))}
        print(f"{which}: {name:28s} {cpu:7.3f} s CPU  x{base / cpu:5.2f}  steps {steps[name]}  "
              f"max rel. diff {out['routes'][name]['max_rel_diff_rewards']:.1e}", flush=True)
    if out_path:
        with open(out_path, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1:])
