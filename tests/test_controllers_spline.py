"""SplinePlan: the interpolation matrix S and the warm-start shift."""

import numpy as np
import pytest

from controllers import SplinePlan


@pytest.mark.parametrize("kind", ["cubic", "linear"])
@pytest.mark.parametrize("knots", [1, 2, 3, 5, 9])
def test_S_reproduces_constant_and_linear_signals_exactly(kind, knots):
    plan = SplinePlan(horizon=33, knots=knots, control_dim=2, kind=kind)
    times = plan.spacing * np.arange(knots) if knots > 1 else np.zeros(1)
    level, slope = np.array([0.3, -0.7]), np.array([0.01, -0.02])
    plan.knots = np.tile(level, (knots, 1))
    np.testing.assert_allclose(plan.controls(), np.tile(level, (33, 1)), rtol=0, atol=1e-15)
    if knots > 1:
        plan.knots = level + times[:, None] * slope
        expected = level + np.arange(33)[:, None] * slope
        np.testing.assert_allclose(plan.controls(), expected, rtol=0, atol=1e-14)
    # The paper's S (HC x KC) acts on the row-major stacked knots.
    s = plan.full_matrix()
    assert s.shape == (33 * 2, knots * 2)
    np.testing.assert_allclose(s @ plan.knots.ravel(), plan.controls().ravel(), atol=1e-14)


def test_cubic_passes_through_its_knots_and_periodic_plans_repeat():
    rng = np.random.default_rng(0)
    plan = SplinePlan(horizon=41, knots=5, control_dim=3)
    plan.knots = rng.uniform(-1, 1, (5, 3))
    np.testing.assert_allclose(plan.controls()[::10], plan.knots, atol=1e-15)
    periodic = SplinePlan(horizon=50, knots=8, control_dim=3, period=20)
    periodic.knots = rng.uniform(-1, 1, (8, 3))
    u = periodic.controls()
    np.testing.assert_allclose(u[20:40], u[:20], atol=1e-14)
    np.testing.assert_allclose(u[0:20:5][:, 0], periodic.knots[0:8:2, 0], atol=1e-14)


def test_shift_keeps_the_future_values():
    rng = np.random.default_rng(1)
    periodic = SplinePlan(horizon=40, knots=6, control_dim=2, period=24)
    periodic.knots = rng.uniform(-1, 1, (6, 2))
    before = periodic.controls()
    after = periodic.copy()
    after.shift(7)
    np.testing.assert_allclose(after.controls()[:33], before[7:], atol=1e-14)
    # A linear open plan shifted by whole knot intervals: exact, then the last value held.
    linear = SplinePlan(horizon=41, knots=5, control_dim=2, kind="linear")
    linear.knots = rng.uniform(-1, 1, (5, 2))
    before = linear.controls()
    linear.shift(20)
    np.testing.assert_allclose(linear.controls()[:21], before[20:], atol=1e-14)
    np.testing.assert_allclose(linear.controls()[21:], np.tile(before[-1], (20, 1)), atol=1e-14)
    # A cubic open plan keeps its values at the new knot times.
    cubic = SplinePlan(horizon=41, knots=5, control_dim=2)
    cubic.knots = rng.uniform(-1, 1, (5, 2))
    before = cubic.controls()
    cubic.shift(13)
    np.testing.assert_allclose(cubic.controls()[[0, 10, 20]], before[[13, 23, 33]], atol=1e-14)
    np.testing.assert_allclose(cubic.value(0.0), before[13], atol=1e-14)
    # One open knot holds its value over the horizon; a shift keeps it (and warns of nothing).
    single = SplinePlan(horizon=10, knots=1, control_dim=3)
    single.knots = rng.uniform(-1, 1, (1, 3))
    held = single.knots.copy()
    single.shift(1)
    np.testing.assert_allclose(single.knots, held, atol=1e-14)


