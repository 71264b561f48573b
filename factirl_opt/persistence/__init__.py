"""Saving and loading fitted models and demonstration sets.

File format (``FORMAT_VERSION`` 2). A file is an ``.npz`` archive (``numpy.savez_compressed``)
holding plain numeric arrays only, so it loads with ``allow_pickle=False``, plus one member
``__header__``: a 0-d unicode array holding a JSON object::

    {"format": "factirl-opt", "format_version": 2, "kind": "model" | "demonstrations",
     "library_version": "0.1.0", "numpy_version": "1.26.4", ...}

A **model** file adds ``"class"`` (``"GradIRL"``, ``"FactIRL"`` or ``"MultiIntentIRL"``),
``"params"`` (the constructor parameters, ``model.get_params()``), ``"array_params"`` (names
of parameters stored as arrays: ``features``, FactIRL's ``init`` given as a tuple
``(D0, H0)``, MultiIntentIRL's ``init`` given as labels or responsibilities), ``"attributes"``
(learnt attributes that are not arrays: lists of losses, counts, status strings, the MDP
signature, the features digest) and ``"array_attributes"``. Arrays are stored as members
``param/<name>`` and ``attr/<name>``, exactly (dtype and bits), so a loaded model transfers
and scores bit-identically.

Parameters and learnt attributes. Which parameters are saved comes from the estimator's
``get_params()`` (the arguments of its ``__init__``, :class:`factirl_opt.learners.estimator.Estimator`),
and how each is stored from the kind its class declares in ``param_kinds``
(:data:`.params.PARAM_KINDS`; undeclared: plain JSON). Which attributes are saved, and how
each is checked on saving and loading, comes from the class too: ``learnt_attributes`` maps
each attribute ``fit`` or ``transfer`` sets to its kind (:mod:`.learnt`). An attribute the
class does not declare is refused, on saving and on loading. Every declared attribute is
optional in a file, so files written before an attribute existed still load (see
:func:`load_model`); the format version is unchanged by a new attribute.

The MDP signature and the features digest. A fitted model carries ``mdp_signature_``, the
:meth:`~factirl_opt.TabularMDP.signature` of the MDP it was fitted on (S, A, gamma and a
SHA-256 of the transitions), so that it can refuse another MDP
(:func:`~factirl_opt.mdp.tabular.check_signature`), and ``features_sha256_``, the SHA-256 of the
``features`` it was fitted with (:func:`.learnt.features_sha256`; None without features), so
that it can refuse other features of the same shape. Both are saved with the model, and
:func:`load_model` checks the digest against the saved ``features``. A fitted model's file
without a signature loads with ``mdp_signature_ = None`` (unknown, not checked); one without
a digest gets the digest of its saved features.

Tasks in several environments. A model fitted on a sequence of MDPs has a list
``mdp_signature_`` (one signature per task, saved as a JSON list); one fitted with one feature
matrix per task stores its ``features`` parameter as ``{"per_task": n}`` in ``"params"`` and
the matrices as members ``param/features/<i>``, and has ``features_sha256_ = None`` (transfer
to new environments checks the feature dimension p and the number of actions instead). Per-task
arrays of environments of different sizes (``rewards_``, ``transfer_rewards_``: lists of
(S_i, A) arrays) are stored as members ``attr/<name>/<i>``, listed with their count in the
header's ``"array_list_attributes"``.

Parameters that do not fit in JSON:

- a solver, objective or planner given as an object rather than a registry name (``solver``,
  ``d_solver``, ``objective``, ``planner``) is refused with a :class:`PersistenceError`: give
  it by name, a solver with its options (``solver="armijo", solver_options={...}``), which are
  stored; a :class:`~factirl_opt.SolverSettings` given as ``solver`` is stored as its fields;
- the execution settings (``callback``, a function called during ``fit``; ``n_jobs``,
  ``backend``, ``client``, ``planner_options``) are not part of the model and are not saved:
  the loaded model has their defaults (``callback=None``);
- a parameter saved under a name since renamed (FactIRL's ``h_solver``, ``h_solver_options``,
  before they became ``solver``, ``solver_options``) loads under its name now;
- ``rng`` given as a ``numpy.random.Generator`` is stored as its bit generator's state (the
  loaded model gets a new Generator in that state); a ``SeedSequence`` by its entropy and
  spawn key; an int or None as is;
- options dicts must be JSON-serialisable (tuples come back as lists).

A **demonstrations** file stores the ``(state, action)`` steps of all episodes concatenated
(member ``steps``, int64 (N, 2)), the length of each episode (``episode_lengths``) and the
number of episodes of each task (``task_n_episodes``); the header's ``"task_forms"`` records
whether each task was an (m, L, 2) array (``"array"``) or a list of episodes (``"list"``),
and :func:`load_demonstrations` gives back the same form. Lists of episodes of different
lengths are therefore saved as they are; trajectories of other libraries are saved as their
(state, action) steps. (Format version 1 also wrote ``"episode"``, a task given as a single
(L, 2) array, which the nesting rule of :mod:`factirl_opt.tasks.trajectories` now refuses; such a
task loads as a list of one episode.)

Writing is atomic: a path is written to a temporary file in the same directory, flushed,
fsynced and renamed over the target (:func:`factirl_opt.files.atomic_write`), so a failure at
any point (a full disk, a read-only directory, Ctrl-C) leaves the previous file intact and no
partial file. A writable file object is written into as it is.

Reading is defensive: a corrupt or truncated file, a corrupt compressed member, a header that
is not the expected JSON, a member of the wrong dtype or shape, non-finite values, negative
states or inconsistent lengths all raise :class:`PersistenceError` naming the file and, where
there is one, the member or attribute. Operating-system errors on either side (a missing file
or directory, a read-only directory, a path that is a directory, a full disk) raise
:class:`PersistenceError` naming the path and the cause, the ``OSError`` chained as
``__cause__``.

Pickle and copy. The estimators hold only their parameters and learnt attributes (no MDP, no
planner cache), so a fitted model round-trips through :mod:`pickle` and :func:`copy.deepcopy`
(which joblib and Dask rely on) with equal arrays. ``callback`` is kept as it is (it is not
dropped): a module-level function pickles by name; a lambda or a local function cannot be
pickled, and ``pickle`` raises its own error naming the function (``PicklingError``, or
``AttributeError: Can't pickle local object ...`` for a function defined inside another): set
``callback=None``, or use a module-level function, before pickling. ``copy.deepcopy`` keeps
the same callback object.
"""

from .archive import FORMAT_VERSION
from .demonstrations import load_demonstrations, save_demonstrations
from .models import load_model, save_model

__all__ = ["save_model", "load_model", "save_demonstrations", "load_demonstrations", "FORMAT_VERSION"]
