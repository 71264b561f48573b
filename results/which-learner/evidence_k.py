"""Minka's evidence for k on the which-learner points, beside the committed verdicts:
``python results/which-learner/evidence_k.py OUT.json PRESET [PRESET ...]``

For every point of each preset (its ``tasks_sweep``, seeds 0, 1, 2) the point is set up as the
runner does (``_point.setup``: ground truth, the flat fit of the PCA start), and the evidence of
every number of primitives is computed from the matrix the PCA start decomposes
(``learners.evidence.flat_start_evidence``: one SVD, no candidate fit). Each record holds the
evidence's k, the log evidence per k (relative to its maximum), the CPU time of the evidence and
of the flat start (``time.process_time``), the true k (the preset's), and the committed verdict of
the point (``runs/<preset>/``, through the bench's ``benchmark_verdicts``): flat, factorial and
adaptive test scores, the adaptive learner's (k, lambda) and which learner is best. Points already
in OUT.json are skipped (the file is rewritten after each point).
"""
import glob
import json
import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import numpy as np  # noqa: E402

from factirl_opt.files import write_text_atomic  # noqa: E402
from factirl_opt.lab.benchmarks.which_learner import benchmark_verdicts  # noqa: E402
from factirl_opt.lab.experiments import PRESETS  # noqa: E402
from factirl_opt.learners.evidence import flat_start_evidence  # noqa: E402
from _point import setup  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
out_path, presets = sys.argv[1], sys.argv[2:]
out = json.load(open(out_path)) if os.path.exists(out_path) else {"points": []}
done = {(p["preset"], p["n_tasks"], p["seed"]) for p in out["points"]}


def verdicts(preset):
    rows = [r for f in sorted(glob.glob(os.path.join(HERE, "runs", preset, "*.json"))) for r in json.load(open(f))["rows"]]
    found = benchmark_verdicts(rows)
    return found["column"], {(v["n_tasks"], v["seed"]): v for v in found["verdicts"]}


for name in presets:
    column, committed = verdicts(name)
    for n in PRESETS[name].tasks_sweep:
        for seed in (0, 1, 2):
            if (name, n, seed) in done:
                continue
            t0 = time.process_time()
            P = setup([name, str(n), str(seed), os.devnull])
            t_setup = time.process_time() - t0
            t0 = time.process_time()
            log_ev, k = flat_start_evidence(P.tasks, P.flat.rewards_)
            t_ev = time.process_time() - t0
            v = committed.get((n, seed), {})
            winner = None if not v else (min if column == "deviation" else max)(
                ("flat", "factorial"), key=lambda c: v[c])
            rec = {"preset": name, "n_tasks": n, "seed": seed, "true_k": P.preset.n_primitives,
                   "evidence_k": k, "log_evidence_minus_max": [float(e - log_ev.max()) for e in log_ev],
                   "evidence_cpu_s": t_ev, "setup_cpu_s": t_setup, "score": column,
                   "committed": {key: v.get(key) for key in ("flat", "factorial", "adaptive", "n_primitives",
                                                             "residual_penalty", "no_worse", "beats_both")},
                   "better_of_flat_and_factorial": winner}
            out["points"].append(rec)
            print(name, n, seed, "evidence k", k, "committed", rec["committed"], "better", winner, flush=True)
            write_text_atomic(out_path, json.dumps(out, indent=1, default=float))
