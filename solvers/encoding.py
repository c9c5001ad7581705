"""The planners' inputs as numbers: a task (its features) and a layout (its pads' coordinates and flags).

Every planner that feeds a model encodes its inputs here, numpy in and numpy out (no torch, so that a
light caller need not import it); each function names its scaling or takes its range as an argument,
and none changes a number that a planner has been run with (a run's bits depend on them).

Tasks: :func:`task_features` (T, F), ``Problem.features`` scaled over the problem's tasks, one of two ways:

- ``scale="min-max"``: each column to [0, 1], ``(f - min) / (max - min)``; a column constant over the
  tasks -> 0.5 (the middle, not a 0 that would look like the lowest task). Every column is kept, so the
  width is the case's feature count. Users: ``vdn`` (solvers/learners/vdn.py) and ``nashq`` / ``iql``
  (:class:`fixbench.solvers.learners.marl_engine.Learner`): networks whose first layer wants inputs of one range.
- ``scale="spread"``: each column divided by its spread over the tasks, ``f / (max - min)``, not shifted
  (a column's values span exactly 1 wherever they lie); constant columns dropped (all constant: one zero
  column). Users: what measures distances between tasks or fits a kernel on them, where a shift does not
  matter and a constant column would only add a length scale to fit: the rounds bandits
  (solvers/bandits/bandit.py: ``surrogate-ts`` centres them, ``gp-ucb``'s feature kernel and its local windows),
  and the nearest-task search of solvers/transfer.py (the warm starts of the search planners with a
  ``transfer`` setting: ``greedy``, ``local``, ``ga``, ``pso``, ``optuna``, the bandits; and every
  planner's held-out layouts left at -1, filled from the nearest training task).
  Distances between tasks are the same under both scalings.
- :func:`min_max_loc_scale`: the same min-max as (loc, scale) in a chosen dtype, for a normaliser that
  takes them, ``(f - loc) / scale`` (a constant column's scale is 1, so it becomes 0, not 0.5). Users:
  the TorchRL learners ``mappo``, ``ippo`` and ``qmix`` (solvers/learners/torchrl_learner.py), deliberately: their
  env (cases/env.py, also the BenchMARL task) emits the raw features, and TorchRL's ``ObservationNorm``
  normalises them in float32 inside TorchRL's pipeline (qmix's mixer state is that observation too).

Layouts: an action's pads' (x, y) (``Problem.points``; a "no pad" sits at its robot's candidates'
centroid) in an interval of the candidates' bounding box (an axis without extent: divided by 1):

- :func:`pad_coordinates` (options, 2 m), ``interval`` named by the caller: ``(0, 1)`` for ``vdn`` and
  ``nashq`` / ``iql`` (the min-max range of their task features), ``(-1, 1)`` for ``surrogate-ts`` and
  ``gp-ucb`` (centred, as a Gaussian process's inputs and a ReLU ensemble's like them);
- :func:`pad_flags` (options, m): 1 where the option places its pad k, 0 for a "no pad" (idle robots,
  pad limits): the flag tells a "no pad" from a pad that happens to lie at the centroid;
- :func:`action_inputs`: the coordinates, and the flags when the case's effector is not simple (one pad,
  never idle, no limit: every flag would be 1). ``vdn`` uses it. On a pair effector without idle the
  flags are 1 too; they stay, as vdn has always had them there. ``nashq`` / ``iql`` use the coordinates
  alone: their own action is an output head, not an input, and nashq's joint input (the other robots'
  coordinates) has never had flags;
- :func:`robot_centres` (N, D): each robot's inputs averaged over its action set, where a robot not yet
  placed sits (nashq's best response starts the robots it has not chosen there);
- :func:`layout_inputs` (B, N, D + 1): a partial layout (global actions, -1: robot not placed yet), each
  robot its :func:`action_inputs` row (a robot not placed: its centre, pad flags 0) and a last column 1
  if the robot is placed, else 0. For a learner that places robots one after another; every learner
  here places all robots at once (one env step), so it has no partial layouts, that flag would be a
  constant 1, and none of them adds it.

Case-based retrieval (solvers/knowledge/cbr.py ``task_features``: a case's part, material and task) encodes a
different thing, one case of a library against another, and stays there.
"""

