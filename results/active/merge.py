"""Merge one-seed runs of ``bench active`` into one file, as one run of the seeds would write it.

Usage: python results/active/merge.py OUT.json RUN_SEED0.json RUN_SEED1.json ...

Each seed's row depends on its seed only (the ground truth, the model's ``rng`` and the
demonstrations' generator, ``demonstration_rng``, are seeded by it), so running the seeds in
separate processes gives the rows one process would; the settings are the first run's with the
seeds of every run.
"""

import json
import os
import sys
import tempfile


def main(out, paths):
    runs = [json.load(open(p)) for p in paths]
    merged = {"settings": dict(runs[0]["settings"]), "worlds": {}}
    merged["settings"]["seeds"] = []
    for run in runs:
        other = {k: v for k, v in run["settings"].items() if k != "seeds"}
        if other != {k: v for k, v in merged["settings"].items() if k != "seeds"}:
            raise SystemExit(f"settings differ: {other} against {merged['settings']}")
        merged["settings"]["seeds"] += run["settings"]["seeds"]
        for name, rows in run["worlds"].items():
            for seed, row in rows.items():
                if seed in merged["worlds"].setdefault(name, {}):
                    raise SystemExit(f"seed {seed} of {name} twice")
                merged["worlds"][name][seed] = row
    fd, tmp = tempfile.mkstemp(dir=os.path.dirname(os.path.abspath(out)) or ".")
    with os.fdopen(fd, "w") as f:
        json.dump(merged, f, indent=2)
        f.write("\n")
    os.replace(tmp, out)


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
