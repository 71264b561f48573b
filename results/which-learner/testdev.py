"""Test deviation of fixed (k, lambda) candidates fitted on all training tasks of a which-learner point and
transferred to its test tasks from one demonstration: python testdev.py PRESET N SEED OUT.json "k,lam" ..."""
import json, os, sys
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from _point import setup, test_deviation
P = setup(sys.argv[1:5])
out = {}
for spec in sys.argv[5:]:
    k, lam = spec.split(","); k, lam = int(k), float(lam)
    dev = test_deviation(P, k, lam)
    out[spec] = dev
    print(spec, dev, flush=True)
    json.dump(out, open(P.out_path, "w"))
