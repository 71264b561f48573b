"""The flat model's transfer (``FactIRL(n_primitives=1, residual_penalty=0)``, what ``"auto"`` keeps outside
the grid at 20 and 100 tasks) with and without the saturation rule:
``python results/transfer/flat_model.py PRESET SEED OUT.json``.

The model is fitted on the point's 5 training tasks (the flat model's transfer does not read them:
each new task is fitted as the flat learner fits it, from zero), with the line-up's adaptive
options (the flat learner's solver); its test tasks are transferred from their one demonstration
with ``transfer_stol`` 0 (today), 1e-2, 1e-3 and 1e-4. Records per value: each test task's deviation,
the stop reason, the MaxIterWarnings, the CPU time.
"""
import json
import re
import sys
import time
import warnings

import numpy as np

import factirl_opt as fo
from factirl_opt.exceptions import MaxIterWarning
from factirl_opt.lab.experiments import PRESETS, make_ground_truth
from factirl_opt.lab.experiments.learner_solvers import factorial_options

STOLS = (0.0, 1e-2, 1e-3, 1e-4)


def main(name, seed, out_path):
    preset = PRESETS[name]
    gt = make_ground_truth(preset, 5, preset.default_demos, seed)
    if gt.task_maps:
        Ftr, Fte = list(gt.task_maps["train"].features), list(gt.task_maps["test"].features)
    else:
        Ftr, Fte = (None if preset.world == "grid" else gt.features), None
    kw = factorial_options(preset, preset.solvers, adaptive=True, features=Ftr is not None)
    kw.update(n_primitives=1, residual_penalty=0.0)
    kw.pop("sharing_search", None)
    model = fo.FactIRL(rng=0, features=Ftr, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model.fit(gt.mdps("train"), gt.train_demos)
    record = {"preset": name, "seed": seed, "variants": {}}
    for stol in STOLS:
        model.set_params(transfer_stol=stol)
        t0 = time.process_time()
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            model.transfer(gt.mdps("test"), gt.test_demos, features=Fte)
        cpu = time.process_time() - t0
        dev = np.asarray(fo.deviation(gt.mdps("test"), gt.rewards("test"), model.transfer_rewards_, planner=preset.planner))
        hit = re.search(r"(\d+) at max_iter", model.transfer_stop_reason_)
        record["variants"][f"{stol:g}"] = {
            "deviation": dev.tolist(), "mean": float(dev.mean()), "cpu": cpu, "status": model.transfer_status_,
            "reason": model.transfer_stop_reason_, "max_iter_tasks": int(hit.group(1)) if hit else 0,
            "max_iter_warnings": sum(isinstance(w.message, MaxIterWarning) for w in caught)}
        print(name, seed, stol, f"{dev.mean():.3f}", model.transfer_status_, f"{cpu:.2f}s", flush=True)
    with open(out_path, "w") as f:
        json.dump(record, f, indent=1)


if __name__ == "__main__":
    main(sys.argv[1], int(sys.argv[2]), sys.argv[3])
