"""The held-out fit in a fresh process, no warm-up: the 100-task 32x32 Objectworld FactIRL fit on
features of ``bench scale --fit-iter 3`` (fixed budget), in the order given, e.g. ``1,2,dask,1,2,dask``
(n_jobs=1, n_jobs=2, a 2-worker Dask LocalCluster): the first sharded fit pays for the fork server
unless it was started early (third argument ``prestart``: factirl_opt.parallel.start_shard_server()
at the program's start). Prints per fit: configuration, wall s, this process's CPU s, finished
children's CPU s (0 for fork-server children), final loss.

    PYTHONPATH=$PWD python results/shard-speedup/first_fit.py 1,2,dask,1,2,dask 3 [prestart]
"""
import argparse, os, sys, time, resource, warnings, json
import numpy as np
warnings.simplefilter("ignore")
from factirl_opt.lab.benchmarks import scale
from factirl_opt.parallel import limit_blas_threads

def cpu():
    a = resource.getrusage(resource.RUSAGE_SELF); b = resource.getrusage(resource.RUSAGE_CHILDREN)
    return a.ru_utime + a.ru_stime, b.ru_utime + b.ru_stime

if __name__ == "__main__":
    order = sys.argv[1].split(",")  # e.g. 1,2,2,1,2
    fit_iter = int(sys.argv[2]) if len(sys.argv) > 2 else 3
    if len(sys.argv) > 3 and sys.argv[3] == "prestart":
        from factirl_opt.parallel import start_shard_server
        print("prestart", start_shard_server(), flush=True)
    args = argparse.Namespace(seed=0, tasks=100, n_demos=10, length=10, beta=5.0, fit_iter=fit_iter)
    with limit_blas_threads(1):
        p = scale.fit_problem(32, args)
        client = None
        out = []
        for j in order:
            if j == "dask" and client is None:
                from distributed import Client, LocalCluster
                cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None)
                client = Client(cluster)
                client.run(lambda: __import__("factirl_opt"))
            extra = dict(backend="dask", client=client) if j == "dask" else dict(n_jobs=int(j))
            m = scale.fit_model(args, p["features"], **extra)
            c0 = cpu(); t0 = time.perf_counter()
            m.fit(p["mdp"], p["demos"])
            w = time.perf_counter() - t0; c1 = cpu()
            out.append((j, round(w, 2), round(c1[0] - c0[0], 2), round(c1[1] - c0[1], 2), float(m.loss_history_[-1])))
            print(*out[-1], flush=True)
        print("load", os.getloadavg())
        if client is not None:
            client.close(); cluster.close()
