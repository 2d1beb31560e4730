"""The simulated tabletop world (PyBullet), free of ROS so that tests and tools can drive it.

Contents: a table (a box whose top is at the scenario's table height), the scenario's objects
(dynamic boxes and cylinders with their mass and friction) and obstacles (fixed), and the Panda
with the ball pusher, torque-controlled by a TrajectoryController at every physics step.

Friction: an object slides on the table with mu = object.friction * table.friction, isotropic
Coulomb friction the sim applies itself (table_friction: PyBullet's depends on the heading); the
ball pushes it with PyBullet's friction, mu = object.friction * PUSHER_FRICTION (PyBullet
multiplies the coefficients of the two bodies in contact).
"""

from __future__ import annotations

import functools
import math
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pybullet

from tsrrt_common.camera import R_WORLD_OPTICAL, OverheadCamera
from tsrrt_common.errors import TsrrtError
from tsrrt_common.geometry import Pose2D, wrap_angle
from tsrrt_common.robot_model import (
    ARM_JOINT_NAMES,
    OBSERVE_POSTURE,
    TOOL_FRAME,
    pusher_urdf_path,
)
from tsrrt_common.scenario import ObjectSpec, Scenario
from tsrrt_sim.kinematics import PusherKinematics
from tsrrt_sim.table_friction import RESTING_TOLERANCE, SlidingBody, footprint_cells
from tsrrt_sim.trajectory_controller import ControllerGains, Tolerances, TrajectoryController

DEFAULT_PHYSICS_HZ = 240.0
TABLE_THICKNESS = 0.04
# Objects start this far above the table so that the first contact is not a deep penetration.
SPAWN_CLEARANCE = 5e-4
PUSHER_FRICTION = 0.5
TABLE_COLOR = (0.55, 0.45, 0.35, 1.0)
ARM_COLOR = (0.92, 0.92, 0.92, 1.0)
DEFAULT_CAMERA = OverheadCamera()
# Largest change (rad, m, quaternion component) a scene may show and still look the same: a
# hundredth of a millimetre, where resting bodies and the held arm drift by less.
STILL_TOLERANCE = 1e-5
DEFAULT_GAINS = ControllerGains()
DEFAULT_TOLERANCES = Tolerances.uniform(path_position=0.1, path_velocity=0.0,
                                        goal_position=0.01, goal_velocity=0.01, goal_time=1.0)


class SimWorldError(TsrrtError):
    """A request to the simulated world cannot be carried out (unknown object, bad value...)."""


@dataclass(frozen=True)
class ArmState:
    """Measured arm state, each (7,) in ARM_JOINT_NAMES order."""

    positions: np.ndarray     # rad
    velocities: np.ndarray    # rad/s
    efforts: np.ndarray       # N m, the torques applied in the last step


@dataclass(frozen=True)
class VisualState:
    """What the camera needs to redraw the scene elsewhere (see render_worker).

    Attributes:
        joint_positions: (7,) arm joint positions.
        body_poses: object id -> (position (3,), quaternion xyzw (4,)), obstacles included.
        sim_time: simulation seconds of the state.
    """

    joint_positions: tuple[float, ...]
    body_poses: dict[str, tuple[tuple[float, ...], tuple[float, ...]]]
    sim_time: float

    def looks_like(self, other: VisualState, tolerance: float = STILL_TOLERANCE) -> bool:
        """True when the camera cannot tell the two scenes apart: the same bodies, and no
        joint angle, coordinate or quaternion component differing by more than `tolerance`
        (a pixel on the table is about 0.6 mm)."""
        if self.body_poses.keys() != other.body_poses.keys():
            return False
        values = [*self.joint_positions]
        others = [*other.joint_positions]
        for body, (position, orientation) in self.body_poses.items():
            other_position, other_orientation = other.body_poses[body]
            values += [*position, *orientation]
            others += [*other_position, *other_orientation]
        return bool(np.max(np.abs(np.subtract(values, others))) <= tolerance)


@dataclass(frozen=True)
class CameraFrame:
    """One overhead camera image.

    Attributes:
        rgb: (H, W, 3) uint8.
        depth: (H, W) float32, metres along the optical axis (z in the optical frame).
        sim_time: simulation seconds at which the scene was rendered.
    """

    rgb: np.ndarray
    depth: np.ndarray
    sim_time: float


