"""Tests for priortrack.geometry.sphere: geometry on (S^2)^K."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from priortrack.errors import PriortrackError
from priortrack.geometry.sphere import (
    distance,
    exp_map,
    karcher_mean,
    log_map,
    project_to_tangent,
    sphere_angles,
    transport,
)

MAX_ROUND_TRIP_NORM = math.pi - 1e-3

# ---------------------------------------------------------------------------
# Strategies (numpy float64; converted to torch in the tests)
# ---------------------------------------------------------------------------

batch_shapes = st.tuples(st.integers(1, 3), st.integers(1, 3))  # (B, K)


@st.composite
def unit_points(draw, shape):
    """Unit vectors of shape (*shape, 3) from polar/azimuth angles (no rejection)."""
    polar = draw(hnp.arrays(np.float64, shape, elements=st.floats(0.0, math.pi)))
    azimuth = draw(hnp.arrays(np.float64, shape, elements=st.floats(0.0, 2 * math.pi)))
    points = np.stack(
        [np.sin(polar) * np.cos(azimuth), np.sin(polar) * np.sin(azimuth), np.cos(polar)], axis=-1
    )
    return points / np.linalg.norm(points, axis=-1, keepdims=True)


def tangent_basis(x):
    """Orthonormal tangent basis (e1, e2) at each row of x, built independently in numpy."""
    helper = np.where(np.abs(x[..., :1]) < 0.9, [1.0, 0.0, 0.0], [0.0, 1.0, 0.0])
    e1 = helper - np.sum(helper * x, axis=-1, keepdims=True) * x
    e1 /= np.linalg.norm(e1, axis=-1, keepdims=True)
    return e1, np.cross(x, e1)


@st.composite
def tangent_vectors(draw, x, max_norm=MAX_ROUND_TRIP_NORM):
    """Tangent vectors at x with per-sphere norm in [0, max_norm]."""
    shape = x.shape[:-1]
    norms = draw(hnp.arrays(np.float64, shape, elements=st.floats(0.0, max_norm)))
    angles = draw(hnp.arrays(np.float64, shape, elements=st.floats(0.0, 2 * math.pi)))
    e1, e2 = tangent_basis(x)
    return norms[..., None] * (np.cos(angles)[..., None] * e1 + np.sin(angles)[..., None] * e2)


@st.composite
def point_pairs(draw):
    shape = draw(batch_shapes)
    return draw(unit_points(shape)), draw(unit_points(shape))


@st.composite
def point_and_tangent(draw, max_norm=MAX_ROUND_TRIP_NORM):
    x = draw(unit_points(draw(batch_shapes)))
    return x, draw(tangent_vectors(x, max_norm))


def random_unit(shape, seed=0):
    """Seeded random unit vectors of shape (*shape, 3) for the example-based tests."""
    points = np.random.default_rng(seed).normal(size=shape + (3,))
    return points / np.linalg.norm(points, axis=-1, keepdims=True)


def t(array):
    return torch.as_tensor(np.asarray(array), dtype=torch.float64)


def assert_close(actual, expected, atol):
    """Elementwise |actual - expected| <= atol; a number as ``expected`` is broadcast."""
    if not isinstance(expected, torch.Tensor):
        expected = torch.full_like(actual, expected)
    torch.testing.assert_close(actual, expected, rtol=0, atol=atol)


def row_dot(a, b):
    return (a * b).sum(dim=-1)


def reference_angles(x, y):
    """theta = atan2(|x × y|, x·y), computed independently in numpy."""
    return np.arctan2(np.linalg.norm(np.cross(x, y), axis=-1), np.sum(x * y, axis=-1))


# ---------------------------------------------------------------------------
# exp / log
# ---------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(point_pairs())
def test_exp_of_log_is_identity(pair):
    # All pairs, near-antipodal ones included (log_map keeps full precision up to -x).
    x, y = map(t, pair)
    assert_close(exp_map(x, log_map(x, y)), y, 1e-10)


@settings(max_examples=100, deadline=None)
@given(point_and_tangent())
def test_log_of_exp_is_identity(sample):
    x, v = map(t, sample)
    assert_close(log_map(x, exp_map(x, v)), v, 1e-10)


@settings(max_examples=100, deadline=None)
@given(point_and_tangent())
def test_exp_stays_on_sphere_and_moves_by_norm(sample):
    x, v = map(t, sample)
    y = exp_map(x, v)
    assert_close(y.norm(dim=-1), 1.0, 1e-14)
    assert_close(sphere_angles(x, y), v.norm(dim=-1), 1e-10)


@settings(max_examples=100, deadline=None)
@given(point_pairs())
def test_log_norm_is_angle_and_log_is_tangent(pair):
    x, y = map(t, pair)
    log = log_map(x, y)
    expected = t(reference_angles(*pair))
    assert_close(log.norm(dim=-1), expected, 1e-12)
    assert_close(sphere_angles(x, y), expected, 1e-12)
    assert_close(row_dot(x, log), 0.0, 1e-12)


@pytest.mark.parametrize("tiny_norm", [1e-9, 1e-300])
def test_exp_near_zero_is_x_plus_v(tiny_norm):
    x = t(random_unit((2, 4)))
    e1, e2 = tangent_basis(x.numpy())
    v = tiny_norm * t(0.6 * e1 + 0.8 * e2)
    expected = x + v
    error = (exp_map(x, v) - expected).norm(dim=-1)
    assert torch.all(error <= 1e-15 * expected.norm(dim=-1))


def test_log_of_identical_points_is_exactly_zero():
    x = t(random_unit((3, 5)))
    assert torch.equal(log_map(x, x.clone()), torch.zeros_like(x))
    assert torch.equal(distance(x, x.clone()), torch.zeros(3, dtype=x.dtype))


def test_log_near_zero_is_accurate():
    """theta/|w| -> 1: for y = x + d, d tiny, log_x(y) = d - (x·d)x to full relative precision."""
    x = random_unit((4, 3), seed=1)
    e1, e2 = tangent_basis(x)
    for scale in (1e-6, 1e-9, 1e-12, 1e-15):
        y = x + scale * (0.28 * e1 - 0.96 * e2 + 0.1 * x)
        chord = y - x  # exact in floating point (Sterbenz), so this is the true displacement
        expected = chord - np.sum(x * chord, axis=-1, keepdims=True) * x
        error = (log_map(t(x), t(y)) - t(expected)).norm(dim=-1)
        assert torch.all(error <= 1e-12 * t(expected).norm(dim=-1)), scale


def test_gradients_at_zero_are_finite():
    x = t([[0.0, 0.0, 1.0], [0.6, 0.0, 0.8]])
    v = torch.zeros_like(x, requires_grad=True)
    jacobian = torch.autograd.functional.jacobian(lambda tangent: exp_map(x, tangent), v)
    assert_close(jacobian.reshape(6, 6), torch.eye(6, dtype=x.dtype), 0)

    exp_map(x, v).sum().backward()
    assert torch.equal(v.grad, torch.ones_like(x))

    for target in (x, -x):  # identical and antipodal points
        y = target.clone().requires_grad_(True)
        loss = log_map(x, y).sum() + distance(x, y).sum() + transport(x, y, x.roll(1, -1)).sum()
        loss.backward()
        assert torch.isfinite(y.grad).all()


@pytest.mark.parametrize(
    "x",
    [
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, 0.0, -1.0],
        [0.48, 0.6, 0.64],
        [-0.36, 0.48, -0.8],
    ],
)
def test_log_of_antipode(x):
    x = t([x]) / t([x]).norm(dim=-1, keepdim=True)
    log = log_map(x, -x)
    assert abs(float(log.norm()) - math.pi) <= 1e-12
    assert abs(float(row_dot(x, log))) <= 1e-15
    assert_close(exp_map(x, log), -x, 1e-12)
    assert torch.equal(log, log_map(x.clone(), -x.clone()))
    axis = np.eye(3)[np.argmin(np.abs(x.numpy()[0]))]
    direction = np.cross(x.numpy()[0], axis)
    assert_close(log[0], t(math.pi * direction / np.linalg.norm(direction)), 1e-14)
    assert float(sphere_angles(x, -x)) == pytest.approx(math.pi, abs=1e-15)


def test_log_close_to_antipode_points_at_target():
    x = t([[0.0, 0.0, 1.0]])
    for gap in (1e-4, 1e-8, 1e-12):
        y = exp_map(x, t([[math.pi - gap, 0.0, 0.0]]))
        log = log_map(x, y)
        assert_close(log, t([[math.pi - gap, 0.0, 0.0]]), 1e-12)


# ---------------------------------------------------------------------------
# distance
# ---------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_distance_is_a_metric(data):
    shape = data.draw(batch_shapes)
    x, y, z = (t(data.draw(unit_points(shape))) for _ in range(3))
    d_xy, d_yx = distance(x, y), distance(y, x)
    assert d_xy.shape == shape[:1]
    assert_close(d_xy, d_yx, 1e-14)
    assert torch.all(distance(x, x) == 0)
    assert torch.all(d_xy <= distance(x, z) + distance(z, y) + 1e-12)
    expected = np.sqrt(np.sum(reference_angles(x.numpy(), y.numpy()) ** 2, axis=-1))
    assert_close(d_xy, t(expected), 1e-12)


def test_distance_known_values():
    x = t([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    y = t([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0]])
    assert_close(sphere_angles(x, y), t([math.pi / 2, math.pi]), 1e-15)
    assert float(distance(x, y)) == pytest.approx(math.sqrt(1.25) * math.pi, abs=1e-15)


# ---------------------------------------------------------------------------
# Karcher mean
# ---------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_karcher_mean_of_symmetric_points_is_centre(data):
    shape = data.draw(batch_shapes)
    centre = data.draw(unit_points(shape))
    pairs = data.draw(st.integers(1, 3))
    points, weights = [], []
    for _ in range(pairs):
        offset = data.draw(tangent_vectors(centre, max_norm=1.2))
        weight = data.draw(st.floats(0.1, 1.0))
        points += [exp_map(t(centre), t(offset)), exp_map(t(centre), -t(offset))]
        weights += [weight, weight]
    mean = karcher_mean(torch.stack(points), t(weights))
    assert_close(mean, t(centre), 1e-10)


def test_karcher_mean_of_single_point_is_that_point():
    x = t(random_unit((2, 4)))
    assert_close(karcher_mean(x[None]), x, 1e-15)
    assert_close(karcher_mean(x[None], [3.0]), x, 1e-15)


@settings(max_examples=100, deadline=None)
@given(point_and_tangent(max_norm=2.5), st.floats(0.0, 1.0))
def test_weighted_mean_of_two_points_lies_on_geodesic(sample, fraction):
    x, v = map(t, sample)
    y = exp_map(x, v)
    mean = karcher_mean(torch.stack([x, y]), t([1.0 - fraction, fraction]))
    assert_close(mean, exp_map(x, fraction * log_map(x, y)), 1e-10)


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_karcher_mean_satisfies_first_order_condition(data):
    shape = data.draw(batch_shapes)
    centre = data.draw(unit_points(shape))
    count = data.draw(st.integers(2, 6))
    offsets = [t(data.draw(tangent_vectors(centre, max_norm=1.0))) for _ in range(count)]
    points = torch.stack([exp_map(t(centre), offset) for offset in offsets])
    weights = t(data.draw(hnp.arrays(np.float64, (count,), elements=st.floats(0.0, 1.0))))
    weights[0] += 0.1  # not all zero
    mean = karcher_mean(points, weights)
    residual = ((weights / weights.sum())[:, None, None, None] * log_map(mean, points)).sum(dim=0)
    assert float(residual.norm(dim=-1).max()) <= 1e-10
    assert_close(mean.norm(dim=-1), 1.0, 1e-14)


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
@pytest.mark.parametrize("spread", [1e-9, 1e-4, 0.1, 1.5])
def test_fast_mean_step_equals_the_sum_of_logs(spread, dtype):
    """The batched step Σ_i a_i x_i − (Σ_i a_i c_i) μ (points within 90° of μ) against Σ_i w_i log_μ(x_i)
    from log_map, including the Taylor branch (spread 1e-9: c rounds to 1). With θ/sin θ in float32
    (float32 points) the step moves by float32's relative rounding of the angles, no more."""
    from priortrack.geometry.sphere import _mean_step

    gen = torch.Generator().manual_seed(1)
    mean = torch.nn.functional.normalize(torch.randn(5, 3, dtype=torch.float64, generator=gen), dim=-1)
    directions = torch.nn.functional.normalize(
        project_to_tangent(mean, torch.randn(400, 5, 3, dtype=torch.float64, generator=gen)), dim=-1)
    angles = spread * torch.rand(400, 5, 1, dtype=torch.float64, generator=gen)
    points = exp_map(mean, angles * directions)
    weights = torch.rand(400, dtype=torch.float64, generator=gen)
    weights /= weights.sum()
    expected = (weights[:, None, None] * log_map(mean, points)).sum(0)
    step = _mean_step(mean, points.permute(1, 2, 0).contiguous(), weights, dtype)
    assert step.dtype == torch.float64
    assert_close(step, expected, 1e-15 + (1e-13 if dtype == torch.float64 else 2e-7) * spread)


