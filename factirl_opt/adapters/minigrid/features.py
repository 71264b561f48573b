"""State features of MiniGrid layouts (the same columns in every layout) and BabyAI missions.

Feature columns, in order (names from :func:`minigrid_feature_names`):

1. **What the agent faces** (the cell in front of it), one-hot over 7 columns: ``front=empty``
   (nothing, or floor), ``front=wall``, ``front=other`` (goal, lava, ...), then one column per
   object type of :data:`OBJECT_TYPES` (``front=key``, ``front=ball``, ``front=box``,
   ``front=door``); exactly one of these 7 is 1.
2. **The colour of the faced object**: ``front colour=red`` ... one column per colour of
   :data:`COLOURS` (all 0 unless the agent faces a key, ball, box or door; walls are not coloured).
3. **Their conjunction**: ``front=red key`` ..., colour-major (``c * 4 + t``), 24 columns.
4. **Distances**: for each colour of :data:`COLOURS`, then each type of :data:`OBJECT_TYPES`,
   the indicators ``1[distance < d]`` for the thresholds ``d`` (``near red<2`` ...), where the
   distance is the Euclidean distance, in cells, from the agent's cell to the nearest object of
   that colour (any of the four types) or type; column ``j * T + k`` for distance column ``j``
   and threshold ``k`` (colour-major then threshold, as Objectworld's features; the direction
   does not enter). A colour or type absent from the layout has no indicator set.

With the default thresholds there are 7 + 6 + 24 + 10 * 9 = 127 columns.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from ..._validation import check_real
from ...exceptions import ValidationError

__all__ = [
    "COLOURS",
    "OBJECT_TYPES",
    "DEFAULT_THRESHOLDS",
    "grid_objects",
    "minigrid_feature_names",
    "minigrid_features",
    "parse_goto_mission",
]

#: MiniGrid's colours, in its own index order (``minigrid.core.constants.COLOR_TO_IDX``).
COLOURS = ("red", "green", "blue", "purple", "yellow", "grey")
#: The object types that BabyAI missions name.
OBJECT_TYPES = ("key", "ball", "box", "door")
#: Default ``d`` of the indicators ``1[distance < d]``: fine near the agent, coarse far away
#: (a 22 x 22 BabyAI grid has distances up to about 28).
DEFAULT_THRESHOLDS = (1.0, 2.0, 3.0, 4.0, 6.0, 8.0, 12.0, 16.0, 24.0)
_KINDS = ("empty", "wall", "other")
_DIRECTIONS = np.array([(1, 0), (0, 1), (-1, 0), (0, -1)])
_MISSION = re.compile(r"go to (?:the|a) (?:(%s) )?(%s)" % ("|".join(COLOURS), "|".join(OBJECT_TYPES)))


def _check_thresholds(thresholds: Any) -> tuple[float, ...]:
    try:
        values = tuple(thresholds)
    except TypeError:
        raise ValidationError(f"thresholds must be a sequence of increasing positive numbers; got {thresholds!r}") from None
    values = tuple(check_real(d, "each threshold", low=0.0, low_open=True) for d in values)
    if not values or any(b <= a for a, b in zip(values, values[1:])):
        raise ValidationError(f"thresholds must be a non-empty, strictly increasing sequence; got {values}")
    return values


def minigrid_feature_names(thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS) -> list[str]:
    """The names of the feature columns, in order (see the module docstring).

    Parameters
    ----------
    thresholds : tuple of float, default=DEFAULT_THRESHOLDS

    Returns
    -------
    names : list of str, length 7 + 6 + 24 + 10 * len(thresholds)
    """
    thresholds = _check_thresholds(thresholds)
    names = [f"front={k}" for k in _KINDS + OBJECT_TYPES]
    names += [f"front colour={c}" for c in COLOURS]
    names += [f"front={c} {t}" for c in COLOURS for t in OBJECT_TYPES]
    names += [f"near {what}<{d:g}" for what in COLOURS + OBJECT_TYPES for d in thresholds]
    return names


def grid_objects(grid: Any) -> np.ndarray:
    """The keys, balls, boxes and doors of a MiniGrid grid.

    Returns
    -------
    objects : ndarray of int64, shape (m, 4)
        Rows ``(x, y, colour, type)``, colour an index into :data:`COLOURS` and type into
        :data:`OBJECT_TYPES`, in row-major order of the cells.
    """
    rows = []
    for y in range(grid.height):
        for x in range(grid.width):
            cell = grid.get(x, y)
            if cell is not None and cell.type in OBJECT_TYPES:
                rows.append((x, y, COLOURS.index(cell.color), OBJECT_TYPES.index(cell.type)))
    return np.array(rows, dtype=np.int64).reshape(-1, 4)


def _front_columns(states: np.ndarray, grid: Any) -> np.ndarray:
    """Blocks 1-3 of the features: what each state faces."""
    nk, nt, nc = len(_KINDS), len(OBJECT_TYPES), len(COLOURS)
    out = np.zeros((len(states), nk + nt + nc + nc * nt))
    front = states[:, :2] + _DIRECTIONS[states[:, 2]]
    for s, (fx, fy) in enumerate(front):
        inside = 0 <= fx < grid.width and 0 <= fy < grid.height
        cell = grid.get(int(fx), int(fy)) if inside else None
        if cell is None or cell.type in ("empty", "floor"):
            out[s, 0] = 1.0
        elif cell.type == "wall":
            out[s, 1] = 1.0
        elif cell.type in OBJECT_TYPES:
            t, c = OBJECT_TYPES.index(cell.type), COLOURS.index(cell.color)
            out[s, [nk + t, nk + nt + c, nk + nt + nc + c * nt + t]] = 1.0
        else:
            out[s, 2] = 1.0
    return out


def minigrid_features(states: np.ndarray, objects: np.ndarray, grid: Any,
                      thresholds: tuple[float, ...] = DEFAULT_THRESHOLDS) -> np.ndarray:
    """Features of navigation states of a MiniGrid layout (columns in the module docstring).

    Parameters
    ----------
    states : ndarray of int, shape (S, 3)
        Rows ``(x, y, direction)``.
    objects : ndarray of int, shape (m, 4)
        Rows ``(x, y, colour, type)`` as returned by :func:`grid_objects`.
    grid : minigrid.core.grid.Grid
        The layout's grid (read for the faced cells).
    thresholds : tuple of float, default=DEFAULT_THRESHOLDS

    Returns
    -------
    features : ndarray of float64, shape (S, 37 + 10 * len(thresholds))
        Entries 0 or 1.
    """
    thresholds = _check_thresholds(thresholds)
    states = np.asarray(states, dtype=np.int64).reshape(-1, 3)
    diff = states[:, None, :2] - objects[None, :, :2]
    dist = np.sqrt((diff * diff).sum(axis=2))  # (S, m)
    groups = [objects[:, 2] == c for c in range(len(COLOURS))] + [objects[:, 3] == t for t in range(len(OBJECT_TYPES))]
    nearest = np.column_stack([dist[:, g].min(axis=1) if g.any() else np.full(len(states), np.inf) for g in groups])
    near = (nearest[:, :, None] < np.asarray(thresholds)[None, None, :]).reshape(len(states), -1)
    return np.hstack([_front_columns(states, grid), near.astype(np.float64)])


def parse_goto_mission(mission: str) -> tuple[str | None, str]:
    """The (colour, type) of a BabyAI GoTo mission such as "go to the red key".

    Parameters
    ----------
    mission : str
        "go to the|a [colour] type", colour one of :data:`COLOURS` and type one of
        :data:`OBJECT_TYPES` (surrounding white space is ignored).

    Returns
    -------
    colour : str or None
        None when the mission names no colour ("go to the ball": any ball will do).
    type : str

    Raises
    ------
    ValidationError
        The mission is not of that form (other verbs, locations such as "on your left",
        sequences joined by "and"/"then", unknown colours or types).
    """
    if not isinstance(mission, str):
        raise ValidationError(f"mission must be a string; got {type(mission).__name__}")
    match = _MISSION.fullmatch(mission.strip())
    if match is None:
        raise ValidationError(
            f"mission {mission!r} is not a BabyAI GoTo mission 'go to the|a [colour] type' with colour in "
            f"{COLOURS} and type in {OBJECT_TYPES}"
        )
    return match.group(1), match.group(2)