from __future__ import annotations

import numpy as np

from fixbench.cases.problem import Problem

SCALES = ("min-max", "spread")
"""The scalings :func:`task_features` knows."""


# ---------------------------------------------------------------------------------------------
# tasks
# ---------------------------------------------------------------------------------------------
def _min_max(problem: Problem, dtype) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(features, min, max - min) over the tasks, computed in ``dtype``."""
    f = np.asarray(problem.features, dtype=dtype).reshape(problem.n_tasks, -1)
    return f, f.min(axis=0), np.ptp(f, axis=0)


def task_features(problem: Problem, scale: str) -> np.ndarray:
    """(T, F) task features scaled over the problem's tasks, float64: ``scale`` "min-max" (to [0, 1],
    constant columns 0.5) or "spread" (divided by the spread, constant columns dropped); see the module
    docstring."""
    if scale not in SCALES:
        raise ValueError(f"scale must be one of {', '.join(SCALES)}, got '{scale}'")
    f, lo, span = _min_max(problem, np.float64)
    if scale == "min-max":
        return np.where(span > 0, (f - lo) / np.where(span > 0, span, 1), 0.5)
    keep = span > 0
    return f[:, keep] / span[keep] if keep.any() else np.zeros((problem.n_tasks, 1))


def min_max_loc_scale(problem: Problem, dtype=np.float32) -> tuple[np.ndarray, np.ndarray]:
    """(loc, scale) (F,) in ``dtype`` such that ``(features - loc) / scale`` is the min-max scaling in [0, 1],
    a constant column's scale 1 (so it becomes 0)."""
    _, lo, span = _min_max(problem, dtype)
    return lo, np.where(span > 0, span, span.dtype.type(1))


# ---------------------------------------------------------------------------------------------
# layouts
# ---------------------------------------------------------------------------------------------
def pad_coordinates(problem: Problem, interval: tuple[float, float]) -> np.ndarray:
    """(options, 2 m) every option's pads' (x, y), the candidates' bounding box mapped to ``interval``
    (lo, hi) on each axis (an axis without extent: divided by 1)."""
    a, b = interval
    if not a < b:
        raise ValueError(f"interval must be (lo, hi) with lo < hi, got {interval}")
    lo, hi = problem.candidates.min(axis=0), problem.candidates.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    n_opt = len(problem.points)
    unit = (problem.points.reshape(n_opt, -1, 2) - lo) / span
    return (a + (b - a) * unit).reshape(n_opt, -1)


def pad_flags(problem: Problem) -> np.ndarray:
    """(options, m) 1.0 where the option places its pad k, 0.0 for a "no pad"."""
    return (problem.options >= 0).astype(np.float64)


def action_inputs(problem: Problem, interval: tuple[float, float]) -> np.ndarray:
    """(options, D) an action as inputs: :func:`pad_coordinates` in ``interval``, then :func:`pad_flags`
    unless the effector is simple (D = 2 m, or 3 m)."""
    pos = pad_coordinates(problem, interval)
    if problem.spec.effector.simple:
        return pos
    return np.concatenate([pos, pad_flags(problem)], axis=1)


def robot_centres(problem: Problem, inputs: np.ndarray) -> np.ndarray:
    """(N, D) each robot's rows of ``inputs`` (options, D) averaged over its action set."""
    return np.stack([inputs[s].mean(axis=0) for s in problem.action_sets])


def layout_inputs(problem: Problem, layouts: np.ndarray, interval: tuple[float, float]) -> np.ndarray:
    """(B, N, D + 1) partial layouts (B, N) of global actions, -1 where a robot is not placed yet: each
    robot's :func:`action_inputs` row, a robot not placed at its coordinates' centre with pad flags 0,
    then 1.0 if the robot is placed, else 0.0."""
    layouts = np.atleast_2d(np.asarray(layouts, dtype=np.int64))
    acts = action_inputs(problem, interval)
    coords = pad_coordinates(problem, interval).shape[1]
    waiting = robot_centres(problem, acts)
    waiting[:, coords:] = 0.0
    placed = layouts >= 0
    rows = np.where(placed[..., None], acts[np.maximum(layouts, 0)], waiting[None])
    return np.concatenate([rows, placed[..., None].astype(np.float64)], axis=2)
