"""The lab: the experiment harness above the library (presets, runner, tables, figures, benchmarks, CLI).

Nothing in the library imports it, and ``import factirl_opt`` does not load it. The command
line is :mod:`factirl_opt.lab.cli` (``factirl-opt``); the benchmarks are
:mod:`factirl_opt.lab.bench` (``python -m factirl_opt.lab.bench`` or ``factirl-opt bench``).
"""
