"""Tabular Markov decision processes: :class:`TabularMDP` and the paper's :class:`GridWorld`.

Conventions (DESIGN section 2): transitions ``P[s, a, s']`` of shape (S, A, S) whose rows sum
to one; rewards ``R[..., s, a]``; a tabular reward parameter ``theta`` is ``R`` flattened in
C order, so ``d = S * A`` and index ``s * A + a``.
"""

import numpy as np

from ._validation import check_int, check_probability, check_real
from .exceptions import ValidationError

__all__ = ["TabularMDP", "GridWorld", "check_signature"]

_ROW_SUM_TOL = 1e-9


class TabularMDP:
    """A finite MDP with known dynamics and discount, validated on construction.

    Parameters
    ----------
    transitions : array_like, shape (S, A, S)
        ``transitions[s, a, s']`` is the probability of reaching ``s'`` after taking action
        ``a`` in state ``s``. Must be finite, nonnegative, and each row ``[s, a, :]`` must sum
        to 1 within 1e-9.
    gamma : float
        Discount factor, ``0 <= gamma < 1``.

    Attributes
    ----------
    transitions : ndarray of float64, shape (S, A, S)
        A read-only copy of the transitions.
    gamma : float
    n_states, n_actions : int
    n_params : int
        ``S * A``, the size of a tabular reward parameter.

    Raises
    ------
    ValidationError
        With a message naming the bad shape or value.
    """

    def __init__(self, transitions, gamma):
        try:
            P = np.array(transitions, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValidationError(f"transitions must be a numeric array of shape (S, A, S): {exc}") from None
        if P.ndim != 3:
            raise ValidationError(f"transitions must have shape (S, A, S); got ndim={P.ndim}, shape {P.shape}")
        S, A, S2 = P.shape
        if S == 0 or A == 0:
            raise ValidationError(f"transitions must have at least one state and one action; got shape {P.shape}")
        if S2 != S:
            raise ValidationError(f"transitions must have shape (S, A, S); got {P.shape} (last axis {S2} != {S} states)")
        if not np.all(np.isfinite(P)):
            bad = np.argwhere(~np.isfinite(P))[0]
            raise ValidationError(f"transitions must be finite; found {P[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
        if np.any(P < 0):
            bad = np.argwhere(P < 0)[0]
            raise ValidationError(f"transitions must be nonnegative; found {P[tuple(bad)]} at index {tuple(int(i) for i in bad)}")
        sums = P.sum(axis=2)
        err = np.abs(sums - 1.0)
        if np.any(err > _ROW_SUM_TOL):
            s, a = np.unravel_index(np.argmax(err), err.shape)
            raise ValidationError(
                f"each row transitions[s, a, :] must sum to 1 (within {_ROW_SUM_TOL}); row (s={s}, a={a}) sums to {float(sums[s, a])!r}"
            )
        gamma = check_real(gamma, "gamma", 0.0, 1.0, high_open=True)
        P.setflags(write=False)
        self.transitions = P
        self.gamma = gamma

    @property
    def n_states(self):
        return self.transitions.shape[0]

    @property
    def n_actions(self):
        return self.transitions.shape[1]

    @property
    def n_params(self):
        return self.transitions.shape[0] * self.transitions.shape[1]

    @property
    def transitions_flat(self):
        """Transitions reshaped to (S * A, S), rows indexed by ``s * A + a``."""
        return self.transitions.reshape(self.n_states * self.n_actions, self.n_states)

    def signature(self):
        """What identifies this MDP: a JSON-able dict of S, A, gamma and a digest of the dynamics.

        Learners record it at ``fit`` (``mdp_signature_``), saved models carry it, and a model
        refuses an MDP whose signature differs (:func:`check_signature`). The digest is the
        SHA-256 of the transitions as a canonical CSR matrix (float64, sorted indices, explicit
        zeros removed), so a dense and a sparse copy of the same dynamics share it.
        """
        import hashlib

        import scipy.sparse as sp

        P = sp.csr_matrix(self.transitions_flat, dtype=np.float64)
        P.eliminate_zeros()
        P.sort_indices()
        h = hashlib.sha256()
        for part in (np.asarray(P.shape, dtype=np.int64), P.indptr.astype(np.int64), P.indices.astype(np.int64), P.data):
            h.update(np.ascontiguousarray(part).tobytes())
        return {"n_states": int(self.n_states), "n_actions": int(self.n_actions), "gamma": float(self.gamma),
                "transitions_sha256": h.hexdigest()}

    def __repr__(self):
        return f"{type(self).__name__}(n_states={self.n_states}, n_actions={self.n_actions}, gamma={self.gamma})"


def check_signature(expected, mdp, what="this model"):
    """Raise :class:`ValidationError` unless ``mdp`` has the signature ``expected``.

    Parameters
    ----------
    expected : dict
        A :meth:`TabularMDP.signature` (e.g. a learner's ``mdp_signature_``).
    mdp : TabularMDP
    what : str
        Names the owner of ``expected`` in the message.
    """
    got = mdp.signature()
    if not isinstance(expected, dict) or set(expected) != set(got):
        raise ValidationError(f"{what} carries no valid MDP signature (got {expected!r})")
    diffs = [k for k in ("n_states", "n_actions", "gamma", "transitions_sha256") if expected[k] != got[k]]
    if diffs:
        detail = ", ".join("the transitions differ" if k == "transitions_sha256" else f"{k}: fitted {expected[k]!r}, given {got[k]!r}"
                           for k in diffs)
        raise ValidationError(f"{what} was fitted on another MDP ({detail}); use the MDP it was fitted on")


class GridWorld(TabularMDP):
    """The paper's grid world (section 4; DESIGN section 2).

    States are the cells of a ``size x size`` grid, numbered row-major: ``s = row * size + col``
    (row 0 at the top). Actions are the four moves ``0: up, 1: down, 2: left, 3: right``.

    Dynamics, as fixed by DESIGN section 2: from state ``s`` let ``F(s)`` be the feasible moves
    (those that stay on the grid). A feasible requested move succeeds with probability
    ``p_success``; with probability ``1 - p_success`` the agent makes a move drawn uniformly
    from ``F(s)`` (the requested one included). An infeasible request (into a wall) gives a
    move drawn uniformly from ``F(s)``.

    Parameters
    ----------
    size : int, default=10
        Side of the grid (>= 2).
    p_success : float, default=0.7
        Probability that a feasible move succeeds, in [0, 1].
    gamma : float, default=0.9
        Discount factor.
    """

    ACTIONS = ("up", "down", "left", "right")
    #: (row, column) displacement of each action, in the order of ``ACTIONS``
    MOVES = ((-1, 0), (1, 0), (0, -1), (0, 1))

    def __init__(self, size=10, p_success=0.7, gamma=0.9):
        self.size = check_int(size, "size", minimum=2)
        p = check_probability(p_success, "p_success")
        self.p_success = p
        super().__init__(self._build(self.size, p), gamma)

    @classmethod
    def _build(cls, size, p):
        S = size * size
        P = np.zeros((S, 4, S))
        for s in range(S):
            r, c = divmod(s, size)
            targets = {}
            for a, (dr, dc) in enumerate(cls.MOVES):
                rr, cc = r + dr, c + dc
                if 0 <= rr < size and 0 <= cc < size:
                    targets[a] = rr * size + cc
            nf = len(targets)
            for a in range(4):
                for t in targets.values():  # the uniform part over feasible moves
                    P[s, a, t] += (1.0 - p) / nf if a in targets else 1.0 / nf
                if a in targets:
                    P[s, a, targets[a]] += p
        return P

    def state_to_cell(self, state):
        """(row, col) of a state index, or arrays of them for an array of states."""
        state = np.asarray(state)
        if not np.issubdtype(state.dtype, np.integer) or np.any((state < 0) | (state >= self.n_states)):
            raise ValidationError(f"states must be integers in [0, {self.n_states}); got {state!r}")
        r, c = np.divmod(state, self.size)
        if r.ndim == 0:
            return int(r), int(c)
        return r, c

    def cell_to_state(self, row, col):
        """State index of cell (row, col) (scalars or arrays)."""
        row, col = np.asarray(row), np.asarray(col)
        for name, v in (("row", row), ("col", col)):
            if not np.issubdtype(v.dtype, np.integer) or np.any((v < 0) | (v >= self.size)):
                raise ValidationError(f"{name} must be integers in [0, {self.size}); got {v!r}")
        s = row * self.size + col
        return int(s) if s.ndim == 0 else s

    def __repr__(self):
        return f"GridWorld(size={self.size}, p_success={self.p_success}, gamma={self.gamma})"
