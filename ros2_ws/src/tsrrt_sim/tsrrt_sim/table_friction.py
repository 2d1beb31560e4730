"""Isotropic Coulomb friction between the objects and the table, computed by the sim itself.

Why not PyBullet's: Bullet solves a contact's friction as two constraints along axes fixed to the
world, each with its own effective mass, so a box sliding at an angle to those axes is steered
towards them (bullet3 issue #2590). Measured here with the arm: a 5 cm end-on push of the remote
ended 36 mm sideways per radian of the remote's heading on the table, so the same push on the
same object gave displacements 8.5 mm apart (std) depending only on where it happened to point,
which no object-frame model can learn. The table therefore has no friction in PyBullet, and
before every physics step the sim applies the friction of each object sliding on it:

- pressure uniform over the object's footprint (flat objects resting on the table, weight m g),
  sampled at the centres of a grid of cells of at most GRID_SPACING;
- at each cell, Coulomb friction mu * (its share of m g) opposing that cell's velocity
  (v + omega x r), summed into a force at the bottom face's centre and a torque about z;
- sticking: when that friction's impulse over one step would do more than stop the body (its
  projection on the generalised velocity exceeds the momentum m|v|^2 + I omega^2), the force and
  torque that stop it in this step are applied instead.

The friction coefficient is the product the scenario documents (object friction times table
friction). The other contacts (ball on object, object on object) keep PyBullet's friction.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

GRAVITY = 9.81
GRID_SPACING = 0.01   # metres between sample points of a footprint
# Height above its resting height (m) beyond which an object no longer rests on the table.
RESTING_TOLERANCE = 1e-3


def footprint_cells(shape: str, length: float, width: float,
                    spacing: float = GRID_SPACING) -> np.ndarray:
    """Centres (K, 2) of equal cells covering a footprint in the object frame.

    A box is divided into a regular grid; a disc keeps the cells of the grid over its bounding
    square whose centres lie inside it (equal cells, so each still carries an equal share).
    """
    columns = max(2, math.ceil(length / spacing))
    rows = max(2, math.ceil(width / spacing))
    xs = (np.arange(columns) + 0.5) / columns * length - length / 2.0
    ys = (np.arange(rows) + 0.5) / rows * width - width / 2.0
    cells = np.array([(x, y) for x in xs for y in ys])
    if shape == "cylinder":
        cells = cells[np.hypot(cells[:, 0], cells[:, 1]) <= length / 2.0]
    return cells


@dataclass(frozen=True)
class SlidingBody:
    """What friction needs to know of one object: its mass, inertia and footprint cells."""

    mass: float            # kg
    inertia_z: float       # kg m^2 about the vertical axis through the centre of mass
    mu: float              # object friction times table friction
    half_height: float     # m, from the centre to the bottom face
    rest_z: float          # height of the centre when resting on the table
    cells: np.ndarray      # (K, 2) object frame

    def wrench(self, yaw: float, velocity: np.ndarray, spin: float, time_step: float
               ) -> tuple[np.ndarray, float]:
        """Friction force (2,) in the world frame and torque about z for this step.

        Args:
            yaw: heading of the object (rad).
            velocity: (2,) world-frame velocity of the centre of mass, m/s.
            spin: angular velocity about z, rad/s.
            time_step: seconds the wrench will act.
        """
        c, s = math.cos(yaw), math.sin(yaw)
        cells_x, cells_y = self.cells[:, 0], self.cells[:, 1]
        offset_x, offset_y = c * cells_x - s * cells_y, s * cells_x + c * cells_y   # world
        vx, vy = float(velocity[0]), float(velocity[1])
        cell_vx, cell_vy = vx - spin * offset_y, vy + spin * offset_x
        # A cell at rest (speed 0) has velocity 0 and so gets no force from the division.
        scale = (self.mu * self.mass * GRAVITY / len(self.cells)
                 / np.maximum(np.hypot(cell_vx, cell_vy), 1e-12))
        force_x, force_y = -cell_vx * scale, -cell_vy * scale
        force = np.array([force_x.sum(), force_y.sum()])
        torque = float((offset_x * force_y - offset_y * force_x).sum())
        slowing = -(force[0] * vx + force[1] * vy + torque * spin) * time_step
        momentum = self.mass * (vx * vx + vy * vy) + self.inertia_z * spin * spin
        if slowing >= momentum:
            return -self.mass * np.array([vx, vy]) / time_step, -self.inertia_z * spin / time_step
        return force, torque
