"""The user guide's table "Choosing an objective": policy matching against maximum causal entropy
on the paper's grid at its default point, one seed, in one process.

``fo.GridWorld(10)``, beta 5, k = 5; 100 training tasks x 10 demonstrations of 10 steps
(``fo.synthetic_tasks(mdp, 100, 10, 10, rng=0)``) and 100 test tasks from the same dictionary
with one demonstration each (``rng=1``). Per objective: GradIRL with its defaults on the
training tasks and, from scratch, on the test tasks; FactIRL, the paper's algorithm
(``**fo.PAPER_SETTINGS`` with ``gtol=1e-4``), from the PCA of the flat training rewards, then
its transfer to the test tasks. Writes the mean deviations (eq. 13), the fits' planning
evaluations and their CPU times (``time.process_time``, one BLAS thread) as JSON on stdout:

    OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 python results/objectives/objectives_table.py > results/objectives/objectives_table.json
"""

import json
import time
import warnings

import factirl_opt as fo

mdp = fo.GridWorld(10)
train = fo.synthetic_tasks(mdp, 100, 10, 10, rng=0)
test = fo.synthetic_tasks(mdp, 100, 1, 10, dictionary=train.dictionary, rng=1)
out = {"setting": {"grid": 10, "train": "synthetic_tasks(mdp, 100, 10, 10, rng=0)",
                   "test": "synthetic_tasks(mdp, 100, 1, 10, dictionary=train.dictionary, rng=1)",
                   "factirl": "FactIRL(n_primitives=5, objective=obj, rng=0, **PAPER_SETTINGS, gtol=1e-4)"},
       "objectives": {}}
for obj in ("policy-matching", "mce"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", fo.exceptions.ConvergenceWarning)
        t0 = time.process_time()
        flat = fo.GradIRL(objective=obj).fit(mdp, train.demos)
        flat_cpu = time.process_time() - t0
        t0 = time.process_time()
        fact = fo.FactIRL(n_primitives=5, objective=obj, rng=0, **{**fo.PAPER_SETTINGS, "gtol": 1e-4}).fit(
            mdp, train.demos, flat_rewards=flat.rewards_)
        fact_cpu = time.process_time() - t0
        fact.transfer(mdp, test.demos)
        flat_test = fo.GradIRL(objective=obj).fit(mdp, test.demos)
    out["objectives"][obj] = {
        "flat_train_deviation": float(fo.deviation(mdp, train.rewards, flat.rewards_).mean()),
        "factorial_train_deviation": float(fo.deviation(mdp, train.rewards, fact.rewards_).mean()),
        "flat_test_deviation": float(fo.deviation(mdp, test.rewards, flat_test.rewards_).mean()),
        "factorial_test_deviation": float(fo.deviation(mdp, test.rewards, fact.transfer_rewards_).mean()),
        "flat_fit": {"evaluations": int(flat.n_evaluations_), "cpu_s": flat_cpu, "n_iter": int(flat.n_iter_)},
        "factorial_fit": {"evaluations": int(fact.n_evaluations_), "cpu_s": fact_cpu, "n_iter": int(fact.n_iter_),
                          "stop_reason": str(fact.stop_reason_)},
    }
print(json.dumps(out, indent=1))
