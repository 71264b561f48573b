#!/bin/sh
# the flat model's transfer, every world of the benchmark where "auto" keeps it, 3 seeds (from the worktree root)
for p in sharing-grid sharing-objectworld-quick sharing-objectworld-per-task-quick; do for s in 0 1 2; do
  OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python results/transfer/flat_model.py $p $s results/transfer/flat/$p-seed$s.json
done; done
