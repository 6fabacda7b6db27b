"""An independent second physics judge of grasps in PyBullet (Bullet physics), for benchmarks and tests only.

graspgen judges its grasps with MuJoCo (graspgen/physics.py). Customers check exports with other simulators, so this
module simulates the same scenario with a different engine, contact model and friction model, built from scratch:
nothing of physics.py's model is reused but its public perturbation set and its scenario constants (stage times,
accelerations, outcome thresholds: `physics.SIM`). Nothing under graspgen/ or services/ imports this module.

The scenario, in the grasp frame of the contract (origin at the contact midpoint, +X the closing axis, +Z the
approach direction, palm at -Z), which is Bullet's world frame here:

- the gripper is a multibody with a fixed base: the palm box (when the spec has a palm) and two finger boxes of the
  spec's `finger_thickness x finger_width x finger_depth` on prismatic joints along X, coupled by a gear constraint
  (q0 = q1, like a real parallel gripper) and each closed by a velocity motor whose force is capped at the grip force
  (a blocked finger presses with exactly `grip_force`); they start open at the pre-grasp width
  `min(width + pregrasp_clearance, stroke)`;
- the part is a free rigid body of the given mass; its collision shape is Bullet's own convex decomposition
  (`pybullet.vhacd`, independent of our CoACD pieces), or the convex hull for a convex part; the centre of mass and
  the principal inertia come from the mesh volume (trimesh), scaled to the mass. It starts at its grasp pose
  `inv(T_object_grasp)` between the open pads, exactly (no placement error); a piece reaching more than
  `start_tolerance` (1 mm) into the palm or a pad at the start -> `collision` (no approach phase);
- friction: Coulomb coefficient `friction` pad/part (Bullet multiplies the two bodies' coefficients, so the pads
  carry 1.0 and the part the run's coefficient), Bullet's torsional ("spinning") friction of `friction * 2 mm`, a
  ~2 mm pad patch, no rolling friction, no restitution, no damping of the part's motion;
- loads: world gravity along +Z (the top-down pick; the gripper lifts along -Z), and the gripper's acceleration a(t)
  as the fictitious force `-m a(t)` applied at the part's centre of mass every step: close (`close_time`, no load),
  lift (3 m/s^2 ramped over 0.2 s), hold 0.2 s, the perturbation's gravity turn (0.3 s per 90 degrees, then another
  hold), and one sine period of 5 m/s^2 at 4 Hz along X, Y, Z and (0, .707, -.707) (or the perturbation's shake);
- outcomes like physics.py: `collision`; `no_contact` (a pad without contact after closing); `dropped` (either pad
  without contact for more than 20 ms, or the contact midpoint moving more than 20 mm); `slipped` (the contact
  midpoint moved more than 5 mm, or the part turned more than 10 degrees, relative to the gripper); else held.

Outside grasps only: the fingers close inwards (bench_crosscheck.py leaves inside grasps unjudged and says so).

`prepare_part(mesh, spec, mass_kg=, grip_force=, friction=)` builds the decomposition once per part;
`BulletJudge(part)` owns one headless client (`pybullet.DIRECT`) and `judge.simulate(T_object_grasp, width,
perturbation)` runs one grasp (the world is reset and rebuilt for every grasp, so results do not depend on order).
"""

from __future__ import annotations

import contextlib
import math
import os
import sys
import tempfile
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import trimesh

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from graspgen import physics  # noqa: E402
from graspgen.gripper import GripperSpec  # noqa: E402

try:
    import pybullet
except ImportError:  # the judge is a dev tool: callers check `available()`
    pybullet = None

REASONS = ("collision", "no_contact", "dropped", "slipped")


def available() -> bool:
    return pybullet is not None


