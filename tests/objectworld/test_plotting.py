"""Drawing an Objectworld."""

import numpy as np
import pytest

from factirl_opt.exceptions import ValidationError
from factirl_opt.datasets.objectworld import levine_reward, make_objectworld, plot_objectworld


def test_plot_objectworld_draws_objects_and_values():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    world = make_objectworld(8, rng=0)
    ax = plot_objectworld(world, values=levine_reward(world))
    assert len(ax.images) == 1 and ax.images[0].get_array().shape == (8, 8)
    offsets = ax.collections[-1].get_offsets()
    np.testing.assert_array_equal(np.asarray(offsets), world.objects[:, [1, 0]])
    plt.close(ax.figure)
    fig, ax2 = plt.subplots()
    assert plot_objectworld(world, ax=ax2) is ax2 and len(ax2.images) == 0
    plt.close(fig)


def test_plot_validation():
    world = make_objectworld(4, n_inner=2, n_outer=1, rng=0)
    with pytest.raises(ValidationError, match="world must be an ObjectWorld"):
        plot_objectworld("not a world")
    with pytest.raises(ValidationError, match=r"values must have shape \(S,\) = \(16,\)"):
        plot_objectworld(world, values=np.zeros(5))
    with pytest.raises(ValidationError, match="values must be finite"):
        plot_objectworld(world, values=np.full(16, np.nan))