@pytest.mark.parametrize("kind", ["cubic", "linear"])
def test_an_open_plan_stepped_one_step_at_a_time_sends_the_controls_it_was_scored_on(kind):
    # shift(1) at every step re-sampled the knots each time, and the errors compounded: the
    # tenth control was 0.5 of the bound away from the plan's own tenth
    rng = np.random.default_rng(2)
    plan = SplinePlan(horizon=40, knots=6, control_dim=2, kind=kind)
    plan.knots = rng.uniform(-1, 1, (6, 2))
    scored = plan.controls()
    sent = []
    for _ in range(40):
        sent.append(plan.value(0.0))
        plan.shift(1)
    np.testing.assert_allclose(np.array(sent), scored, atol=1e-14)
    # the warm start moves the knots to the clock: exact at the new knot times
    plan.rebase()
    assert plan.offset == 0.0
    np.testing.assert_allclose(plan.knots, np.tile(scored[-1], (6, 1)), atol=1e-14)
    again = SplinePlan(horizon=40, knots=6, control_dim=2, kind=kind)
    again.knots = rng.uniform(-1, 1, (6, 2))
    before = again.controls()
    again.shift(3)
    again.rebase()
    np.testing.assert_allclose(again.controls()[[0, 39]], before[[3, 39]], atol=1e-14)


def test_a_periodic_cubic_is_catmull_rom_in_every_segment_including_the_wrap():
    # Midway between knots j and j + 1 the Catmull-Rom spline is (-p_{j-1} + 9 p_j + 9 p_{j+1}
    # - p_{j+2}) / 16, indices modulo K. Guards the last segment, from knot K - 1 to the next
    # cycle's knot 0: evaluated by the segment before it (extrapolated), it would still pass
    # through the knots but not between them.
    rng = np.random.default_rng(3)
    plan = SplinePlan(horizon=16, knots=4, control_dim=2, period=8)  # a knot every 2 steps
    plan.knots = p = rng.uniform(-1, 1, (4, 2))
    mid = (-np.roll(p, 1, 0) + 9 * p + 9 * np.roll(p, -1, 0) - np.roll(p, -2, 0)) / 16
    u = plan.controls()
    np.testing.assert_allclose(u[0:8:2], p, rtol=0, atol=1e-15)
    np.testing.assert_allclose(u[1:8:2], mid, rtol=0, atol=1e-15)
    np.testing.assert_allclose(u[8:], u[:8], rtol=0, atol=1e-15)


@pytest.mark.parametrize("period", [None, 7.5])
def test_value_reads_the_plan_any_steps_ahead_and_a_zero_shift_keeps_it(period):
    # value(step) is the control ``step`` env steps after the clock, controls()[step] (the
    # planners read value(0) only, so one that ignored step passed every other test); shift(0),
    # a finite number >= 0, changes nothing
    rng = np.random.default_rng(4)
    plan = SplinePlan(horizon=12, knots=4, control_dim=2, period=period)
    plan.knots = rng.uniform(-1, 1, (4, 2))
    plan.shift(3)
    u = plan.controls()
    for step in (0, 1, 5, 11):
        np.testing.assert_allclose(plan.value(step), u[step], rtol=0, atol=1e-15)
    plan.shift(0)
    assert plan.offset == 3.0
    np.testing.assert_array_equal(plan.controls(), u)


def test_bad_plans_raise_errors_naming_the_value():
    with pytest.raises(ValueError, match="horizon must be a positive integer, got 0"):
        SplinePlan(0, 2, 3)
    with pytest.raises(ValueError, match=r"knots = 9 exceeds the horizon \(8 steps\)"):
        SplinePlan(8, 9, 3)
    with pytest.raises(ValueError, match=r"knots = 9 exceeds the period \(6 steps\)"):
        SplinePlan(20, 9, 3, period=6)
    with pytest.raises(
        ValueError, match="kind must be one of \\['cubic', 'linear'\\], got 'quintic'"
    ):
        SplinePlan(8, 2, 3, kind="quintic")
    with pytest.raises(ValueError, match="steps must be a finite number >= 0, got -1"):
        SplinePlan(8, 2, 3).shift(-1)