@dataclass(frozen=True)
class BulletConstants:
    """The Bullet set-up (SI units). Scenario times, accelerations and outcome limits are physics.SIM's."""

    #: integration step (s) and the solver's iterations per step
    timestep: float = 1.0e-3
    solver_iterations: int = 150
    #: the solver stops early when its residual falls below this; pybullet's default stops while a part squeezed
    #: by 20 N still creeps round the closing axis with no load at all (a 40 mm cube of 0.1 kg at 1.4 deg/s): 0 runs
    #: every iteration, and the cube stays put
    solver_residual_threshold: float = 0.0
    #: Bullet's global constraint force mixing: a little softness makes the contact forces unique. With rigid
    #: contacts (0) the solver leaves the squeeze of a pad on a face to one or two of its four corner points (14, 5,
    #: 1 and 0 N of 20 N) with internal friction between them, and a 40 mm cube squeezed by 20 N at friction 0.5
    #: slid under 10-14 N across the closing axis instead of 2 mu F = 20 N; at 1e-3 each corner carries 5 N, the cube
    #: slides at 20.4 N (ramped load) in every direction, and a pad sinks 0.07 mm into the part at 20 N
    global_cfm: float = 1.0e-3
    #: finger mass (kg) and the motors' closing speed (m/s; the velocity motor's force is capped at the grip force)
    finger_mass: float = 0.05
    closing_speed: float = 0.2
    #: torsional friction of a pad patch of this radius (m): Bullet's spinning friction = friction * radius
    patch_radius: float = 2.0e-3
    #: Bullet's collision margin of the part's convex pieces (m): its default, 1 mm, would make the part 2 mm wider
    #: and round its edges by 1 mm; boxes keep their size whatever the margin
    collision_margin: float = 1.0e-4
    #: contact points farther apart than this are dropped from Bullet's persistent manifolds (m; default 20 mm)
    contact_breaking_threshold: float = 1.0e-3
    #: convex/convex contacts by separating axes and face clipping (a whole contact polygon per step) instead of
    #: GJK/EPA's one new point per step
    enable_sat: bool = True
    #: Bullet's implicit friction cone (False: its default pyramid of two independent friction directions)
    cone_friction: bool = True
    #: a contact point counts as touching when its distance is below this (m)
    touch_distance: float = 2.0e-4
    #: a piece of the part reaching deeper than this into the palm or a pad at the start -> collision (m)
    start_tolerance: float = 1.0e-3
    #: samples of the part's own surface that confirm a start overlap (about 0.2 mm apart on a 100 cm^2 part)
    surface_samples: int = 200_000
    #: V-HACD (pybullet.vhacd) settings: voxel resolution, concavity, vertices per hull
    vhacd_resolution: int = 1_000_000
    vhacd_concavity: float = 0.0025
    vhacd_max_vertices: int = 64
    #: the scenario: stage times (s), accelerations (m/s^2), shake, outcome limits, check interval (steps)
    gravity: float = physics.SIM.gravity
    close_time: float = physics.SIM.close_time
    lift_acceleration: float = physics.SIM.lift_acceleration
    lift_time: float = physics.SIM.lift_time
    hold_time: float = physics.SIM.hold_time
    turn_time: float = physics.SIM.turn_time
    shake_acceleration: float = physics.SIM.shake_acceleration
    shake_frequency: float = physics.SIM.shake_frequency
    shake_directions: tuple[tuple[float, float, float], ...] = physics.SIM.shake_directions
    slip_limit: float = physics.SIM.slip_limit
    rotation_limit_deg: float = physics.SIM.rotation_limit_deg
    drop_distance: float = physics.SIM.drop_distance
    lost_contact_time: float = physics.SIM.lost_contact_time
    check_steps: int = physics.SIM.check_steps

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


BULLET = BulletConstants()


