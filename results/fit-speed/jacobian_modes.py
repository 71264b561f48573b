"""CPU time of the policy-matching residual Jacobian in forward and reverse mode, by the number of
residual rows at visited states, side by side in one process:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/fit-speed/jacobian_modes.py [OUT.json]

Six tasks of the ``sharing-objectworld-quick`` preset (one 16x16 map, seed 0; p = 105 state
features on every action), each from its first 1, 2, 4, 8 or 16 demonstrations, at random feature
weights: ``fo.objectives.residual_jacobian(..., mode=...)`` (the forward point included, the same
in both modes), median of 5 calls per mode. ``rows`` is the batch's residual rows at visited
states per task (the largest number of visited states of a task times A), the reverse mode's
right-hand sides; forward mode solves with p. ``"auto"`` takes reverse mode where rows < p.
"""
import json
import statistics
import sys
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.lab.experiments import PRESETS, make_ground_truth


def main(argv):
    warnings.simplefilter("ignore")
    preset = PRESETS["sharing-objectworld-quick"]
    gt = make_ground_truth(preset, 20, preset.default_demos, 0)
    mdp = gt.mdps("train")
    F = np.repeat(np.asarray(gt.features), mdp.n_actions, axis=0)  # state features on every action
    rng = np.random.default_rng(0)
    out = {"point": "sharing-objectworld-quick, 20 tasks, seed 0, tasks 0-5", "p": int(F.shape[1]), "rows": []}
    for n_demos in (1, 2, 4, 8, 16):
        mu, pi_hat = fo.empirical_statistics(mdp, [d[:n_demos] for d in gt.train_demos[:6]])
        R = 0.1 * (F @ rng.normal(size=(F.shape[1], 6))).T.reshape(6, mdp.n_states, mdp.n_actions)
        times = {"forward": [], "reverse": []}
        for _ in range(5):
            for mode in times:
                t0 = time.process_time()
                fo.objectives.residual_jacobian(mdp, R, mu, pi_hat, preset.beta, F, mode=mode)
                times[mode].append(time.process_time() - t0)
        row = {"demonstrations": n_demos, "rows": int((mu > 0).sum(axis=1).max() * mdp.n_actions),
               **{f"{mode}_cpu_s": statistics.median(v) for mode, v in times.items()}}
        out["rows"].append(row)
        print(row, flush=True)
    if argv:
        with open(argv[0], "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1:])