def test_karcher_mean_of_many_float32_points_converges_to_the_float64_mean(caplog):
    """10⁴ float32 points: the iteration runs in float64 (a float32 sum would stall above the
    float32 tolerance), converges without a warning and agrees with the float64 mean."""
    gen = torch.Generator().manual_seed(3)
    centre = torch.nn.functional.normalize(torch.randn(14, 3, dtype=torch.float64, generator=gen), dim=-1)
    points = exp_map(centre, project_to_tangent(centre, 0.2 * torch.randn(10_000, 14, 3, dtype=torch.float64,
                                                                                generator=gen)))
    weights = torch.rand(10_000, dtype=torch.float64, generator=gen)
    with caplog.at_level("WARNING", logger="priortrack.geometry.sphere"):
        mean32 = karcher_mean(points.float(), weights.float())
    assert "no convergence" not in caplog.text and mean32.dtype == torch.float32
    assert_close(mean32.double(), karcher_mean(points, weights), 1e-6)


def test_fast_mean_step_declines_points_beyond_90_degrees():
    from priortrack.geometry.sphere import _mean_step

    mean = t([[0.0, 0.0, 1.0]])
    points = t([[[1.0, 0.0, 0.0]], [[0.0, 0.6, -0.8]]])
    assert _mean_step(mean, points.permute(1, 2, 0).contiguous(), t([0.5, 0.5]), torch.float64) is None