@dataclass(frozen=True)
class BulletResult:
    """The outcome of one grasp in Bullet."""

    success: bool
    reason: str | None  # None when held, else one of REASONS
    slip_mm: float  # largest displacement of the contact midpoint relative to the gripper after closing
    rotation_deg: float  # largest rotation of the part relative to the gripper after closing
    contacts: int  # touching part/pad contact points at the end of closing
    start_penetration_mm: float  # deepest penetration of the part's pieces into the gripper at the start
    max_penetration_mm: float  # deepest part/pad penetration after closing
    member: str = "nominal"
    #: where the pieces reached deeper than start_tolerance into the gripper at the start while the part's own
    #: surface did not (V-HACD's slack): "palm" (then the palm collides with nothing for this grasp), "pad" or None
    start_overlap: str | None = None

    def to_json(self) -> dict[str, Any]:
        return {k: (round(v, 4) if isinstance(v, float) else v) for k, v in asdict(self).items()}


@dataclass
class BulletPart:
    """A part prepared for Bullet: convex pieces in its principal inertial frame (an OBJ file), mass properties."""

    spec: GripperSpec
    friction: float
    grip_force: float  # N per finger
    mass: float  # kg
    center_of_mass: np.ndarray  # (3,) object frame
    principal_axes: np.ndarray  # (3, 3) columns: the principal axes in the object frame (det +1)
    principal_moments: np.ndarray  # (3,) kg m^2
    urdf_path: str  # the part: one link, its frame the principal inertial frame, a collision mesh per piece
    geometry: str  # "convex" | "vhacd" | "convex-hull"
    pieces: int
    note: str | None = None
    constants: BulletConstants = field(default_factory=BulletConstants)
    workdir: Any = field(default=None, repr=False)  # keeps the TemporaryDirectory alive
    #: seeded samples of the part's own surface (object frame): a start overlap of the pieces is a collision only
    #: when the surface confirms it (the pieces bridge grooves and recesses of the part)
    surface_points: np.ndarray | None = field(default=None, repr=False)

    def describe(self) -> str:
        return f"{self.geometry} ({self.pieces})"


# --------------------------------------------------------------------------------------------------------------------
# the part


@contextlib.contextmanager
def _quiet_fd(fd: int = 1):
    """Silence a C library writing to file descriptor `fd` (V-HACD prints its progress to stdout)."""
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "wb") as null:
            os.dup2(null.fileno(), fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _read_obj_pieces(path: str) -> list[np.ndarray]:
    """The vertex arrays of the `o` groups of a Wavefront OBJ (V-HACD's output: one convex hull per group)."""
    pieces: list[list[list[float]]] = []
    for line in Path(path).read_text().splitlines():
        if line.startswith("o ") or (line.startswith("v ") and not pieces):
            pieces.append([])
        if line.startswith("v "):
            pieces[-1].append([float(x) for x in line.split()[1:4]])
    return [np.asarray(p, dtype=np.float64) for p in pieces if len(p) >= 4]


def _write_obj(path: str, hull: trimesh.Trimesh) -> None:
    lines = [f"v {x:.12g} {y:.12g} {z:.12g}" for x, y, z in hull.vertices]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in hull.faces]
    Path(path).write_text("\n".join(lines) + "\n")


def _g(values) -> str:
    return " ".join(f"{float(v):.12g}" for v in values)


def _inertial(mass: float, diagonal) -> str:
    ixx, iyy, izz = (float(v) for v in diagonal)
    return (
        f'<inertial><origin xyz="0 0 0" rpy="0 0 0"/><mass value="{mass:.12g}"/>'
        f'<inertia ixx="{ixx:.12g}" iyy="{iyy:.12g}" izz="{izz:.12g}" ixy="0" ixz="0" iyz="0"/></inertial>'
    )


def _part_urdf(workdir: str, hulls: list[trimesh.Trimesh], mass: float, moments: np.ndarray) -> str:
    """A URDF of the part (one link whose frame is the principal inertial frame, a convex mesh per piece): pybullet
    gives meshes and boxes the polyhedral features of separating-axis contact (a whole contact polygon per step,
    not GJK's one point) only when they come from a URDF loaded with URDF_INITIALIZE_SAT_FEATURES."""
    collisions = []
    for k, h in enumerate(hulls):
        path = os.path.join(workdir, f"piece{k}.obj")
        _write_obj(path, h)
        collisions.append(f'<collision><geometry><mesh filename="{path}"/></geometry></collision>')
    text = '<robot name="part"><link name="part">' + _inertial(mass, moments) + "".join(collisions) + "</link></robot>"
    path = os.path.join(workdir, "part.urdf")
    Path(path).write_text(text)
    return path


