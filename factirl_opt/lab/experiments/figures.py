"""Figures 1-3 of the paper, drawn from the tables the runner writes (matplotlib, Agg).

- Figure 1 (train tasks) and figure 2 (test tasks): two panels each, mean deviation from the
  optimal score against demos per training task (at the preset's default number of tasks) and
  against the number of training tasks (at its default demos per task); markers at the mean
  over seeds, error bars one standard deviation over seeds (when there are several).
- Figure 3: optimal value functions of 4 test tasks (default point, first seed): the true task
  with its single demonstration drawn on it, then the models of the line-up's ``value_maps``
  learners (the paper's: flat and factorial). Each map has its own colour scale (learnt rewards
  are defined up to scale); blue is high, as in the paper. On Objectworld the objects are drawn
  over every map (:func:`factirl_opt.datasets.objectworld.plot_objectworld`: dots filled with the inner colour,
  ringed with the outer one).

A figure shows a sweep's panel only when the sweep has at least two points (Objectworld's
presets sweep the number of training tasks only).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ...exceptions import PersistenceError, ValidationError
from ...files import atomic_write, open_for_reading, os_error
from ...mdp.tabular import GridWorld
from ...datasets.objectworld import make_objectworld, plot_objectworld
from .learner_names import (ADAPTIVE, ADAPTIVE_FEATURES, FACTORIAL, FACTORIAL_FEATURES, FACTORIAL_FEATURES_RANDOM_INIT, FACTORIAL_MCE,
                            FACTORIAL_RANDOM_INIT, FLAT, FLAT_FEATURES, FLAT_FEATURES_FROM_EXAMPLES, FLAT_GROUND_TRUTH,
                            FLAT_MCE, FLAT_PCA_FEATURES)
from .learners import get_lineup
from .tables import load_preset_from_manifest, read_results

__all__ = ["plot_sweeps", "plot_value_functions", "plot_all", "figure_files", "FIGURES"]

#: one fixed style per learner name, shared by figures 1 and 2
STYLES: dict[str, dict[str, Any]] = {
    FLAT: dict(color="#d62728", marker="o", linestyle="-"),
    FACTORIAL: dict(color="#1f77b4", marker="s", linestyle="-", linewidth=2.2),
    FACTORIAL_RANDOM_INIT: dict(color="#17becf", marker="D", linestyle="--"),
    FLAT_GROUND_TRUTH: dict(color="#2ca02c", marker="^", linestyle=":"),
    FLAT_PCA_FEATURES: dict(color="#ff7f0e", marker="v", linestyle="-."),
    FLAT_FEATURES_FROM_EXAMPLES: dict(color="#9467bd", marker="P", linestyle="--"),
    FLAT_FEATURES: dict(color="#e377c2", marker="o", linestyle="--"),
    FACTORIAL_FEATURES: dict(color="#08306b", marker="s", linestyle="-", linewidth=2.2),
    FACTORIAL_FEATURES_RANDOM_INIT: dict(color="#6baed6", marker="D", linestyle="--"),
    FLAT_MCE: dict(color="#8c564b", marker="o", linestyle=":"),
    FACTORIAL_MCE: dict(color="#bcbd22", marker="s", linestyle="-", linewidth=2.2),
    ADAPTIVE: dict(color="#000000", marker="*", linestyle="-", linewidth=2.2),
    ADAPTIVE_FEATURES: dict(color="#404040", marker="*", linestyle="-", linewidth=2.2),
}

#: figure 3's row labels of the paper's learners (other learners are labelled by their names)
ROW_NAMES = {FLAT: "flat learner", FACTORIAL: "factorial learner"}
#: the figures :func:`plot_all` writes into ``OUT/figures``, as ``(stem, formats)``
FIGURES = tuple((f"figure{i}", ("png", "svg")) for i in (1, 2, 3))


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _series(rows, learner, x_name, fixed_name, fixed_value):
    pts = {}
    for r in rows:
        if r["learner"] == learner and r[fixed_name] == fixed_value:
            pts.setdefault(r[x_name], []).append(r["deviation"])
    xs = sorted(pts)
    mean = np.array([np.mean(pts[x]) for x in xs])
    std = np.array([np.std(pts[x], ddof=1) if len(pts[x]) > 1 else 0.0 for x in xs])
    return np.array(xs), mean, std, [len(pts[x]) for x in xs]


def figure_files(out: str | os.PathLike) -> list[str]:
    """The paths of every figure :func:`plot_all` may write into ``out/figures``."""
    return [os.path.join(os.fspath(out), "figures", f"{stem}.{ext}") for stem, formats in FIGURES for ext in formats]


def plot_sweeps(rows: Sequence[dict], preset: Any, split: str, path_base: str, h_solver: str | None = None) -> list[str]:
    """Figure 1 (``split="train"``) or 2 (``"test"``): deviation along both sweeps.

    Parameters
    ----------
    rows : list of dict
        Rows of results.csv.
    preset : Preset
        Gives the default point that fixes the other variable of each panel.
    split : {"train", "test"}
    path_base : str
        Written as ``path_base + ".png"`` and ``".svg"``.
    h_solver : str, optional
        Keep the rows of this solver only (default: the first one found).

    Returns
    -------
    list of str
        The files written.
    """
    if split not in ("train", "test"):
        raise ValidationError(f"split must be 'train' or 'test'; got {split!r}")
    rows = [r for r in rows if r["split"] == split]
    if not rows:
        raise ValidationError(f"no {split} rows to plot")
    h_solver = h_solver or sorted({r["h_solver"] for r in rows})[0]
    rows = [r for r in rows if r["h_solver"] == h_solver]
    n_seeds = len({r["seed"] for r in rows})
    panels = _panels(rows, preset)
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(5.5 * len(panels) if len(panels) > 1 else 8.0, 4.4), sharey=True,
                             squeeze=False)
    axes = axes[0]
    learners = list(dict.fromkeys(r["learner"] for r in rows))  # the tables' order: the line-up's
    lows, highs = [], []
    for ax, (x_name, fixed_name, fixed_value, xlabel, title) in zip(axes, panels):
        for learner in learners:
            xs, mean, std, _ = _series(rows, learner, x_name, fixed_name, fixed_value)
            if xs.size == 0:
                continue
            style = STYLES.get(learner, {})
            lows.extend(mean[mean > 0])
            highs.extend(mean + std)
            ax.errorbar(xs, mean, yerr=std if n_seeds > 1 else None, label=learner, capsize=3, markersize=6, **style)
        ax.set_xscale("log")
        xticks = sorted({r[x_name] for r in rows if r[fixed_name] == fixed_value})
        ax.set_xticks(xticks)
        ax.set_xticklabels([str(x) for x in xticks])
        ax.minorticks_off()
        ax.set_xlabel(xlabel)
        ax.set_title(title, fontsize=10)
        ax.grid(True, alpha=0.3)
        # deviations span two decades (ground truth ~0.1, a failed fit ~20): log scale
        ax.set_yscale("log", nonpositive="clip")
    if lows:
        axes[0].set_ylim(min(lows) / 1.6, max(highs) * 1.4)
    axes[0].set_ylabel("deviation from optimal score\n(mean over tasks; lower is better; log scale)")
    what = "training tasks" if split == "train" else "test tasks, one demonstration each"
    spread = f"mean ± std over {n_seeds} seeds" if n_seeds > 1 else "1 seed"
    sep = "  " if len(panels) > 1 else "\n"
    fig.suptitle(f"Figure {1 if split == 'train' else 2}: performance on {what}{sep}[{spread}; H-step solver: {h_solver}]",
                 fontsize=11)
    handles, labels = axes[0].get_legend_handles_labels()
    legend_rows = -(-len(labels) // (5 if len(panels) > 1 else 3))  # the paper's 5 learners: one row
    fig.legend(handles, labels, loc="lower center", ncol=-(-len(labels) // legend_rows), fontsize=9, frameon=False)
    fig.tight_layout(rect=(0, 0.03 + 0.05 * legend_rows, 1, 0.95 if len(panels) > 1 else 0.9))
    return _save(plt, fig, path_base, dpi=130)


def _panels(rows, preset):
    """The panels of figures 1-2: each sweep with at least two points (or the first sweep alone)."""
    panels = [
        ("demos_per_task", "n_tasks", preset.default_tasks, "demonstrations per training task",
         f"{preset.default_tasks} training tasks"),
        ("n_tasks", "demos_per_task", preset.default_demos, "number of training tasks",
         f"{preset.default_demos} demonstrations per training task"),
    ]
    swept = [p for p in panels if len({r[p[0]] for r in rows if r[p[1]] == p[2]}) > 1]
    return swept or panels[:1]


def _save(plt, fig, path_base, dpi):
    """Write ``fig`` as PNG and SVG next to each other (atomically), close it, return the two paths."""
    written = []
    try:
        for ext in ("png", "svg"):
            with atomic_write(f"{path_base}.{ext}", binary=True) as fh:
                fig.savefig(fh, format=ext, dpi=dpi)
            written.append(f"{path_base}.{ext}")
    finally:
        plt.close(fig)
    return written


def _draw_demo(ax, demo, size, moves, colour):
    """The demonstration's path: a line through the visited cells, arrows for the actions.

    ``moves[a]`` is action a's ``(d_row, d_col)``; an action that does not move gets no arrow.
    """
    steps = np.asarray(demo)
    rows, cols = np.divmod(steps[:, 0], size)
    ax.plot(cols, rows, color=colour, linewidth=1.5, alpha=0.8)
    for r, c, a in zip(rows, cols, steps[:, 1]):
        dr, dc = moves[a]
        if (dr, dc) != (0, 0):
            ax.annotate("", xy=(c + 0.4 * dc, r + 0.4 * dr), xytext=(c, r),
                        arrowprops=dict(arrowstyle="->", color=colour, lw=1.2))
    ax.plot(cols[0], rows[0], "o", color=colour, markersize=7, markeredgecolor="white", zorder=4)


def _map_style(data, size):
    """How figure 3 draws a world: ``(draw(ax, V), demo colour, "... is high")``.

    The paper's grid: blue heat maps, red demonstrations. Objectworld: grey heat maps (the
    objects' colours stay readable) with the objects drawn over them
    (:func:`factirl_opt.datasets.objectworld.plot_objectworld`), demonstrations in cyan (no object has that colour).
    """
    if "objects" not in data:
        return (lambda ax, V: ax.imshow(V, cmap="Blues", interpolation="nearest")), "#d62728", "blue is high"
    world = make_objectworld(size, int(data["n_inner"]), int(data["n_outer"]), objects=np.asarray(data["objects"]))

    def draw(ax, V):
        ax.imshow(V, cmap="Greys", interpolation="nearest")
        plot_objectworld(world, ax)

    return draw, "#17becf", "dark is high"


def plot_value_functions(data: dict, path_base: str, point: tuple[int, int] | None = None,
                         learners: Sequence[str] = (FLAT, FACTORIAL)) -> list[str]:
    """Figure 3: value-function heat maps of 4 test tasks (rows: the truth, then each learner).

    Parameters
    ----------
    data : dict
        Contents of figure3.json: ``grid_size``, ``true``, ``demos``, and for each learner its
        maps and ``deviation_<learner>``; Objectworld's (``objects``, ``n_inner``, ``n_outer``,
        ``moves``) draw the objects over the maps (:func:`factirl_opt.datasets.objectworld.plot_objectworld`) and the
        demonstrations with the world's actions.
    path_base : str
    point : tuple (n_tasks, demos_per_task), optional
        The training point the learners come from (shown in the title).
    learners : sequence of str
        The test learners whose maps are drawn, one row each (the line-up's ``value_maps``).

    Returns
    -------
    list of str
    """
    size = int(data["grid_size"])
    missing = [name for name in learners if name not in data or f"deviation_{name}" not in data]
    if missing:
        raise ValidationError(f"figure3 data has no value maps of {missing}; rerun `factirl-opt reproduce` to rewrite it")
    (draw, demo_colour, high), moves = _map_style(data, size), data.get("moves", GridWorld.MOVES)
    plt = _pyplot()
    n, rows = len(data["true"]), [("true", "true task (V*) + demonstration")]
    rows += [(name, ROW_NAMES.get(name, name)) for name in learners]
    fig, axes = plt.subplots(len(rows), n, figsize=(2.7 * n + 0.6, 2.8 * len(rows)), squeeze=False)
    for i, (key, name) in enumerate(rows):
        for j in range(n):
            ax = axes[i, j]
            draw(ax, np.asarray(data[key][j]).reshape(size, size))
            if key == "true":
                _draw_demo(ax, data["demos"][j], size, moves, demo_colour)
                ax.set_title(f"test task {j + 1}", fontsize=10)
            else:
                ax.set_title(f"deviation {data['deviation_' + key][j]:.2f}", fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
            if j == 0:
                ax.set_ylabel(name, fontsize=10)
    trained = f"learners trained on {point[0]} tasks x {point[1]} demos, " if point else ""
    fig.suptitle(f"Figure 3: optimal value functions of {n} test tasks, one demonstration each\n"
                 f"({trained}seed {data.get('seed', '?')}; {high}; each map has its own colour scale)", fontsize=10)
    fig.tight_layout(rect=(0, 0, 1, 0.95))
    return _save(plt, fig, path_base, dpi=110)


def plot_all(out: str | os.PathLike) -> list[str]:
    """Draw figures 1-3 into ``out/figures`` from a reproduce directory; returns the files written.

    Reads ``out/results.csv``, ``out/manifest.json`` (the preset) and ``out/figure3.json``;
    without figure3.json, a figure 3 drawn from earlier tables is removed.
    """
    out = os.fspath(out)
    rows = read_results(out)
    preset = load_preset_from_manifest(out)
    fig_dir = os.path.join(out, "figures")
    try:
        os.makedirs(fig_dir, exist_ok=True)
    except OSError as exc:
        raise os_error(exc, "create the figures directory", fig_dir) from exc
    written = plot_sweeps(rows, preset, "train", os.path.join(fig_dir, "figure1"))
    written += plot_sweeps(rows, preset, "test", os.path.join(fig_dir, "figure2"))
    f3 = os.path.join(out, "figure3.json")
    if os.path.exists(f3):
        try:
            with open_for_reading(f3, binary=False) as fh:
                data = json.load(fh)
        except PersistenceError:  # cannot be opened (a ValueError too): named as such
            raise
        except ValueError as exc:
            raise ValidationError(f"{f3} is not valid JSON ({exc}); rerun `factirl-opt reproduce` to rewrite it") from None
        written += plot_value_functions(data, os.path.join(fig_dir, "figure3"),
                                        point=(preset.default_tasks, preset.default_demos),
                                        learners=get_lineup(preset.lineup).value_maps)
    else:
        for ext in FIGURES[2][1]:
            path = os.path.join(fig_dir, f"{FIGURES[2][0]}.{ext}")
            if os.path.exists(path):
                try:
                    os.unlink(path)
                except OSError as exc:
                    raise os_error(exc, "remove the stale figure", path) from exc
    return written