def test_karcher_mean_falls_back_to_heaviest_point_when_euclidean_mean_vanishes():
    x = t([[[0.0, 0.0, 1.0]], [[0.0, 0.0, -1.0]]])
    mean = karcher_mean(x)
    # Starts at the first (heaviest on ties) point, then moves half way along log_map's
    # deterministic antipodal geodesic (direction x × e_x = (0, 1, 0)) to the equator.
    assert_close(mean, t([[0.0, 1.0, 0.0]]), 1e-15)


def test_karcher_mean_warns_without_convergence(caplog):
    centre = t([[0.0, 0.0, 1.0]])
    offsets = t([[[1.0, 0.0, 0.0]], [[0.0, 0.5, 0.0]], [[-0.2, -0.3, 0.0]]])
    points = exp_map(centre, offsets)  # the Euclidean start is not the Karcher mean
    with caplog.at_level("WARNING", logger="priortrack.geometry.sphere"):
        karcher_mean(points, max_iter=1)
    assert "no convergence after 1 iterations" in caplog.text


# ---------------------------------------------------------------------------
# transport and projection
# ---------------------------------------------------------------------------


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_transport_is_an_isometry_onto_tangent_space(data):
    shape = data.draw(batch_shapes)
    x_np, y_np = data.draw(unit_points(shape)), data.draw(unit_points(shape))
    x, y = t(x_np), t(y_np)
    u, v = (t(data.draw(tangent_vectors(x_np, max_norm=3.0))) for _ in range(2))
    pu, pv = transport(x, y, u), transport(x, y, v)
    assert_close(pv.norm(dim=-1), v.norm(dim=-1), 1e-12)
    assert_close(row_dot(pu, pv), row_dot(u, v), 1e-12)
    assert_close(row_dot(y, pv), 0.0, 1e-12)