def gripper_urdf(spec: GripperSpec, c: BulletConstants, path: str) -> str:
    """The gripper as a URDF: the palm (base link, fixed) and two fingers on prismatic joints along X; joint 0 moves
    finger 0 along +X, joint 1 finger 1 along -X; q = 0 is fully open (inner faces at -+stroke / 2)."""
    t, fw, fd = spec.finger_thickness, spec.finger_width, spec.finger_depth
    half = spec.stroke / 2
    close_range = max(half - spec.min_width / 2, 0.0)
    box = spec.palm_box()
    palm = ""
    if box is not None:
        palm = (
            f'<collision><origin xyz="{_g(box.center)}" rpy="0 0 0"/>'
            f'<geometry><box size="{_g(box.extents)}"/></geometry></collision>'
        )
    links = [f'<link name="palm">{_inertial(0.0, (0.0, 0.0, 0.0))}{palm}</link>']
    joints = []
    for k, sign in ((0, -1.0), (1, 1.0)):
        links.append(
            f'<link name="finger{k}">{_inertial(c.finger_mass, (1e-5, 1e-5, 1e-5))}'
            f'<collision><geometry><box size="{_g((t, fw, fd))}"/></geometry></collision></link>'
        )
        joints.append(
            f'<joint name="close{k}" type="prismatic"><parent link="palm"/><child link="finger{k}"/>'
            f'<origin xyz="{sign * (half + t / 2):.12g} 0 0" rpy="0 0 0"/><axis xyz="{-sign:g} 0 0"/>'
            f'<limit lower="0" upper="{close_range:.12g}" effort="1e6" velocity="10"/></joint>'
        )
    Path(path).write_text('<robot name="gripper">' + "".join(links) + "".join(joints) + "</robot>")
    return path


def _vhacd(mesh: trimesh.Trimesh, workdir: str, c: BulletConstants) -> list[trimesh.Trimesh]:
    src, out, log = (os.path.join(workdir, n) for n in ("part.obj", "vhacd.obj", "vhacd.log"))
    mesh.export(src)
    client = pybullet.connect(pybullet.DIRECT)
    try:
        with _quiet_fd(1):
            pybullet.vhacd(
                src,
                out,
                log,
                resolution=int(c.vhacd_resolution),
                concavity=float(c.vhacd_concavity),
                maxNumVerticesPerCH=int(c.vhacd_max_vertices),
                physicsClientId=client,
            )
    finally:
        pybullet.disconnect(client)
    hulls = []
    for v in _read_obj_pieces(out) if os.path.isfile(out) else []:
        try:
            h = trimesh.convex.convex_hull(v)
        except Exception:  # a flat or degenerate piece adds nothing to the contact geometry
            continue
        if h.volume > 1e-12:
            hulls.append(h)
    return hulls


def _mass_properties(mesh: trimesh.Trimesh, mass_kg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, str | None]:
    """Centre of mass (3,), principal axes (3, 3, columns, det +1) and principal moments (3,) at `mass_kg`."""
    note = None
    body = mesh
    if not (mesh.is_watertight and mesh.volume > 0):
        body, note = mesh.convex_hull, "not a closed volume: mass properties of the convex hull"
    props = body.mass_properties
    com = np.asarray(props["center_mass"], dtype=np.float64)
    inertia = np.asarray(props["inertia"], dtype=np.float64) * (mass_kg / float(props["volume"]))
    moments, axes = np.linalg.eigh(0.5 * (inertia + inertia.T))
    if np.linalg.det(axes) < 0:
        axes[:, 2] *= -1.0
    return com, axes, np.maximum(moments, 1e-12), note