def opengl_view_matrix(camera: OverheadCamera) -> list[float]:
    """Column-major 4x4 world-to-OpenGL-eye matrix for `camera`'s pose.

    The OpenGL eye frame is the optical frame with y and z negated (y up, looking along -z).
    """
    rotation_world_eye = R_WORLD_OPTICAL @ np.diag([1.0, -1.0, -1.0])
    view = np.eye(4)
    view[:3, :3] = rotation_world_eye.T
    view[:3, 3] = -rotation_world_eye.T @ np.asarray(camera.position)
    return view.T.ravel().tolist()


def opengl_projection_matrix(camera: OverheadCamera) -> list[float]:
    """Column-major 4x4 OpenGL projection reproducing `camera.intrinsics` exactly.

    TinyRenderer samples pixel column i at window x = i and stores window row j as image row
    H - 1 - j (measured: with the textbook pixel-centre mapping every object lands half a pixel
    off, i.e. 0.6 mm on the table). So a point at OpenCV pixel (u, v) must reach window
    coordinates (u, H - 1 - v): NDC x = 2u/W - 1 and NDC y = 1 - 2(v + 1)/H.
    """
    K = camera.intrinsics
    width, height, near, far = camera.width, camera.height, camera.near, camera.far
    projection = np.zeros((4, 4))
    projection[0, 0] = 2.0 * K[0, 0] / width
    projection[0, 2] = 1.0 - 2.0 * K[0, 2] / width
    projection[1, 1] = 2.0 * K[1, 1] / height
    projection[1, 2] = 2.0 * (K[1, 2] + 1.0) / height - 1.0
    projection[2, 2] = -(far + near) / (far - near)
    projection[2, 3] = -2.0 * far * near / (far - near)
    projection[3, 2] = -1.0
    return projection.T.ravel().tolist()


def depth_buffer_to_metres(depth_buffer: np.ndarray, near: float, far: float) -> np.ndarray:
    """Metric depth (H, W) float32 along the optical axis from an OpenGL depth buffer in [0, 1]."""
    buffer = np.asarray(depth_buffer, dtype=np.float64)
    return (far * near / (far - (far - near) * buffer)).astype(np.float32)


def simple_visuals_urdf(urdf_path: Path) -> Path:
    """A copy of the pusher URDF whose visual meshes are the coarse collision meshes.

    The detailed visual meshes (~130k triangles) make TinyRenderer 2-3 times slower; the camera
    only needs the arm's silhouette, and the collision meshes are exactly what the physics sees.
    Kinematics, inertias and collision geometry are unchanged.
    """
    text = urdf_path.read_text()
    simple = text.replace("/meshes/visual/", "/meshes/collision/").replace(".dae", ".stl")
    path = urdf_path.with_name(urdf_path.stem + "_simple_visuals.urdf")
    if not path.is_file() or path.read_text() != simple:
        # Several processes (node, render worker, tests) may write it at once: write, then rename.
        with tempfile.NamedTemporaryFile("w", dir=path.parent, suffix=".tmp",
                                         delete=False) as tmp:
            tmp.write(simple)
        os.replace(tmp.name, path)
    return path