@settings(max_examples=100, deadline=None)
@given(point_and_tangent(), st.data())
def test_transport_matches_closed_form_along_geodesic(sample, data):
    x, step = map(t, sample)
    y = exp_map(x, step)
    v = t(data.draw(tangent_vectors(sample[0], max_norm=2.0)))
    moved = transport(x, y, v)
    # The geodesic's velocity is parallel: log_x(y) goes to -log_y(x).
    assert_close(transport(x, y, log_map(x, y)), -log_map(y, x), 1e-10)
    log_xy, log_yx = log_map(x, y), log_map(y, x)
    angle_sq = row_dot(log_xy, log_xy)[..., None]
    closed_form = v - row_dot(log_xy, v)[..., None] / angle_sq * (log_xy + log_yx)
    resolved = angle_sq > 1e-6  # the log form loses precision as theta -> 0
    mismatch = torch.where(resolved, moved - closed_form, torch.zeros_like(v))
    assert float(mismatch.abs().max()) <= 1e-10


@pytest.mark.parametrize("gap", [1e-4, 1e-9, 1e-15, 0.0])
def test_transport_near_antipode(gap):
    x = t(random_unit((50, 2), seed=2))
    e1, e2 = tangent_basis(x.numpy())
    direction = t(e1)
    y = exp_map(x, (math.pi - gap) * direction)
    v = t(0.7 * e1 - 1.3 * e2)
    moved = transport(x, y, v)
    assert_close(row_dot(y, moved), 0.0, 1e-13)
    assert_close(moved.norm(dim=-1), v.norm(dim=-1), 1e-13)
    if gap >= 1e-4:  # closer in, rounding y moves its geodesic by ~eps/gap
        angle = math.pi - gap
        along = row_dot(direction, v)[..., None]
        expected = v + along * ((math.cos(angle) - 1) * direction - math.sin(angle) * x)
        assert_close(moved, expected, 1e-11)


