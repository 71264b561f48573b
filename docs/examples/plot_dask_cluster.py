"""
A fit on a Dask cluster
=======================

``GradIRL`` and ``FactIRL`` evaluate task shards in parallel: ``fo.Execution(n_jobs=2)`` uses worker processes of
this machine, ``fo.Execution(backend="dask", client=...)`` with a ``dask.distributed.Client`` the workers of a cluster. Each
shard keeps its tasks' MDPs and statistics for the whole fit; only weights go in and losses and
gradients come out, and the results equal the serial fit's to rounding. Here a small local
cluster (threads of this process, ``processes=False``) fits the same model as the serial code;
the two loss curves coincide.
"""

import matplotlib.pyplot as plt
import numpy as np
from dask.distributed import Client, LocalCluster

import factirl_opt as fo

mdp = fo.GridWorld(size=5)
D = fo.random_dictionary(mdp.n_params, 3, rng=0)
R = fo.task_rewards(D, fo.random_coefficients(8, 3, rng=1), mdp.n_states, mdp.n_actions)
demos = fo.sample_demonstrations(mdp, R, n_demos=8, length=8, rng=2)

serial_losses, dask_losses = [], []
serial = fo.FactIRL(n_primitives=3, max_iter=10, start=fo.Start(flat_max_iter=30),
                    execution=fo.Execution(callback=lambda i, loss: serial_losses.append(loss))).fit(mdp, demos)

with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
        Client(cluster) as client:
    on_dask = fo.FactIRL(n_primitives=3, max_iter=10, start=fo.Start(flat_max_iter=30),
                         execution=fo.Execution(backend="dask", client=client,
                                                callback=lambda i, loss: dask_losses.append(loss))).fit(mdp, demos)

print("largest difference of the learnt rewards:", np.abs(serial.rewards_ - on_dask.rewards_).max())

fig, ax = plt.subplots(figsize=(6, 4))
ax.plot(range(1, len(serial_losses) + 1), serial_losses, "o-", label="serial (n_jobs=1)")
ax.plot(range(1, len(dask_losses) + 1), dask_losses, "x--", markersize=10, label="2-worker Dask cluster")
ax.set_xlabel("outer iteration")
ax.set_ylabel("total loss")
ax.set_yscale("log")
ax.legend()
fig.tight_layout()
plt.show()