def prepare_part(
    mesh: trimesh.Trimesh,
    spec: GripperSpec,
    *,
    mass_kg: float,
    grip_force: float | None = None,
    friction: float | None = None,
    decomposition: str = "auto",
    constants: BulletConstants = BULLET,
) -> BulletPart:
    """The part (`mesh` in metres, object frame) for Bullet. `decomposition`: "auto" (the convex hull when the mesh is
    convex, else V-HACD), "vhacd" or "hull"."""
    if pybullet is None:
        raise RuntimeError("pybullet is not installed (pip install -c constraints.txt pybullet)")
    force = float(grip_force if grip_force is not None else spec.grip_force)
    mu = float(spec.friction if friction is None else friction)
    com, axes, moments, note = _mass_properties(mesh, float(mass_kg))
    workdir = tempfile.TemporaryDirectory(prefix="crosscheck-bullet-")
    if decomposition == "hull" or (decomposition == "auto" and mesh.is_convex):
        hulls, geometry = [mesh.convex_hull], "convex" if mesh.is_convex else "convex-hull"
    else:
        hulls, geometry = _vhacd(mesh, workdir.name, constants), "vhacd"
        if not hulls:
            hulls, geometry = [mesh.convex_hull], "convex-hull"
            note = "; ".join(n for n in (note, "V-HACD gave no pieces: the convex hull") if n)
    principal = [(np.asarray(h.vertices) - com) @ axes for h in hulls]  # principal frame: v' = R^T (v - com)
    urdf = _part_urdf(workdir.name, [trimesh.convex.convex_hull(v) for v in principal], float(mass_kg), moments)
    return BulletPart(
        spec=spec,
        friction=mu,
        grip_force=force,
        mass=float(mass_kg),
        center_of_mass=com,
        principal_axes=axes,
        principal_moments=moments,
        urdf_path=urdf,
        geometry=geometry,
        pieces=len(hulls),
        note=note,
        constants=constants,
        workdir=workdir,
        surface_points=np.asarray(
            trimesh.sample.sample_surface(mesh, int(constants.surface_samples), seed=0)[0], dtype=np.float64
        ),
    )


# --------------------------------------------------------------------------------------------------------------------
# one grasp


def _quat_xyzw(R: np.ndarray) -> list[float]:
    T = np.eye(4)
    T[:3, :3] = R
    w, x, y, z = trimesh.transformations.quaternion_from_matrix(T)
    return [float(x), float(y), float(z), float(w)]


def _matrix(q) -> np.ndarray:
    return np.asarray(pybullet.getMatrixFromQuaternion(q), dtype=np.float64).reshape(3, 3)


def _rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    return trimesh.transformations.rotation_matrix(angle, axis)[:3, :3]


def loads(c: BulletConstants, p: physics.Perturbation, dt: float):
    """Per check interval of `dt` seconds: (world gravity (3,), fictitious acceleration -a(t) of the gripper (3,)),
    grasp frame, from the lift to the end of the shake."""
    g = np.array([0.0, 0.0, c.gravity])
    zero = np.zeros(3)
    n_ramp = max(1, int(round(c.lift_time / dt)))
    for k in range(n_ramp):  # the gripper lifts along -Z with a growing acceleration: -m a points along +Z
        yield g, np.array([0.0, 0.0, c.lift_acceleration]) * (k + 1) / n_ramp
    n_hold = int(round(c.hold_time / dt))
    for _ in range(n_hold):
        yield g, zero
    target = np.asarray(p.gravity, dtype=np.float64)
    angle = math.acos(min(1.0, max(-1.0, float(target[2]))))
    if angle > 1e-6:  # the robot turns the part: gravity swings from +Z to the target about Z x target
        axis = np.cross([0.0, 0.0, 1.0], target)
        axis = np.array([1.0, 0.0, 0.0]) if np.linalg.norm(axis) < 1e-9 else axis / np.linalg.norm(axis)
        n_turn = max(1, int(round(c.turn_time * angle / (math.pi / 2) / dt)))
        for k in range(n_turn):
            yield _rotation(axis, angle * (k + 1) / n_turn) @ g, zero
        g = c.gravity * target
        for _ in range(n_hold):
            yield g, zero
    accel = c.shake_acceleration if p.shake_acceleration is None else p.shake_acceleration
    directions = c.shake_directions if p.shake_directions is None else p.shake_directions
    n_shake = max(1, int(round(1.0 / c.shake_frequency / dt)))
    for v in directions:
        u = np.asarray(v, dtype=np.float64) / np.linalg.norm(v)
        for k in range(n_shake):  # the gripper accelerates along u A sin(...): the part feels the opposite
            yield g, -u * (accel * math.sin(2 * math.pi * (k + 0.5) / n_shake))