def cylinder_mesh(radius: float, height: float, sides: int = 64
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangle mesh of a cylinder centred at the origin, axis z, for rendering.

    PyBullet's own cylinder visual renders about 1 mm taller than the cylinder it simulates; this
    prism has the exact height and the disc's exact area (its polygon radius is enlarged so), so
    the centroid and size perception measures are the true ones.

    Returns:
        vertices (V, 3), per-vertex normals (V, 3), triangle indices (3T,) counter-clockwise
        seen from outside.
    """
    angles = np.arange(sides) * (2.0 * math.pi / sides)
    polygon_radius = radius * math.sqrt(2.0 * math.pi / (sides * math.sin(2.0 * math.pi / sides)))
    ring = np.column_stack([polygon_radius * np.cos(angles), polygon_radius * np.sin(angles)])
    half = height / 2.0
    vertices, normals, indices = [], [], []
    for z, sign in ((half, 1.0), (-half, -1.0)):          # caps: centre then ring
        base = len(vertices)
        vertices += [(0.0, 0.0, z)] + [(x, y, z) for x, y in ring]
        normals += [(0.0, 0.0, sign)] * (sides + 1)
        for i in range(sides):
            a, b = base + 1 + i, base + 1 + (i + 1) % sides
            indices += [base, a, b] if sign > 0 else [base, b, a]
    base = len(vertices)                                   # side: radial normals, smooth shading
    for (x, y), angle in zip(ring, angles, strict=True):
        vertices += [(x, y, half), (x, y, -half)]
        normals += [(math.cos(angle), math.sin(angle), 0.0)] * 2
    for i in range(sides):
        top_a, bottom_a = base + 2 * i, base + 2 * i + 1
        top_b, bottom_b = base + 2 * ((i + 1) % sides), base + 2 * ((i + 1) % sides) + 1
        indices += [bottom_a, bottom_b, top_b, bottom_a, top_b, top_a]
    return np.array(vertices), np.array(normals), np.array(indices, dtype=np.int32)


class _PhysicsClient:
    """PyBullet's functions bound to one physics server.

    Like pybullet_utils' BulletClient, which however prints to stdout on connecting and rebinds
    the function on every call (measurable at thousands of steps per second).
    """

    def __init__(self, gui: bool) -> None:
        self.client_id = pybullet.connect(pybullet.GUI if gui else pybullet.DIRECT)
        if self.client_id < 0:
            raise SimWorldError("could not start a PyBullet physics server")

    def __getattr__(self, name: str):
        function = functools.partial(getattr(pybullet, name), physicsClientId=self.client_id)
        setattr(self, name, function)
        return function


def _yaw_quaternion(theta: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(theta / 2.0), math.cos(theta / 2.0))


def yaw_of_quaternion(quaternion: tuple[float, float, float, float]) -> float:
    """Rotation about z (rad) of an xyzw quaternion, for a body that stays upright."""
    x, y, z, w = quaternion
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


class SimWorld:
    """PyBullet world of one scenario, stepped explicitly; not thread-safe.

    Args:
        scenario: the world to build.
        gui: open PyBullet's window instead of the headless DIRECT mode.
        physics_hz: physics steps per simulated second.
        camera: the overhead camera to render with.
        simple_robot_visuals: render the arm with its collision meshes (see simple_visuals_urdf).
        gains, tolerances: of the trajectory controller.
        initial_posture: (7,) joint positions the arm starts in (and returns to on a reset);
            by default out of the camera's view, so that every object can be seen at once.
    """

    def __init__(self, scenario: Scenario, *, gui: bool = False,
                 physics_hz: float = DEFAULT_PHYSICS_HZ,
                 camera: OverheadCamera = DEFAULT_CAMERA, simple_robot_visuals: bool = True,
                 gains: ControllerGains = DEFAULT_GAINS,
                 tolerances: Tolerances = DEFAULT_TOLERANCES,
                 initial_posture: tuple[float, ...] = OBSERVE_POSTURE) -> None:
        if not (math.isfinite(physics_hz) and physics_hz > 0):
            raise SimWorldError(f"physics_hz must be positive, got {physics_hz}")
        self.physics_hz = physics_hz
        self.time_step = 1.0 / physics_hz
        self.camera = camera
        self.initial_posture = tuple(float(v) for v in initial_posture)
        if len(self.initial_posture) != len(ARM_JOINT_NAMES):
            raise SimWorldError(f"initial_posture needs {len(ARM_JOINT_NAMES)} joint positions, "
                                f"got {len(self.initial_posture)}")
        self._urdf_path = pusher_urdf_path()
        self._visual_urdf_path = (simple_visuals_urdf(self._urdf_path) if simple_robot_visuals
                                  else self._urdf_path)
        self.kinematics = PusherKinematics(self._urdf_path)
        self._client = _PhysicsClient(gui)
        self._view_matrix = opengl_view_matrix(camera)
        self._projection_matrix = opengl_projection_matrix(camera)
        self._joint_indices = list(range(len(ARM_JOINT_NAMES)))
        self.controller = TrajectoryController(
            self.kinematics.limits, self._inverse_dynamics, self.kinematics.tool_position,
            tolerances, np.array(self.initial_posture), gains)
        self.scenario = scenario
        self.sim_time = 0.0
        self._step_count = 0
        self._last_torques = np.zeros(len(ARM_JOINT_NAMES))
        self.load_scenario(scenario)

    # ------------------------------------------------------------------------------- building
    def load_scenario(self, scenario: Scenario) -> None:
        """Rebuild the world for `scenario`: arm at its initial posture, objects at their poses.

        Simulation time keeps running (a /clock never goes backwards); any goal is aborted.
        """
        client = self._client
        client.resetSimulation()
        client.setGravity(0.0, 0.0, -9.81)
        client.setPhysicsEngineParameter(fixedTimeStep=self.time_step)
        self.scenario = scenario
        self._robot = self._load_robot()
        self._table = self._create_table(scenario)
        self._bodies: dict[str, int] = {}
        self._specs: dict[str, ObjectSpec] = {}
        self._sliding: dict[int, SlidingBody] = {}
        for spec in (*scenario.obstacles, *scenario.objects):
            self._bodies[spec.id] = self._create_object(spec, scenario.table.height)
            self._specs[spec.id] = spec
            if not spec.static:
                self._sliding[self._bodies[spec.id]] = SlidingBody(
                    mass=spec.mass,
                    inertia_z=client.getDynamicsInfo(self._bodies[spec.id], -1)[2][2],
                    mu=spec.friction * scenario.table.friction, half_height=spec.height / 2.0,
                    rest_z=scenario.table.height + spec.height / 2.0,
                    cells=footprint_cells(spec.shape, spec.length, spec.width))
        self.controller.reset(np.array(self.initial_posture))
        self._last_torques = np.zeros(len(ARM_JOINT_NAMES))

    def _load_robot(self) -> int:
        client = self._client
        robot = client.loadURDF(str(self._visual_urdf_path), basePosition=(0.0, 0.0, 0.0),
                                useFixedBase=True, flags=pybullet.URDF_USE_INERTIA_FROM_FILE)
        names = [client.getJointInfo(robot, j)[1].decode()
                 for j in range(client.getNumJoints(robot))]
        if tuple(names[:len(ARM_JOINT_NAMES)]) != ARM_JOINT_NAMES:
            raise SimWorldError(f"unexpected joint order in the pusher URDF: {names}")
        self._tool_link = next(j for j in range(client.getNumJoints(robot))
                               if client.getJointInfo(robot, j)[12].decode() == TOOL_FRAME)
        for link in range(-1, client.getNumJoints(robot)):
            # No artificial damping: the controller's inverse dynamics must match the plant.
            client.changeDynamics(robot, link, linearDamping=0.0, angularDamping=0.0,
                                  jointDamping=0.0)
            if self._visual_urdf_path != self._urdf_path:
                client.changeVisualShape(robot, link, rgbaColor=ARM_COLOR)
        client.changeDynamics(robot, self._tool_link, lateralFriction=PUSHER_FRICTION)
        for joint, position in zip(self._joint_indices, self.initial_posture, strict=True):
            client.resetJointState(robot, joint, position, 0.0)
        # PyBullet drives every joint with a velocity motor by default; torque control only
        # works once those motors are given zero force.
        client.setJointMotorControlArray(robot, self._joint_indices, pybullet.VELOCITY_CONTROL,
                                         forces=[0.0] * len(self._joint_indices))
        return robot

    def _create_table(self, scenario: Scenario) -> int:
        client = self._client
        table = scenario.table
        half_extents = (table.size[0] / 2.0, table.size[1] / 2.0, TABLE_THICKNESS / 2.0)
        body = client.createMultiBody(
            baseMass=0.0,
            baseCollisionShapeIndex=client.createCollisionShape(pybullet.GEOM_BOX,
                                                                halfExtents=half_extents),
            baseVisualShapeIndex=client.createVisualShape(pybullet.GEOM_BOX,
                                                          halfExtents=half_extents,
                                                          rgbaColor=TABLE_COLOR),
            basePosition=(table.center[0], table.center[1], table.height - TABLE_THICKNESS / 2.0))
        # Its friction is applied by _apply_table_friction, not by PyBullet.
        client.changeDynamics(body, -1, lateralFriction=0.0)
        return body

    def _create_object(self, spec: ObjectSpec, table_height: float) -> int:
        client = self._client
        if spec.shape == "box":
            half_extents = (spec.length / 2.0, spec.width / 2.0, spec.height / 2.0)
            collision = client.createCollisionShape(pybullet.GEOM_BOX, halfExtents=half_extents)
            visual = client.createVisualShape(pybullet.GEOM_BOX, halfExtents=half_extents,
                                              rgbaColor=(*spec.color, 1.0))
        else:
            radius = spec.length / 2.0
            collision = client.createCollisionShape(pybullet.GEOM_CYLINDER, radius=radius,
                                                    height=spec.height)
            vertices, normals, indices = cylinder_mesh(radius, spec.height)
            visual = client.createVisualShape(pybullet.GEOM_MESH, vertices=vertices.tolist(),
                                              normals=normals.tolist(), indices=indices.tolist(),
                                              rgbaColor=(*spec.color, 1.0))
        z = table_height + spec.height / 2.0 + (0.0 if spec.static else SPAWN_CLEARANCE)
        body = client.createMultiBody(
            baseMass=0.0 if spec.static else spec.mass, baseCollisionShapeIndex=collision,
            baseVisualShapeIndex=visual, basePosition=(spec.pose.x, spec.pose.y, z),
            baseOrientation=_yaw_quaternion(spec.pose.theta))
        client.changeDynamics(body, -1, lateralFriction=spec.friction,
                              linearDamping=0.0, angularDamping=0.0, restitution=0.0)
        if not spec.static:
            # Left awake, a resting box creeps by tens of micrometres and ~0.1 mrad per second
            # (solver drift); asleep it stays put until the ball or another body touches it.
            client.changeDynamics(body, -1,
                                  activationState=pybullet.ACTIVATION_STATE_ENABLE_SLEEPING)
        return body

    # ------------------------------------------------------------------------------- stepping
    def _inverse_dynamics(self, positions: np.ndarray, velocities: np.ndarray,
                          accelerations: np.ndarray) -> np.ndarray:
        return np.asarray(self._client.calculateInverseDynamics(
            self._robot, positions.tolist(), velocities.tolist(), accelerations.tolist()))

    def _measure(self) -> tuple[np.ndarray, np.ndarray]:
        states = self._client.getJointStates(self._robot, self._joint_indices)
        return (np.array([s[0] for s in states]), np.array([s[1] for s in states]))

    def step(self, count: int = 1) -> None:
        """Advance `count` physics steps, running the controller before each."""
        client = self._client
        for _ in range(count):
            positions, velocities = self._measure()
            torques = self.controller.update(self.sim_time, positions, velocities)
            client.setJointMotorControlArray(self._robot, self._joint_indices,
                                             pybullet.TORQUE_CONTROL, forces=torques.tolist())
            self._apply_table_friction()
            client.stepSimulation()
            self._last_torques = torques
            self._step_count += 1
            self.sim_time = self._step_count * self.time_step

    def _apply_table_friction(self) -> None:
        """Friction of every object sliding on the table for the coming step (table_friction)."""
        client = self._client
        for body, sliding in self._sliding.items():
            linear, angular = client.getBaseVelocity(body)
            if linear[0] == 0.0 and linear[1] == 0.0 and angular[2] == 0.0:
                continue                      # at rest (or asleep): no friction to apply
            position, orientation = client.getBasePositionAndOrientation(body)
            if position[2] > sliding.rest_z + RESTING_TOLERANCE:
                continue                      # lifted off the table
            force, torque = sliding.wrench(yaw_of_quaternion(orientation),
                                           np.array(linear[:2]), angular[2], self.time_step)
            bottom = (position[0], position[1], position[2] - sliding.half_height)
            client.applyExternalForce(body, -1, (force[0], force[1], 0.0), bottom,
                                      pybullet.WORLD_FRAME)
            client.applyExternalTorque(body, -1, (0.0, 0.0, torque), pybullet.WORLD_FRAME)

    def settle(self, seconds: float) -> None:
        """Let the world run for `seconds` of simulated time (objects come to rest)."""
        self.step(max(0, round(seconds * self.physics_hz)))

    # ------------------------------------------------------------------------------ reading
    def joint_state(self) -> ArmState:
        positions, velocities = self._measure()
        return ArmState(positions, velocities, self._last_torques.copy())

    def tool_position(self) -> np.ndarray:
        """Ball centre (3,) in the world frame, by forward kinematics of the measured joints."""
        return self.kinematics.tool_position(self._measure()[0])

    @property
    def object_ids(self) -> tuple[str, ...]:
        """Ids of the movable objects (not the obstacles), in scenario order."""
        return tuple(spec.id for spec in self.scenario.objects)

    def object_spec(self, object_id: str) -> ObjectSpec:
        try:
            return self._specs[object_id]
        except KeyError:
            raise SimWorldError(f"unknown object {object_id!r}; known: {sorted(self._specs)}"
                                ) from None

    def object_poses(self, include_obstacles: bool = False) -> dict[str, Pose2D]:
        """Ground-truth planar pose of every object (and obstacle, if asked), by id."""
        specs = [*self.scenario.objects, *(self.scenario.obstacles if include_obstacles else ())]
        poses = {}
        for spec in specs:
            position, orientation = self._client.getBasePositionAndOrientation(
                self._bodies[spec.id])
            poses[spec.id] = Pose2D(position[0], position[1],
                                    wrap_angle(yaw_of_quaternion(orientation)))
        return poses

    def object_speeds(self) -> dict[str, float]:
        """Speed (m/s) of each movable object's centre, by id."""
        return {spec.id: float(np.linalg.norm(
            self._client.getBaseVelocity(self._bodies[spec.id])[0]))
            for spec in self.scenario.objects}

    # ----------------------------------------------------------------------------- changing
    def disturb_object(self, object_id: str, dx: float, dy: float, dtheta: float) -> Pose2D:
        """Move an object at once by (dx, dy) metres in the world frame and dtheta radians,
        as a bumped table would; returns its new pose.

        Raises:
            SimWorldError: unknown or static object, non-finite offset, or a new footprint that
                is not entirely on the table.
        """
        spec = self.object_spec(object_id)
        if spec.static:
            raise SimWorldError(f"{object_id!r} is a fixed obstacle and cannot be moved")
        if not all(math.isfinite(v) for v in (dx, dy, dtheta)):
            raise SimWorldError(f"disturbance must be finite, got ({dx}, {dy}, {dtheta})")
        body = self._bodies[object_id]
        position, orientation = self._client.getBasePositionAndOrientation(body)
        pose = Pose2D(position[0] + dx, position[1] + dy,
                      wrap_angle(yaw_of_quaternion(orientation) + dtheta))
        xmin, ymin, xmax, ymax = self.scenario.table.bounds
        footprint = spec.footprint(pose)
        if (footprint[:, 0].min() < xmin or footprint[:, 0].max() > xmax
                or footprint[:, 1].min() < ymin or footprint[:, 1].max() > ymax):
            raise SimWorldError(f"moving {object_id!r} to ({pose.x:.3f}, {pose.y:.3f}) would put "
                                "it partly off the table")
        self._client.resetBasePositionAndOrientation(body, (pose.x, pose.y, position[2]),
                                                     _yaw_quaternion(pose.theta))
        self._client.resetBaseVelocity(body, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        self._client.changeDynamics(body, -1, activationState=pybullet.ACTIVATION_STATE_WAKE_UP)
        return pose

    # ------------------------------------------------------------------------------- camera
    def visual_state(self) -> VisualState:
        """The current arm and object poses, for a render worker to reproduce."""
        poses = {object_id: tuple(tuple(v) for v in
                                  self._client.getBasePositionAndOrientation(body))
                 for object_id, body in self._bodies.items()}
        return VisualState(tuple(self._measure()[0].tolist()), poses, self.sim_time)

    def apply_visual_state(self, state: VisualState) -> None:
        """Teleport the arm and objects to `state` (for rendering only: velocities are zeroed)."""
        for joint, position in zip(self._joint_indices, state.joint_positions, strict=True):
            self._client.resetJointState(self._robot, joint, position, 0.0)
        for object_id, (position, orientation) in state.body_poses.items():
            self._client.resetBasePositionAndOrientation(self._bodies[object_id], position,
                                                         orientation)
        self.sim_time = state.sim_time

    def render(self) -> CameraFrame:
        """Render the overhead camera with TinyRenderer (CPU; no display needed)."""
        camera = self.camera
        _, _, rgba, depth_buffer, _ = self._client.getCameraImage(
            camera.width, camera.height, viewMatrix=self._view_matrix,
            projectionMatrix=self._projection_matrix, renderer=pybullet.ER_TINY_RENDERER,
            flags=pybullet.ER_NO_SEGMENTATION_MASK)
        rgba = np.asarray(rgba, dtype=np.uint8).reshape(camera.height, camera.width, 4)
        depth = depth_buffer_to_metres(
            np.asarray(depth_buffer).reshape(camera.height, camera.width), camera.near, camera.far)
        return CameraFrame(np.ascontiguousarray(rgba[:, :, :3]), depth, self.sim_time)

    def close(self) -> None:
        """Disconnect from PyBullet; the world is unusable afterwards."""
        if self._client is not None:
            self._client.disconnect()
            self._client = None
