#!/bin/sh
# usage: sh results/transfer/run_points.sh PRESET "N..." "SEED..."  (from the worktree root)
for n in $2; do for s in $3; do
  out=results/transfer/points/$1-n$n-seed$s.json
  [ -f $out ] && continue
  OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 PYTHONPATH=$PWD python results/transfer/points.py $1 $n $s $out > results/transfer/points/$1-n$n-seed$s.log 2>&1
done; done
