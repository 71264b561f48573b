"""TabularMDP.from_successors: the classmethod form of factirl_opt.mdp.from_successors."""

import numpy as np
import pytest

import factirl_opt as fo
from factirl_opt.exceptions import ValidationError
from factirl_opt.mdp import from_successors, to_successors


def test_classmethod_equals_the_function_and_sums_repeated_successors():
    # state 0, action 0: successor 0 listed twice (a wall), 0.3 + 0.2 must add up to 0.5
    sa_s = np.array([[[1, 1, 2], [2, 2, 2]], [[2, 1, 2], [1, 1, 1]]], dtype=float)
    sa_p = np.array([[[0.3, 0.2, 0.5], [1.0, 0.0, 0.0]], [[0.25, 0.5, 0.25], [0.2, 0.3, 0.5]]])
    mdp = fo.TabularMDP.from_successors(sa_s, sa_p, 0.9, index_base=1)
    ref = from_successors(sa_s, sa_p, 0.9, index_base=1)
    assert type(mdp) is fo.TabularMDP and mdp.signature() == ref.signature()
    np.testing.assert_allclose(mdp.transitions[0, 0], [0.5, 0.5], rtol=0, atol=1e-15)
    np.testing.assert_allclose(mdp.transitions[1, 1], [1.0, 0.0], rtol=0, atol=1e-15)
    grid = fo.GridWorld(3)
    assert fo.GridWorld.from_successors(*to_successors(grid), grid.gamma).signature() == grid.signature()


def test_classmethod_errors_are_the_function_s():
    with pytest.raises(ValidationError, match=r"index_base must be 0 or 1"):
        fo.TabularMDP.from_successors(np.zeros((1, 1, 1)), np.ones((1, 1, 1)), 0.9, index_base=2)
    with pytest.raises(ValidationError, match=r"successor state out of range"):
        fo.TabularMDP.from_successors(np.full((1, 1, 1), 3.0), np.ones((1, 1, 1)), 0.9)