def test_transport_identity_and_antipode():
    x = t([[0.0, 0.0, 1.0], [0.48, 0.6, 0.64]])
    e1, e2 = tangent_basis(x.numpy())
    v = t(0.3 * e1 - 1.7 * e2)
    assert_close(transport(x, x.clone(), v), v, 1e-15)
    moved = transport(x, -x, v)
    direction = log_map(x, -x) / math.pi
    # Along log_map's antipodal geodesic the component along its direction flips.
    expected = v - 2 * row_dot(direction, v)[..., None] * direction
    assert_close(moved, expected, 1e-15)
    assert_close(row_dot(-x, moved), 0.0, 1e-15)
    assert_close(moved.norm(dim=-1), v.norm(dim=-1), 1e-15)


@settings(max_examples=100, deadline=None)
@given(st.data())
def test_project_to_tangent(data):
    shape = data.draw(batch_shapes)
    x = t(data.draw(unit_points(shape)))
    u = t(data.draw(hnp.arrays(np.float64, shape + (3,), elements=st.floats(-10, 10))))
    projected = project_to_tangent(x, u)
    assert_close(row_dot(x, projected), 0.0, 1e-12)
    assert_close(project_to_tangent(x, projected), projected, 1e-12)
    assert_close(projected + row_dot(x, u)[..., None] * x, u, 1e-12)