class BulletJudge:
    """One headless Bullet client for one part; `simulate` rebuilds the world for every grasp."""

    def __init__(self, part: BulletPart) -> None:
        if pybullet is None:
            raise RuntimeError("pybullet is not installed")
        self.part = part
        self.c = part.constants
        self.cid = pybullet.connect(pybullet.DIRECT)
        self.gripper_path = gripper_urdf(part.spec, self.c, os.path.join(part.workdir.name, "gripper.urdf"))

    def close(self) -> None:
        if self.cid is not None:
            pybullet.disconnect(self.cid)
            self.cid = None

    def __enter__(self) -> BulletJudge:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # -- the world -------------------------------------------------------------------------------------------------
    def _build(self, T_object_grasp: np.ndarray, width: float, p: physics.Perturbation) -> tuple[int, int]:
        c, part, spec, cid = self.c, self.part, self.part.spec, self.cid
        pb = pybullet
        pb.resetSimulation(physicsClientId=cid)
        pb.setPhysicsEngineParameter(
            fixedTimeStep=c.timestep,
            numSubSteps=0,
            numSolverIterations=int(c.solver_iterations),
            solverResidualThreshold=float(c.solver_residual_threshold),
            globalCFM=float(c.global_cfm),
            contactBreakingThreshold=c.contact_breaking_threshold,
            deterministicOverlappingPairs=1,
            enableSAT=int(c.enable_sat),
            enableConeFriction=int(c.cone_friction),
            physicsClientId=cid,
        )
        pb.setGravity(0.0, 0.0, 0.0, physicsClientId=cid)
        flags = pb.URDF_INITIALIZE_SAT_FEATURES | pb.URDF_USE_INERTIA_FROM_FILE
        gripper = pb.loadURDF(self.gripper_path, useFixedBase=True, flags=flags, physicsClientId=cid)
        q_open = max((spec.stroke - spec.open_width(width)) / 2, 0.0)
        for link in (-1, 0, 1):
            pb.changeDynamics(
                gripper,
                link,
                lateralFriction=1.0,  # Bullet's contact friction is the product of the two bodies' coefficients
                spinningFriction=0.0,
                rollingFriction=0.0,
                restitution=0.0,
                linearDamping=0.0,
                angularDamping=0.0,
                physicsClientId=cid,
            )
        for j in (0, 1):
            pb.resetJointState(gripper, j, q_open, 0.0, physicsClientId=cid)
            pb.setJointMotorControl2(
                gripper, j, pb.VELOCITY_CONTROL, targetVelocity=0.0, force=0.0, physicsClientId=cid
            )
        gear = pb.createConstraint(
            gripper,
            0,
            gripper,
            1,
            pb.JOINT_GEAR,
            [1.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            [0.0, 0.0, 0.0],
            physicsClientId=cid,
        )
        pb.changeConstraint(gear, gearRatio=-1.0, maxForce=10_000.0, erp=0.2, physicsClientId=cid)
        # the part: its link frame is its principal inertial frame, placed at inv(T_object_grasp)
        mu = part.friction if p.friction is None else float(p.friction)
        T_go = np.linalg.inv(np.asarray(T_object_grasp, dtype=np.float64))
        R = T_go[:3, :3] @ part.principal_axes
        pos = T_go[:3, :3] @ part.center_of_mass + T_go[:3, 3]
        body = pb.loadURDF(
            part.urdf_path, basePosition=pos.tolist(), baseOrientation=_quat_xyzw(R), flags=flags, physicsClientId=cid
        )
        pb.changeDynamics(
            body,
            -1,
            mass=part.mass * p.mass_scale,
            localInertiaDiagonal=(part.principal_moments * p.mass_scale).tolist(),
            lateralFriction=mu,
            spinningFriction=mu * c.patch_radius,
            rollingFriction=0.0,
            restitution=0.0,
            linearDamping=0.0,
            angularDamping=0.0,
            physicsClientId=cid,
        )
        # (a changeDynamics call with activationState and a link index silently changes nothing: calls of their own)
        for b in (gripper, body):
            pb.changeDynamics(b, -1, activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING, physicsClientId=cid)
        for b, links in ((gripper, (-1, 0, 1)), (body, (-1,))):
            for link in links:
                pb.changeDynamics(b, link, collisionMargin=c.collision_margin, physicsClientId=cid)
        return gripper, body

    def _pose(self, body: int) -> tuple[np.ndarray, np.ndarray]:
        """The part's object frame in the world (grasp frame): position (3,), rotation (3, 3)."""
        pos, q = pybullet.getBasePositionAndOrientation(body, physicsClientId=self.cid)
        R_wp = _matrix(q)
        R = R_wp @ self.part.principal_axes.T
        return np.asarray(pos) - R @ self.part.center_of_mass, R

    def _touching(self, body: int, gripper: int) -> tuple[int, int, float]:
        """Touching contact points of the part with finger 0, finger 1, and the deepest penetration (m, >= 0)."""
        n, deepest = [0, 0], 0.0
        for link in (0, 1):
            for cp in pybullet.getContactPoints(body, gripper, -1, link, physicsClientId=self.cid):
                if cp[8] < self.c.touch_distance:
                    n[link] += 1
                    deepest = max(deepest, -cp[8])
        return n[0], n[1], deepest

    # -- one grasp -------------------------------------------------------------------------------------------------
    def _surface_overlaps(self, T_object_grasp: np.ndarray, width: float) -> set[int]:
        """Gripper links (-1 the palm, 0 and 1 the fingers at the pre-grasp opening) whose box, shrunk by the start
        tolerance, holds a sample of the part's own surface at the grasp."""
        part, spec, tol = self.part, self.part.spec, self.c.start_tolerance
        T_go = np.linalg.inv(np.asarray(T_object_grasp, dtype=np.float64))
        q = part.surface_points @ T_go[:3, :3].T + T_go[:3, 3]
        boxes = dict(enumerate(spec.finger_boxes(spec.open_width(width))))
        if spec.palm_box() is not None:
            boxes[-1] = spec.palm_box()
        out = set()
        for link, box in boxes.items():
            half = np.asarray(box.extents) / 2 - tol
            if np.all(half > 0) and np.any(np.all(np.abs(q - np.asarray(box.center)) < half, axis=1)):
                out.add(link)
        return out

    def simulate(
        self, T_object_grasp: np.ndarray, width: float, perturbation: physics.Perturbation | None = None
    ) -> BulletResult:
        pb, c, cid = pybullet, self.c, self.cid
        p = perturbation or physics.NOMINAL
        gripper, body = self._build(T_object_grasp, float(width), p)
        deep: dict[int, float] = {}
        for cp in pb.getClosestPoints(body, gripper, 0.0, physicsClientId=cid):
            deep[cp[4]] = max(deep.get(cp[4], 0.0), -cp[8])
        start_pen = max([0.0, *deep.values()])
        overlap = None
        out = {"start_penetration_mm": start_pen * 1e3, "member": p.name}
        if start_pen > c.start_tolerance:
            if self._surface_overlaps(T_object_grasp, float(width)):
                return BulletResult(False, "collision", 0.0, 0.0, 0, max_penetration_mm=0.0, **out)
            # only the pieces reach into the gripper: V-HACD's slack over a groove or recess of the part. Into the
            # palm: the palm collides with nothing for this grasp (Bullet would push the part out of a penetration
            # that is not real and fling it from the pads); into an open pad: simulated as it is, and said
            if any(deep.get(j, 0.0) > c.start_tolerance for j in (0, 1)):
                overlap = "pad"
            else:
                overlap = "palm"
                pb.setCollisionFilterPair(body, gripper, -1, -1, 0, physicsClientId=cid)
        out["start_overlap"] = overlap
        for j in (0, 1):
            pb.setJointMotorControl2(
                gripper,
                j,
                pb.VELOCITY_CONTROL,
                targetVelocity=c.closing_speed,
                force=self.part.grip_force,
                physicsClientId=cid,
            )
        for _ in range(max(1, int(round(c.close_time / c.timestep)))):
            pb.stepSimulation(physicsClientId=cid)
        n0, n1, deepest = self._touching(body, gripper)
        contacts = n0 + n1
        if n0 == 0 or n1 == 0:
            return BulletResult(False, "no_contact", 0.0, 0.0, contacts, max_penetration_mm=deepest * 1e3, **out)
        mid_obj = np.asarray(T_object_grasp, dtype=np.float64)[:3, 3]
        p_ref, R_ref = self._pose(body)
        mid_ref = R_ref @ mid_obj + p_ref
        mass = self.part.mass * p.mass_scale
        slip = rot = lost = 0.0
        dt = c.timestep * c.check_steps
        for g, a in loads(c, p, dt):
            pb.setGravity(*g.tolist(), physicsClientId=cid)
            force = (mass * a).tolist()
            for _ in range(c.check_steps):
                com = pb.getBasePositionAndOrientation(body, physicsClientId=cid)[0]
                pb.applyExternalForce(body, -1, force, com, pb.WORLD_FRAME, physicsClientId=cid)
                pb.stepSimulation(physicsClientId=cid)
            pos, R = self._pose(body)
            slip = max(slip, float(np.linalg.norm(R @ mid_obj + pos - mid_ref)))
            cos = (np.trace(R_ref.T @ R) - 1.0) / 2.0
            rot = max(rot, math.degrees(math.acos(min(1.0, max(-1.0, cos)))))
            n0, n1, d = self._touching(body, gripper)
            deepest = max(deepest, d)
            lost = lost + dt if (n0 == 0 or n1 == 0) else 0.0
            if slip > c.drop_distance or lost > c.lost_contact_time:
                return BulletResult(
                    False, "dropped", slip * 1e3, rot, contacts, max_penetration_mm=deepest * 1e3, **out
                )
        ok = not (slip > c.slip_limit or rot > c.rotation_limit_deg)
        reason = None if ok else "slipped"
        return BulletResult(ok, reason, slip * 1e3, rot, contacts, max_penetration_mm=deepest * 1e3, **out)

    def simulate_members(self, T_object_grasp: np.ndarray, width: float, members) -> list[BulletResult]:
        """One grasp under every perturbation of `members` (in order)."""
        return [self.simulate(T_object_grasp, width, m) for m in members]


def members(seed: int = 0) -> list[physics.Perturbation]:
    """The nominal simulation and physics.perturbation_set(seed): what bench_hold judges MuJoCo with."""
    return [physics.NOMINAL, *physics.perturbation_set(seed)]


def with_constants(part: BulletPart, **changes) -> BulletPart:
    """The same part under other constants (not the decomposition's)."""
    return replace(part, constants=replace(part.constants, **changes))
