"""What the planning engine keeps between calls, who owns it and how long it lives (docs/maths.md §4).

Two caches, both safe under threads:

**The planners of each MDP** (:func:`cached_planner`, :func:`clear_caches`). Owner: this module,
in a module-level, lock-protected :class:`weakref.WeakKeyDictionary` mapping an MDP to its
planners by name. Lifetime: the MDP's. The planners keep only a weak reference to their MDP,
so the entry (with every factorisation its planners hold) goes when the MDP is
garbage-collected; nothing is stored on the MDP itself, which therefore pickles and copies
without its caches. Models are immutable, so a planner can never go stale.

**The factorisations of a sparse planner** (:class:`FactorCache`). Owner: one
:class:`~factirl_opt.planning.sparse_lu.SparseLUPlanner`, which keeps one cache per thread
that plans with it. Lifetime: the planner's and the thread's, whichever ends first; bounded by
:data:`FACTOR_CACHE_BYTES` (estimated bytes) and :data:`CACHE_GROUPS_PER_TASK` factorisations
per task of the largest batch the thread planned. Per-thread caches mean that concurrent
threads never share a factorisation or an eviction decision: what a thread computes is exactly
what it would compute alone, and a cache hit costs no lock contention. :func:`clear_caches`
empties the caches of every thread.

**The factorisations of one fit** (:func:`isolated_caches`, :func:`isolated_planning`). The
learners' entry points (``GradIRL.fit``, ``FactIRL.fit`` and ``transfer``,
``MultiIntentIRL.fit``, :func:`~factirl_opt.fit_factorial`,
:func:`~factirl_opt.transfer_coefficients`) plan with caches of their own, one per planner,
made empty when the outermost of them starts and dropped when it returns. A low-rank update of
a cached factorisation and a fresh LU agree only to round-off (about 1e-12), so a fit that
could reuse what an earlier call left in the thread's cache would depend, in the last digits,
on that history; isolated, a fit computes exactly what it computes in a new thread or a new
process, and its factorisations are freed when it returns. Planning outside a fit
(``optimal_q``, the evaluation functions) keeps using the thread's cache.
"""

from __future__ import annotations

import collections
import contextlib
import functools
import threading
import weakref
from typing import Any, Callable, Iterator, TypeVar

__all__ = ["FactorCache", "cached_planner", "clear_caches", "isolated_caches", "isolated_planning", "scoped_cache",
           "FACTOR_CACHE_BYTES", "CACHE_GROUPS_PER_TASK"]

F = TypeVar("F", bound=Callable[..., Any])

#: a sparse planner's cache of factorisations of recent policies, per thread (estimated bytes)
FACTOR_CACHE_BYTES = 768 * 2**20
#: ... and at most this many factorisations (with their latest updates) per task of the largest batch seen
CACHE_GROUPS_PER_TASK = 2

_PLANNERS: weakref.WeakKeyDictionary[Any, dict[str, Any]] = weakref.WeakKeyDictionary()
_PLANNERS_LOCK = threading.Lock()
_SCOPE = threading.local()  # .caches: planner -> FactorCache of the outermost isolated call of this thread