def test_works_in_float32_and_broadcasts():
    x = torch.tensor([[[0.0, 0.0, 1.0]]], dtype=torch.float32)  # (1, 1, 3)
    v = torch.tensor([[[0.1, 0.0, 0.0]], [[0.0, 0.2, 0.0]]], dtype=torch.float32)  # (2, 1, 3)
    y = exp_map(x, v)
    assert y.dtype == torch.float32 and y.shape == (2, 1, 3)
    assert_close(log_map(x, y), v, 1e-6)
    assert_close(distance(x, y), torch.tensor([0.1, 0.2]), 1e-6)
    mean = karcher_mean(y, tol=1e-6)
    assert mean.dtype == torch.float32 and mean.shape == (1, 3)


# ---------------------------------------------------------------------------
# Bad input
# ---------------------------------------------------------------------------

GOOD = torch.tensor([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0]], dtype=torch.float64)  # (K=2, 3)


POINTS = "(..., K, 3)"
CLOUD = "(N, ..., K, 3)"


@pytest.mark.parametrize(
    ("call", "name", "expected"),
    [
        (lambda: exp_map(torch.zeros(2, 4, dtype=torch.float64), GOOD), "x", POINTS),
        (lambda: exp_map(GOOD, torch.zeros(2, 2, dtype=torch.float64)), "v", POINTS),
        (lambda: exp_map(GOOD, torch.zeros(3, dtype=torch.float64)), "v", POINTS),
        (lambda: exp_map(GOOD, torch.zeros(2, 3, dtype=torch.int64)), "v", POINTS),
        (lambda: exp_map(GOOD.numpy(), GOOD), "x", POINTS),
        (lambda: log_map(GOOD, torch.zeros(3, 3, dtype=torch.float64)), "y", POINTS),
        (lambda: log_map(GOOD, torch.zeros(2, 5, dtype=torch.float64)), "y", POINTS),
        (lambda: distance(torch.zeros(2, 2, dtype=torch.float64), GOOD), "x", POINTS),
        (lambda: distance(GOOD, torch.zeros(4, 3, dtype=torch.float64)), "y", POINTS),
        (lambda: sphere_angles(GOOD, torch.zeros(1, 3, 3, dtype=torch.float64)), "y", POINTS),
        (lambda: transport(GOOD, GOOD, torch.zeros(3, 3, dtype=torch.float64)), "v", POINTS),
        (lambda: transport(GOOD, torch.zeros(2, 1, dtype=torch.float64), GOOD), "y", POINTS),
        (lambda: project_to_tangent(GOOD, torch.zeros(2, 2, dtype=torch.float64)), "u", POINTS),
        (lambda: karcher_mean(GOOD), "x", CLOUD),
        (lambda: karcher_mean(torch.zeros(3, 2, 4, dtype=torch.float64)), "x", CLOUD),
        (lambda: karcher_mean(torch.zeros(0, 2, 3, dtype=torch.float64)), "x", CLOUD),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), torch.ones(2)), "weights", "(3,)"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), torch.ones(3, 1)), "weights", "(3,)"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), [1.0, -0.5, 1.0]), "weights", "(3,)"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), [0.0, 0.0, 0.0]), "weights", "(3,)"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), [1.0, math.nan, 1.0]), "weights", "(3,)"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), ["a", "b", "c"]), "weights", "(3,)"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), tol=0.0), "tol", "positive"),
        (lambda: karcher_mean(GOOD.expand(3, 2, 3), max_iter=0), "max_iter", "positive"),
    ],
)
def test_bad_input_raises_naming_the_argument(call, name, expected):
    with pytest.raises(PriortrackError) as raised:
        call()
    message = str(raised.value)
    assert message.startswith(f"{name}:") or f" {name} " in message, message
    assert expected in message, message


def test_shape_mismatch_message_names_both_arguments_and_shapes():
    with pytest.raises(PriortrackError) as raised:
        log_map(GOOD, torch.zeros(3, 3, dtype=torch.float64))
    message = str(raised.value)
    assert "x" in message and "y" in message and "(2, 3)" in message and "(3, 3)" in message
    assert "(..., K, 3)" in message
