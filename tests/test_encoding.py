"""solvers/encoding.py: each encoding's shape and range, the two task scalings as defined (constant
features: 0.5 in min-max, dropped in spread), the pad coordinates in the interval asked for, the pad
flags and a partial layout's "placed" flags, and a module that imports without torch."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from fixbench.cases import load_case_spec
from fixbench.cases.problem import Problem
from fixbench.solvers.encoding import (
    action_inputs,
    layout_inputs,
    min_max_loc_scale,
    pad_coordinates,
    pad_flags,
    robot_centres,
    task_features,
)


@pytest.fixture(scope="module")
def fan():
    return Problem(load_case_spec("fan_small", n_agents=2))


@pytest.fixture(scope="module")
def one_task():
    return Problem(load_case_spec("fan_small", n_agents=2).with_tasks([3]))


@pytest.fixture(scope="module")
def pads():
    """4 robots, 3 pads, idle allowed: some options place no pad."""
    return Problem(load_case_spec("wing_panel_pads_small"))


def test_min_max_features_span_zero_to_one_and_constant_features_sit_at_a_half(fan, one_task):
    f = task_features(fan, "min-max")
    assert f.shape == (fan.n_tasks, fan.features.shape[1]) and f.dtype == np.float64
    varies = np.ptp(fan.features, axis=0) > 0
    assert varies.any()
    assert np.all(f[:, varies].min(axis=0) == 0) and np.all(f[:, varies].max(axis=0) == 1)
    assert np.all(f[:, ~varies] == 0.5)
    assert np.all(task_features(one_task, "min-max") == 0.5)  # every feature constant over one task


def test_spread_features_are_the_features_over_their_spread_constant_columns_dropped(fan, one_task):
    raw = np.asarray(fan.features, dtype=float)
    spread = raw.max(axis=0) - raw.min(axis=0)
    f = task_features(fan, "spread")
    np.testing.assert_array_equal(f, raw[:, spread > 0] / spread[spread > 0])
    np.testing.assert_allclose(np.ptp(f, axis=0), 1.0)
    # a task's distance to another is the same under both scalings (a shift changes no difference)
    mm = task_features(fan, "min-max")[:, spread > 0]
    np.testing.assert_allclose(f - f[0], mm - mm[0], atol=1e-12)
    np.testing.assert_array_equal(task_features(one_task, "spread"), np.zeros((1, 1)))
    with pytest.raises(ValueError, match="min-max, spread"):
        task_features(fan, "z-score")


def test_min_max_loc_scale_is_the_min_max_in_the_dtype_asked_for(fan, one_task):
    loc, scale = min_max_loc_scale(fan, np.float32)
    assert loc.dtype == scale.dtype == np.float32 and loc.shape == scale.shape == (fan.features.shape[1],)
    x = (fan.features.astype(np.float32) - loc) / scale
    np.testing.assert_allclose(x, task_features(fan, "min-max"), atol=1e-6)
    loc, scale = min_max_loc_scale(one_task, np.float32)
    assert np.all(scale == 1) and np.all(one_task.features.astype(np.float32) - loc == 0)  # constant -> 0


@pytest.mark.parametrize("interval", [(0.0, 1.0), (-1.0, 1.0)])
def test_pad_coordinates_map_the_candidates_bounding_box_to_the_interval(fan, pads, interval):
    a, b = interval
    for p in (fan, pads):
        xy = pad_coordinates(p, interval)
        assert xy.shape == p.points.shape
        per_axis = xy.reshape(len(xy), -1, 2)
        # the candidates' extremes land on the interval's ends; "no pad" centroids lie inside
        assert np.all(per_axis.min(axis=(0, 1)) == a) and np.all(per_axis.max(axis=(0, 1)) == b)
    np.testing.assert_array_equal(pad_coordinates(fan, (-1.0, 1.0)), 2 * pad_coordinates(fan, (0.0, 1.0)) - 1)
    with pytest.raises(ValueError, match="lo < hi"):
        pad_coordinates(fan, (1.0, 0.0))


def test_pad_flags_mark_the_pads_an_option_places(fan, pads):
    flags = pad_flags(pads)
    assert flags.shape == pads.options.shape
    np.testing.assert_array_equal(flags == 1, pads.options >= 0)
    assert (flags == 0).any()  # the idle options
    assert action_inputs(fan, (0.0, 1.0)).shape[1] == 2  # simple effector: every flag 1, left out
    np.testing.assert_array_equal(action_inputs(pads, (0.0, 1.0)),
                                  np.concatenate([pad_coordinates(pads, (0.0, 1.0)), flags], axis=1))


def test_a_partial_layouts_flags_mark_exactly_the_placed_robots(pads):
    acts = action_inputs(pads, (0.0, 1.0))
    d = acts.shape[1]
    layouts = np.array([[pads.action_sets[0][2], -1, pads.action_sets[2][0], -1],
                        [-1, -1, -1, -1],
                        [s[-1] for s in pads.action_sets]])
    x = layout_inputs(pads, layouts, (0.0, 1.0))
    assert x.shape == (3, pads.n_agents, d + 1)
    np.testing.assert_array_equal(x[..., -1], (layouts >= 0).astype(float))
    placed = layouts >= 0
    np.testing.assert_array_equal(x[placed][:, :d], acts[layouts[placed]])
    centres = robot_centres(pads, acts)
    coords = pad_coordinates(pads, (0.0, 1.0)).shape[1]
    for r, i in zip(*np.nonzero(~placed)):
        np.testing.assert_array_equal(x[r, i, :coords], centres[i, :coords])  # waits at its set's centre
        assert np.all(x[r, i, coords:] == 0)  # no pad placed, not placed itself
    np.testing.assert_array_equal(layout_inputs(pads, layouts[2], (0.0, 1.0)), x[2:])  # one layout: B = 1


def test_the_module_imports_without_torch():
    code = "import sys, fixbench.solvers.encoding; sys.exit('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code]).returncode == 0
