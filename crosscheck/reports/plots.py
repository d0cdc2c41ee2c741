"""The house style of the reports' figures (matplotlib), and the mechanism's stick figure.

Figures print at :data:`WIDTH_IN` inches wide with :data:`FONT_PT`-point text; legends sit outside the data (beside
or below the panels, :func:`legend_right`, :func:`legend_below`); each backend keeps one colour in every figure
(:func:`backend_colour`). (``crosscheck.checks.charts`` is about coordinate charts ``q = psi(p)``, not about figures.)

:func:`stick_points` and :func:`stick_figure`: the mechanism at a configuration, as a 3-D stick figure of its joint
origins and link segments from the reference's forward kinematics (Pinocchio on the model's data,
``crosscheck.references.pinocchio.build.to_pinocchio``), with the task point.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np
from crosscheck.references.pinocchio import kinematics

#: Width of a figure that fills a printed page's text width (inches), and of a one-column figure.
WIDTH_IN = 9.0
NARROW_IN = 7.0
FONT_PT = 9
DPI = 130
#: The backends in a fixed order, so that each keeps its colour across figures (others follow in order met).
BACKENDS = ("euler_lagrange", "newton_euler", "screw", "operational_space", "geometric", "pinocchio", "closed_form")


def pyplot():
    """matplotlib's pyplot on the file-only Agg backend, with the house font sizes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plt.rcParams.update({"font.size": FONT_PT, "axes.titlesize": FONT_PT + 1, "axes.labelsize": FONT_PT,
                         "legend.fontsize": FONT_PT - 1, "xtick.labelsize": FONT_PT - 1,
                         "ytick.labelsize": FONT_PT - 1})
    return plt


def backend_colour(name: str, others: Sequence[str] = ()):
    """The colour of backend ``name``: tab10 by its place in :data:`BACKENDS`, then among ``others``."""
    plt = pyplot()
    order = list(BACKENDS) + [n for n in others if n not in BACKENDS]
    index = order.index(name) if name in order else len(order)
    return plt.cm.tab10(index % 10)


def legend_right(fig, handles, title: str | None = None, width: float = 0.2) -> None:
    """One legend for the whole figure in a column right of the panels (the panels give up ``width`` of it)."""
    fig.legend(handles=handles, loc="center left", bbox_to_anchor=(1.0 - width + 0.01, 0.5), frameon=False,
               title=title)
    fig.subplots_adjust(right=1.0 - width)


def legend_below(fig, handles, columns: int = 4) -> None:
    """One legend for the whole figure in rows under the panels (a figure made with ``layout="constrained"`` makes
    room for it)."""
    fig.legend(handles=handles, loc="outside lower center", ncol=columns, frameon=False)


def save(fig, path: Path) -> Path:
    """Write ``fig`` to ``path`` and close it (a figure without a layout engine is cropped to what it draws, so that
    a legend right of it is kept)."""
    fig.savefig(path, dpi=DPI, bbox_inches=None if fig.get_layout_engine() else "tight")
    pyplot().close(fig)
    return Path(path)


# ---------------------------------------------------------------------------------------------- stick figure

def stick_points(model, q) -> tuple[np.ndarray, list[tuple[int, int]], np.ndarray, np.ndarray]:
    """The mechanism at ``q`` from the reference's forward kinematics
    (``crosscheck.references.pinocchio.kinematics.body_origins``): joint origins (bodies x 3, world frame, in body
    order), segments as (parent row, child row) pairs (-1: the world origin), the leaf bodies' centres of mass (where
    their links end; leaves x 3) and the task point."""
    origins, coms, task = kinematics.body_origins(model, q)
    leaves = [i for i in range(len(model.bodies)) if i not in model.parent_index]
    return origins, [(model.parent_index[i], i) for i in range(len(model.bodies))], coms[leaves], task


def stick_figure(model, q, path: Path, title: str = "") -> Path:
    """A 3-D stick figure of ``model`` at ``q`` (:func:`stick_points`): link segments between joint origins (from
    the world origin for a root body not on a free joint, to the centre of mass for a leaf body), joint origins as dots,
    the task point
    as a star (dashed to its body's origin), equal axis scales."""
    plt = pyplot()
    origins, segments, ends, task = stick_points(model, q)
    fig = plt.figure(figsize=(NARROW_IN * 0.8, NARROW_IN * 0.7))
    ax = fig.add_subplot(projection="3d")
    for parent, child in segments:
        if parent < 0 and model.bodies[child].joint == "free":
            continue                        # a floating base: nothing links it to the world
        start = np.zeros(3) if parent < 0 else origins[parent]
        ax.plot(*zip(start, origins[child]), color="0.3", lw=2)
    leaves = [i for i in range(len(model.bodies)) if i not in model.parent_index]
    for i, end in zip(leaves, ends):
        ax.plot(*zip(origins[i], end), color="0.3", lw=2)
    ax.scatter(*ends.T, color="0.3", s=12, depthshade=False, label="leaf centres of mass")
    body = model.body_index(model.task_point().body)
    ax.plot(*zip(origins[body], task), color="tab:red", lw=1, ls="--")
    ax.scatter(*origins.T, color="tab:blue", s=20, depthshade=False, label="joint origins")
    ax.scatter(*task, color="tab:red", marker="*", s=80, depthshade=False, label="task point")
    ax.scatter(0, 0, 0, color="black", marker="s", s=20, depthshade=False, label="world origin")
    points = np.vstack([origins, ends, task, np.zeros(3)])
    centre, half = (points.max(axis=0) + points.min(axis=0)) / 2, 0.55 * max(np.ptp(points, axis=0).max(), 2e-3)
    ax.set(xlim=(centre[0] - half, centre[0] + half), ylim=(centre[1] - half, centre[1] + half),
           zlim=(centre[2] - half, centre[2] + half), xlabel="x (m)", ylabel="y (m)", zlabel="z (m)", title=title)
    ax.set_box_aspect((1, 1, 1))
    ax.legend(loc="upper left", bbox_to_anchor=(1.05, 1.0), frameon=False)
    return save(fig, path)
