#!/bin/sh
# bench active, requested and random starts, seed 0, both worlds: the library as committed (transfer_stol=0)
# and a copy of it with FactIRL's default transfer_stol set to TRANSFER_STOL (the one-line flip), side by side.
# usage (from the worktree root): sh results/transfer/active/run.sh FLIPPED_COPY_ROOT
# (each run from its library's root: `python -m` puts the working directory first on sys.path)
out=$PWD/results/transfer/active
for w in grid objectworld-per-task-quick; do
  OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python -m factirl_opt.lab.bench active --worlds $w --seeds 0 \
    --strategies requested random > $out/$w-stol0.json
  (cd $1 && OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$1 python -m factirl_opt.lab.bench active --worlds $w \
    --seeds 0 --strategies requested random) > $out/$w-stol1e-3.json
done
