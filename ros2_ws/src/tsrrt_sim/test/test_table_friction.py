"""The sim's own table friction: Coulomb per footprint cell, sticking, no preferred direction."""

import math

import numpy as np
import pytest

from tsrrt_sim.table_friction import GRAVITY, SlidingBody, footprint_cells

STEP = 1.0 / 240.0


def remote(mu=0.2):
    cells = footprint_cells("box", 0.18, 0.045)
    return SlidingBody(mass=0.15, inertia_z=0.15 * (0.18 ** 2 + 0.045 ** 2) / 12.0, mu=mu,
                       half_height=0.01, rest_z=0.01, cells=cells)


def test_box_cells_cover_the_footprint_evenly():
    cells = footprint_cells("box", 0.18, 0.045, spacing=0.01)
    assert len(cells) == 18 * 5
    np.testing.assert_allclose(cells.mean(axis=0), 0.0, atol=1e-12)
    assert cells[:, 0].max() == pytest.approx(0.09 - 0.005)
    assert cells[:, 1].max() == pytest.approx(0.0225 - 0.0045)


def test_disc_cells_lie_inside_the_disc():
    cells = footprint_cells("cylinder", 0.10, 0.10)
    assert np.hypot(cells[:, 0], cells[:, 1]).max() <= 0.05
    # About the disc's share of its bounding square.
    assert len(cells) / 100 == pytest.approx(math.pi / 4, abs=0.05)


@pytest.mark.parametrize("heading", [0.0, 0.4, 1.0, math.pi / 4])
@pytest.mark.parametrize("direction", [0.0, 0.7, 2.0])
def test_sliding_friction_opposes_the_motion_whatever_the_heading(heading, direction):
    body = remote()
    velocity = 0.05 * np.array([math.cos(direction), math.sin(direction)])
    force, torque = body.wrench(heading, velocity, 0.0, STEP)
    np.testing.assert_allclose(force, -body.mu * body.mass * GRAVITY * velocity / 0.05,
                               atol=1e-12)
    assert torque == pytest.approx(0.0, abs=1e-12)


def test_turning_in_place_is_resisted_by_a_torque_alone():
    body = remote()
    force, torque = body.wrench(0.3, np.zeros(2), 1.0, STEP)
    np.testing.assert_allclose(force, 0.0, atol=1e-12)
    # Uniform pressure: mu m g times the mean distance of the footprint from its centre.
    mean_radius = np.hypot(body.cells[:, 0], body.cells[:, 1]).mean()
    assert torque == pytest.approx(-body.mu * body.mass * GRAVITY * mean_radius)


def test_a_body_friction_can_stop_within_the_step_is_stopped_exactly():
    body = remote()
    velocity = np.array([0.003, -0.002])    # below mu g dt = 8 mm/s
    force, torque = body.wrench(0.0, velocity, 0.01, STEP)
    np.testing.assert_allclose(force * STEP / body.mass, -velocity)
    assert torque * STEP / body.inertia_z == pytest.approx(-0.01)
