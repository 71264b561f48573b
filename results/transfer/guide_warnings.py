"""Which python blocks of the user guide warn that a transfer stopped at max_iter:
``python results/transfer/guide_warnings.py docs/guide.md`` (run with the library to check on the path first).

Executes every python block of the guide in order, as tests/test_guide.py does, in a scratch
directory, and prints each block's index with the messages of its transfers' MaxIterWarnings.
"""
import os
import pathlib
import re
import sys
import tempfile
import warnings

import matplotlib

matplotlib.use("Agg")


def main(path):
    blocks = re.findall(r"```python\n(.*?)```", pathlib.Path(path).read_text(), flags=re.S)
    namespace = {}
    os.chdir(tempfile.mkdtemp())
    for i, block in enumerate(blocks):
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            exec(compile(block, f"block {i}", "exec"), namespace)
        hits = [str(w.message)[:120] for w in caught if str(w.message).startswith("transfer stopped at max_iter")]
        print(i, hits, flush=True)


if __name__ == "__main__":
    main(sys.argv[1])
