"""Drawing an Objectworld with matplotlib (imported lazily, only when drawing)."""

from __future__ import annotations

import typing

import numpy as np
from numpy.typing import ArrayLike

from ...exceptions import ValidationError
from .world import ObjectWorld, check_world

__all__ = ["plot_objectworld"]


def _check_values(values, N):
    v = np.asarray(values, dtype=np.float64)
    if v.shape not in ((N * N,), (N, N)):
        raise ValidationError(f"values must have shape (S,) = ({N * N},) or (N, N) = ({N}, {N}); got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValidationError("values must be finite")
    return v.reshape(N, N)


def plot_objectworld(world: ObjectWorld, ax: typing.Any = None, values: ArrayLike | None = None, cmap: typing.Any = "viridis") -> typing.Any:
    """Draw the grid, optionally over a value map, with the objects (matplotlib, lazily imported).

    Each object is a dot filled with its inner colour and ringed with its outer colour. The
    colours follow the toolkit's order (inner colours ``0..c1-1``, then the outer ones) in
    matplotlib's ``tab10`` (``tab20`` beyond 10 colours, cycling beyond 20): inner colour ``c``
    is ``tab10(c)``, outer colour ``c`` is ``tab10(c1 + c)``. Row 0 is at the top, as in the
    state numbering; grid lines are drawn up to ``N = 40``.

    Parameters
    ----------
    world : ObjectWorld
    ax : matplotlib Axes, optional
        Where to draw; a new square figure when None.
    values : array_like, shape (S,) or (N, N), optional
        A finite map drawn as the background (e.g. a reward or value function), state ``s`` at
        cell ``divmod(s, N)``, with a colour bar.
    cmap : str or Colormap, default="viridis"
        Colour map of ``values``.

    Returns
    -------
    ax : matplotlib Axes
    """
    world = check_world(world)
    N = world.size
    grid = None if values is None else _check_values(values, N)
    if ax is None:
        import matplotlib.pyplot as plt

        _, ax = plt.subplots(figsize=(6, 6))
    from matplotlib import colormaps

    if grid is not None:
        image = ax.imshow(grid, cmap=cmap, origin="upper", interpolation="nearest", extent=(-0.5, N - 0.5, N - 0.5, -0.5))
        ax.figure.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    ticks = np.arange(-0.5, N, 1.0)
    ax.set_xticks(ticks, minor=True)
    ax.set_yticks(ticks, minor=True)
    ax.grid(which="minor", color="0.8", linewidth=0.5 if N <= 40 else 0.0)
    ax.tick_params(which="both", length=0, labelbottom=False, labelleft=False)
    n_colours = world.n_inner + world.n_outer
    palette = colormaps["tab10" if n_colours <= 10 else "tab20"]
    objs = world.objects
    fig_w, fig_h = ax.figure.get_size_inches()
    box = ax.get_position()
    cell_pt = 72.0 * min(fig_w * box.width, fig_h * box.height) / N
    ax.scatter(
        objs[:, 1], objs[:, 0], s=(0.5 * cell_pt) ** 2,
        c=[palette(int(c) % palette.N) for c in objs[:, 2]],
        edgecolors=[palette(int(world.n_inner + c) % palette.N) for c in objs[:, 3]],
        linewidths=max(0.5, 0.18 * cell_pt), zorder=3,
    )
    ax.set_xlim(-0.5, N - 0.5)
    ax.set_ylim(N - 0.5, -0.5)
    ax.set_aspect("equal")
    return ax
