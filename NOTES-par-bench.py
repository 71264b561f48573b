"""Side-by-side timing of a 100-task 32x32 Objectworld FactIRL fit: n_jobs=1, n_jobs=2, 2-worker LocalCluster.

Usage: PYTHONPATH=$PWD python NOTES-par-bench.py 1,2,dask REPEATS   (a note for the lead, not part of the package)
"""
import sys, time, pickle, numpy as np
from factirl_opt.experiments.presets import get_preset
from factirl_opt.experiments.worlds import make_ground_truth

def build(n_tasks=100, size=32, demos=32, seed=0):
    import dataclasses
    preset = dataclasses.replace(get_preset("objectworld"), grid_size=size)
    gt = make_ground_truth(preset, n_tasks, demos, seed)
    return gt

def kwargs(max_iter=3):
    return dict(n_primitives=5, init="random", rng=0, max_iter=max_iter, inner_steps=2, tol=0.0, gtol=0.0,
                h_solver="gn-qp-clarabel", d_solver="lbfgs")
import sys, time, resource, numpy as np
import psutil
def cpu():
    a=resource.getrusage(resource.RUSAGE_SELF); b=resource.getrusage(resource.RUSAGE_CHILDREN)
    alive = 0.0
    for ch in psutil.Process().children(recursive=True):
        try:
            t = ch.cpu_times(); alive += t.user + t.system
        except psutil.Error:
            pass
    return np.array([a.ru_utime+a.ru_stime, b.ru_utime+b.ru_stime + alive])
import factirl_opt as fo
from factirl_opt.objectives import distributed as dist
STATS = {}
_close = dist.ShardedObjective.close
def close(self):
    STATS['bytes'] = self.shards.bytes_sent; STATS['evals'] = self.n_evaluations; STATS['setup'] = self.shards.bytes_setup
    _close(self)
dist.ShardedObjective.close = close
def main():
    gt = build()
    fo.FactIRL(features=gt.features, **kwargs(1)).fit(gt.mdp, gt.train_demos[:3])  # import cvxpy once
    configs = sys.argv[1].split(",") if len(sys.argv) > 1 else ["1", "2"]
    reps = int(sys.argv[2]) if len(sys.argv) > 2 else 2
    client = None
    if "dask" in configs:
        from distributed import Client, LocalCluster
        cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
        client = Client(cluster)
    times = {c: [] for c in configs}; res = {}
    for r in range(reps):
        for c in configs:
            extra = dict(backend="dask", client=client) if c == "dask" else dict(n_jobs=int(c))
            m = fo.FactIRL(features=gt.features, **kwargs(3), **extra)
            t = time.perf_counter(); c0 = cpu(); m.fit(gt.mdp, gt.train_demos); times[c].append(time.perf_counter() - t); cp = cpu() - c0
            res[c] = m
            print(c, r, 'wall', round(times[c][-1], 2), 'cpu driver/workers', np.round(cp, 2), m.n_evaluations_, open('/proc/loadavg').read().split()[0], STATS if c != '1' else '', flush=True)
    ref = res[configs[0]]
    for c in configs:
        d = max(np.max(abs(res[c].dictionary_ - ref.dictionary_)), np.max(abs(res[c].coefficients_ - ref.coefficients_)))
        print(c, "median", np.median(times[c]), "speed-up", np.median(times[configs[0]]) / np.median(times[c]), "maxdiff", d, "evals", res[c].n_evaluations_)

if __name__ == '__main__':
    main()
