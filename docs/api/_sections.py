"""The API reference's sections: which public namespace, under which real module, with what title.

Read by ``docs/api/generate.py`` (writes the section pages) and by ``tests/test_docs.py`` (checks
that every public name has its page).
"""

#: (page, namespace as users write it, module that holds the names, title, one-line summary)
SECTIONS = [
    ("top", "fo", "factirl_opt", "The top level: ``factirl_opt``",
     "The core: models, planning entry points, the three estimators, scores, demonstrations, persistence."),
    ("learners", "fo.learners", "factirl_opt.learners", "Learners: ``fo.learners``",
     "The estimators and their fitting schemes."),
    ("mdp", "fo.mdp", "factirl_opt.mdp", "Models: ``fo.mdp``",
     "Tabular MDPs, successor lists, models estimated from logs."),
    ("planning", "fo.planning", "factirl_opt.planning", "Planning: ``fo.planning``",
     "The engine that solves Bellman systems, its planners, caches and memory budget."),
    ("tasks", "fo.tasks", "factirl_opt.tasks", "Tasks: ``fo.tasks``",
     "Demonstrations, trajectories and reward features."),
    ("objectives", "fo.objectives", "factirl_opt.objectives", "Objectives: ``fo.objectives``",
     "Rewards to loss and gradient: policy matching and maximum causal entropy."),
    ("datasets", "fo.datasets", "factirl_opt.datasets", "Datasets: ``fo.datasets``",
     "Synthetic tasks and BabyAI task sets."),
    ("objectworld", "fo.objectworld", "factirl_opt.datasets.objectworld", "Objectworld: ``fo.objectworld``",
     "Levine et al.'s Objectworld, its multi-task version and maps per task."),
    ("minigrid", "fo.minigrid", "factirl_opt.adapters.minigrid", "MiniGrid and BabyAI: ``fo.minigrid``",
     "Models enumerated from MiniGrid layouts, features, the BabyAI bot, policies run in the environment."),
    ("adapters", "fo.adapters", "factirl_opt.adapters", "Adapters: ``fo.adapters``",
     "Gymnasium toy-text environments and Minari datasets."),
    ("exceptions", "fo.exceptions", "factirl_opt.exceptions", "Exceptions and warnings: ``fo.exceptions``",
     "Every error the library raises on bad input is one of these."),
    ("validation", "fo.validation", "factirl_opt.validation", "Argument checks: ``fo.validation``",
     "The library's checks of scalar arguments, for code built on it (presets, scripts, extensions)."),
    ("solvers", "solvers", "solvers", "Step solvers: ``solvers``",
     "The step-solver registry, a leaf package that imports nothing from factirl_opt."),
]


def public_names(module_name):
    """The module's ``__all__``."""
    import importlib

    return list(importlib.import_module(module_name).__all__)


def documented_where():
    """Each public object's one page: full documented name, keyed by (namespace, name).

    A name that a namespace shares with the top level (``fo.mdp.TabularMDP`` is
    ``fo.TabularMDP``) is documented once, at the top level, and the namespace links to it.
    """
    import importlib

    pages = {}
    seen = {}  # id(object) -> documented name
    for page, namespace, module_name, _title, _summary in SECTIONS:
        module = importlib.import_module(module_name)
        for name in public_names(module_name):
            obj = getattr(module, name)
            key = id(obj) if callable(obj) or isinstance(obj, type) else (module_name, name)
            if key not in seen:
                seen[key] = f"{module_name}.{name}"
            pages[(namespace, name)] = seen[key]
    return pages