class FactorCache:
    """Least-recently-used factorisations of deterministic policies, grouped by factorisation.

    Entries map a policy's key (its actions as bytes) to a solver with a ``base`` (the LU it
    uses: itself, or the factorisation a low-rank update corrects) and ``nbytes``. A group is
    an LU and its latest low-rank update (which replaces an older one: the next warm start is
    the latest policy); the least recently used group is evicted first, so every eviction frees
    memory. Every method holds the cache's lock, so a cache may be shared; the sparse planner
    keeps one per thread (see the module docstring).

    Attributes
    ----------
    entries : dict
        Policy key -> solver.
    groups : OrderedDict
        ``id(base)`` -> ``[base, keys, update_key]``, least recently used first (a cached base is
        alive, so its id is unique).
    nbytes : int
        Estimated bytes of the cached solvers.
    max_batch : int
        Largest batch of policies planned so far (bounds the number of groups).
    """

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self.entries: dict[bytes, Any] = {}
        self.groups: collections.OrderedDict[int, list[Any]] = collections.OrderedDict()
        self.nbytes = 0
        self.max_batch = 1

    def __len__(self) -> int:
        return len(self.entries)

    def note_batch(self, n: int) -> None:
        """Record a batch of ``n`` policies (the group bound grows with the largest batch)."""
        with self._lock:
            self.max_batch = max(self.max_batch, n)

    def get(self, key: bytes) -> Any:
        """The solver cached under ``key`` (now the most recently used), or None."""
        with self._lock:
            solver = self.entries.get(key)
            if solver is not None:
                self.groups.move_to_end(id(solver.base))
            return solver

    def remember(self, key: bytes, solver: Any) -> None:
        """Cache ``solver`` under ``key``, then evict least recently used groups over the bounds."""
        with self._lock:
            base = solver.base
            group = self.groups.get(id(base))
            if group is None:
                group = self.groups[id(base)] = [base, [], None]
                self.nbytes += base.nbytes
            if solver is base:
                group[1].append(key)
            else:
                if group[2] is not None:
                    self.nbytes -= self.entries.pop(group[2]).nbytes
                group[2] = key
                self.nbytes += solver.nbytes
            self.entries[key] = solver
            self.groups.move_to_end(id(base))
            self._evict()

    def _evict(self) -> None:
        while len(self.groups) > 1 and (self.nbytes > FACTOR_CACHE_BYTES
                                        or len(self.groups) > CACHE_GROUPS_PER_TASK * self.max_batch):
            _, (old, keys, update) = self.groups.popitem(last=False)
            for k in keys:
                del self.entries[k]
            if update is not None:
                self.nbytes -= self.entries.pop(update).nbytes
            self.nbytes -= old.nbytes

    def clear(self) -> None:
        """Forget every cached factorisation."""
        with self._lock:
            self.entries.clear()
            self.groups.clear()
            self.nbytes = 0


def cached_planner(mdp: Any, name: str, factory: Callable[[Any], Any]) -> Any:
    """The planner ``name`` of ``mdp``, built by ``factory(mdp)`` on first use and kept for the
    MDP's lifetime (one planner per MDP and name, also under threads)."""
    with _PLANNERS_LOCK:
        planners = _PLANNERS.get(mdp)
        if planners is None:
            planners = _PLANNERS[mdp] = {}
        planner = planners.get(name)
        if planner is None:
            planner = planners[name] = factory(mdp)
        return planner


def clear_caches(mdp: Any) -> None:
    """Forget the factorisations kept by every planner bound to ``mdp``, in every thread.

    The sparse planner keeps the factorisations of recent policies for the MDP's lifetime (up
    to :data:`FACTOR_CACHE_BYTES` per thread, see :class:`FactorCache`); this frees them. The
    planners themselves (their fixed orderings, no results) stay until the MDP is collected.
    """
    with _PLANNERS_LOCK:
        planners = list(_PLANNERS.get(mdp, {}).values())
    for planner in planners:
        planner.clear_cache()


@contextlib.contextmanager
def isolated_caches() -> Iterator[None]:
    """Inside the block, every planner of this thread caches its factorisations in a cache of the
    block's own (made on first use, dropped on exit); nested blocks share the outermost one's.

    What the block plans then depends only on what it does, not on what the thread planned before
    (see the module docstring).
    """
    if getattr(_SCOPE, "caches", None) is not None:
        yield
        return
    _SCOPE.caches = weakref.WeakKeyDictionary()
    try:
        yield
    finally:
        _SCOPE.caches = None


def scoped_cache(planner: Any) -> FactorCache | None:
    """``planner``'s cache in this thread's :func:`isolated_caches` block, or None outside one."""
    caches = getattr(_SCOPE, "caches", None)
    if caches is None:
        return None
    cache = caches.get(planner)
    if cache is None:
        cache = caches[planner] = FactorCache()
    return cache


def isolated_planning(fn: F) -> F:
    """Decorator: ``fn`` runs inside :func:`isolated_caches` (the learners' entry points)."""

    @functools.wraps(fn)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        with isolated_caches():
            return fn(*args, **kwargs)

    return wrapper  # type: ignore[return-value]
