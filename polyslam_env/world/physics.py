"""The pymunk world: differential-drive robots among static walls and pillars (SPEC §2).

One :class:`World` is one episode: it owns a fresh ``pymunk.Space`` (the env builds a new World
at every reset), the robot bodies and the sensors. Design choices (the spec is silent on them):

* Robots are dynamic circles with **infinite moment** and **zero friction / elasticity**: the
  wheels alone set the heading (contacts never spin a robot), a robot pushing a wall at an angle
  slides along it, and nothing bounces.
* The command is a velocity, applied in pymunk's velocity phase of every sub-step, *after*
  collision detection and *before* the contact solver, so the solver removes the part of the
  motion that goes into an obstacle before any position moves. (Setting ``body.velocity`` before
  ``space.step`` does not work: pymunk moves positions first, and a robot pushing a wall sinks
  in by several centimetres.) It is done without a Python callback: ``space.damping = 0`` drops
  all velocity at each velocity phase, and a drive force ``m v / h`` along the heading then
  gives exactly the commanded velocity (no momentum is carried between sub-steps). Each sub-step
  moves along the chord of the sub-step's arc (mid-step heading, speed × sinc(ω h / 2)), so a
  free robot lands exactly on the unicycle arc. The heading is kept by this class (θ += ω h
  per sub-step; a circle's contacts do not depend on it) and written to ``body.angle`` once per
  control step.
* Pymunk has no speculative contacts, so a robot could overlap an obstacle by up to one sub-step
  of travel on first impact. The collision shapes therefore carry a **skin** of
  ``v_max · dt / substeps`` (one sub-step at full speed) and ``collision_slop`` equals it: a
  contact starts up to a skin before the true circles touch and blocks further approach, but is
  never pushed apart unless the true shapes overlap. Robots thus never overlap walls, pillars or
  each other, and stop between 0 and one skin (3 cm by default: 10 sub-steps) short of them.
* ``collided`` means a contact pushed on the robot during the step: a robot driving into a wall
  or another robot, or being pushed; gliding past within the skin is not. It is read from the
  motion, not from a contact callback (chipmunk calling Python at every contact of every
  sub-step cost ~10 Python calls each): a free robot lands on its commanded chords to round-off
  (damping 0, the drive force gives the velocity exactly), and any contact impulse changes a
  velocity and so the end position; a robot whose end differs from its free end by more than
  ``PUSH_TOLERANCE`` was pushed.
* A guard checks every control step that no robot centre crossed a wall and that no robot
  overlaps one by more than ``GUARD_TOLERANCE``; a violation puts the robot back where the step
  started, marks it collided and counts it in ``guard_reverts``. The only case seen: a robot
  pushed by another into a gap narrower than itself (between a wall and a wall end), where
  pymunk's solver settles at ~2 mm overlap.
* A failed robot (``disable``) becomes a static body: it stays as an obstacle, cannot be pushed,
  ignores commands, and cameras no longer see it (nor does it see). Its odometry is noise only;
  noise is drawn for every robot every step so the streams do not depend on failures.
* Walls are thick (``wall_radius``) only for the physics; sensors see thin lines.
* The step around pymunk is lean (issue 15): drive forces, the guard and the sensors are
  compiled kernels (:mod:`~polyslam_env.world.kernels`, walls looked up in the layout's static
  :class:`~polyslam_env.world.nearby.WallIndex`), and the sub-step loop calls chipmunk's C
  functions through pymunk's cffi ``lib`` directly: ``Space.step`` and the ``Body`` properties
  check and queue things this world never uses (bodies added during a step, post-step
  callbacks) and cost more than the physics of a few robots.
* Faults (issue 14): ``step(commands, slip)`` makes slipping wheels move the robot ``slip``
  times the commanded motion while the odometry reports the unslipped displacement (the true
  displacement divided by ``slip``, component-wise: exact for straight lines and turns in
  place, first order in ω·dt for arcs); :meth:`World.displace` moves a robot's true pose
  without any odometry (a kidnap).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pymunk
from pymunk._chipmunk_cffi import lib as chipmunk

from polyslam_env.core.errors import MapFileError
from polyslam_env.core.geometry import between, wrap_angle
from polyslam_env.world import kernels
from polyslam_env.world.config import WorldConfig
from polyslam_env.world.layout import Layout
from polyslam_env.world.nearby import wall_index
from polyslam_env.world.point_sensor import PillarReading, PillarSensor
from polyslam_env.world.sensors import Camera, CameraFrame, Detection, RangeSensor

#: Solver iterations per physics step, fixed so results do not depend on pymunk defaults; 40
#: (not pymunk's 10) keeps a robot pushed into a wall corner within 0.1 mm of it.
SOLVER_ITERATIONS = 40
#: Share of a true-shape overlap that the solver removes in one sub-step.
OVERLAP_CORRECTION = 0.5
#: Overlap of the true shapes (beyond the skin) that the guard tolerates, m.
GUARD_TOLERANCE = 1e-3
#: Distance from its free end beyond which a robot counts as pushed, m: 1 nm, ~10^5 times the
#: round-off of summing a control step's sub-steps in another order at building scale (~1e-14 m
#: at 100 m), ~10^-7 of a sub-step.
PUSH_TOLERANCE = 1e-9


@dataclass(frozen=True)
class StepResult:
    """What one control step produced, per robot."""

    odometry: np.ndarray  # (N, 3): noisy (dx, dy, dθ) in the robot frame at the step start
    true_odometry: np.ndarray  # (N, 3): the displacement actually made, noiseless
    collided: np.ndarray  # (N,) bool: a contact pushed on the robot during the step
    commands: np.ndarray  # (N, 2): the clipped (v, ω) actually applied


class World:
    """Robots, walls and pillars in one pymunk space, plus range beams and a camera."""

    def __init__(
        self,
        layout: Layout,
        config: WorldConfig,
        num_robots: int,
        rngs: dict[str, np.random.Generator],
        start_poses: np.ndarray | None = None,
        recycle: World | None = None,
    ) -> None:
        """``recycle``: the previous episode's world on the same layout, whose pymunk space
        (its static walls and pillars) this world takes over instead of building its own
        (:meth:`_take_space`); that world can no longer step."""
        self.layout = layout
        self.config = config
        self.num_robots = num_robots
        self.rngs = rngs
        self.range_sensor = RangeSensor(config.range_sensor)
        self.camera_sensor = Camera(config.camera)
        self.segments = layout.segments  # (S, 4), thin lines for sensing
        self.pillars = np.asarray(layout.pillars, dtype=float).reshape(-1, 3)  # (P, 3)
        self.skin = config.robot.v_max * config.dt / config.substeps  # m, see module doc
        self.walls = wall_index(layout)  # static index of the segments (sensors, guard)
        #: pillar sensing (None when off); the true descriptors come from ``rngs["pillars"]``
        self.pillar_sensor = (
            PillarSensor(config.pillar_sensor, self.pillars, rngs["pillars"])
            if config.pillar_sensor.enabled
            else None
        )
        self._walls = self.walls.arrays
        r = config.robot.radius
        self._clearance = (r + config.wall_radius - GUARD_TOLERANCE, r - GUARD_TOLERANCE)
        rc = config.robot
        self._cmd_lo = np.array([-rc.v_max if rc.allow_reverse else 0.0, -rc.omega_max])  # (2,)
        self._cmd_hi = np.array([rc.v_max, rc.omega_max])  # (2,)
        odo = config.odometry
        self._odo_sigma = np.array([odo.sigma_xy, odo.sigma_xy, odo.sigma_theta])  # (3,)
        self.active = np.ones(num_robots, dtype=bool)  # (N,)
        self.guard_reverts = 0
        self._h = config.dt / config.substeps  # s, one physics sub-step
        self._v = [0.0] * num_robots  # commanded speed of each robot this control step
        self._w = [0.0] * num_robots  # commanded turn rate
        self._touched = np.zeros(num_robots, dtype=bool)  # (N,), pushed this step (module doc)
        self._pose = self._start_poses(start_poses)  # (N, 3), θ unwrapped like pymunk's
        self._wrapped = self._pose  # (N, 3): _wrapped_of with θ wrapped (see ``poses``)
        self._wrapped_of: np.ndarray | None = None
        self.space = self._take_space(recycle) or self._make_space()
        self.bodies = [self._add_robot(p) for p in self._pose]
        self._attach_chipmunk()

    def _attach_chipmunk(self) -> None:
        """Chipmunk's pointers of the space and the robot bodies (see the module doc)."""
        self._space_c: Any = self.space._space  # cpSpace*; None once recycled
        self._bodies_c = [b._body for b in self.bodies]  # cpBody* of each robot

    def __getstate__(self) -> dict[str, Any]:
        """Pickled without the C pointers (pymunk pickles the space and bodies)."""
        state = self.__dict__.copy()
        for name in ("_space_c", "_bodies_c"):
            del state[name]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._attach_chipmunk()

    # -- construction -----------------------------------------------------------------------
    def _start_poses(self, start_poses: np.ndarray | None) -> np.ndarray:
        """The (N, 3) start poses, validated: inside the map, clear of walls and each other."""
        n = self.num_robots
        if n < 1:
            raise ValueError(f"num_robots: must be >= 1, got {n}")
        if start_poses is None:
            have = self.layout.num_start_poses
            if have < n:
                raise MapFileError(
                    f"map {self.layout.name!r}: start_poses has {have} poses,"
                    f" {n} robots need one each"
                )
            start_poses = self.layout.start_poses[:n]
        poses = np.asarray(start_poses, dtype=float)
        if poses.shape != (n, 3) or not np.all(np.isfinite(poses)):
            raise ValueError(f"start_poses: expected ({n}, 3) finite values, got {poses!r}")
        r = self.config.robot.radius
        inside = self.layout.contains(poses[:, :2])
        clear = self.layout.clearance(poses[:, :2])
        for i in range(n):
            if not inside[i] or clear[i] < r + self.config.wall_radius:
                raise ValueError(
                    f"start_poses[{i}]: {tuple(poses[i])} is outside the map or within"
                    f" {r + self.config.wall_radius:g} m of a wall or pillar"
                )
        rel = poses[:, None, :2] - poses[None, :, :2]  # (N, N, 2)
        gap = np.hypot(rel[..., 0], rel[..., 1])  # (N, N)
        gap[np.diag_indices(n)] = np.inf
        if n > 1 and gap.min() < 2 * r:
            a, b = np.unravel_index(int(np.argmin(gap)), gap.shape)
            raise ValueError(f"start_poses[{a}] and start_poses[{b}] overlap")
        return poses.copy()

    def _make_space(self) -> pymunk.Space:
        """A fresh space with fixed solver settings and the static walls and pillars."""
        space = pymunk.Space()
        space.gravity = (0.0, 0.0)
        space.damping = 0.0  # velocity = drive force · h / m at every sub-step (module doc)
        space.iterations = SOLVER_ITERATIONS
        space.collision_slop = self.skin
        space.collision_bias = (1.0 - OVERLAP_CORRECTION) ** (1.0 / self._h)  # left after 1 s
        space.sleep_time_threshold = float("inf")  # never sleep: commands change every step
        static = space.static_body
        for x0, y0, x1, y1 in self.segments:
            seg = pymunk.Segment(static, (x0, y0), (x1, y1), self.config.wall_radius)
            seg.friction, seg.elasticity = 0.0, 0.0
            space.add(seg)
        for x, y, rad in self.pillars:
            circ = pymunk.Circle(static, rad, (x, y))
            circ.friction, circ.elasticity = 0.0, 0.0
            space.add(circ)
        return space

    def _take_space(self, old: World | None) -> pymunk.Space | None:
        """``old``'s space, emptied of its robots, when it holds this world's static shapes
        (same layout and world config); None otherwise, or when a robot of ``old`` failed
        (its body went static and changed the static index).

        Building the walls is most of a reset on a fixed map (~190 pymunk segments on the
        paper map, each a handful of Python calls). The emptied space is the fresh one to the
        bit: the robots' bodies and shapes leave with their contacts, and the two counters a
        fresh space starts at zero go back there, the shape id counter (hash ids order the
        collision pairs and so the contact solver) to the number of static shapes, and the
        previous step's length (it scales cached impulses) to zero. The space's timestamps
        only ever count relative to each other. ``tests/world/test_physics.py`` checks whole
        episodes against fresh worlds."""
        if (
            old is None
            or old._space_c is None
            or old.layout is not self.layout
            or old.config != self.config
            or not old.active.all()
        ):
            return None
        space = old.space
        for body in old.bodies:
            space.remove(*body.shapes, body)
        chipmunk.cpSpaceSetShapeIDCounter(space._space, len(self.segments) + len(self.pillars))
        chipmunk.cpSpaceSetCurrentTimeStep(space._space, 0.0)
        old.bodies, old._space_c, old._bodies_c = [], None, []
        return space

    def _add_robot(self, pose: np.ndarray) -> pymunk.Body:
        """A dynamic circle (radius + skin) with infinite moment, frictionless, driven."""
        body = pymunk.Body(self.config.robot.mass, float("inf"))
        body.position = (float(pose[0]), float(pose[1]))
        body.angle = float(pose[2])
        shape = pymunk.Circle(body, self.config.robot.radius + self.skin)
        shape.friction, shape.elasticity = 0.0, 0.0
        self.space.add(body, shape)
        return body

    # -- state ------------------------------------------------------------------------------
    @property
    def poses(self) -> np.ndarray:  # (N, 3)
        """True poses (x, y, θ), θ wrapped to (−π, π]."""
        if self._wrapped_of is not self._pose:  # the poses changed: wrap once per change
            wrapped = self._pose.copy()
            wrapped[:, 2] = wrap_angle(wrapped[:, 2])
            self._wrapped, self._wrapped_of = wrapped, self._pose
        return self._wrapped.copy()

    def robot_fits(self, i: int, pose: np.ndarray) -> bool:
        """Whether robot ``i`` could stand at ``pose`` (3,): clear of walls and pillars like a
        start pose, and of the other robots by two radii plus the contact skin."""
        xy = np.asarray(pose, dtype=float)[None, :2]  # (1, 2)
        r = self.config.robot.radius
        if (
            not self.layout.contains(xy)[0]
            or self.layout.clearance(xy)[0] < r + self.config.wall_radius
        ):
            return False
        others = np.delete(self._pose[:, :2], i, axis=0)  # (N-1, 2)
        gap = np.hypot(*(others - xy).T)
        return bool(np.all(gap >= 2 * (r + self.skin)))

    def displace(self, i: int, pose: np.ndarray) -> None:
        """Put robot ``i`` at ``pose`` (3,) at once (a kidnap): no odometry reports it. The
        caller checks :meth:`robot_fits`."""
        x, y, th = (float(v) for v in pose)
        self._pose[i] = (x, y, th)
        self._wrapped_of = None  # changed in place
        body = self.bodies[i]
        body.position = (x, y)
        body.angle = th
        body.velocity = (0.0, 0.0)
        self.space.reindex_shapes_for_body(body)

    def disable(self, i: int) -> None:
        """Fail robot ``i``: it stops, becomes an immovable obstacle and leaves camera views."""
        if not self.active[i]:
            return
        self.active[i] = False
        body = self.bodies[i]
        body.velocity = (0.0, 0.0)
        body.body_type = pymunk.Body.STATIC
        self.space.reindex_shapes_for_body(body)

    # -- stepping ---------------------------------------------------------------------------
    def clip_commands(self, commands: np.ndarray) -> np.ndarray:
        """Validate (N, 2) commands and clip (v, ω) to the robot limits; failed robots get 0."""
        cmd = np.asarray(commands, dtype=float)
        if cmd.shape != (self.num_robots, 2):
            raise ValueError(f"commands: expected shape ({self.num_robots}, 2), got {cmd.shape}")
        out = np.empty((self.num_robots, 2))
        i = kernels.clip_commands(cmd, self._cmd_lo, self._cmd_hi, self.active, out)
        if i >= 0:
            raise ValueError(f"commands[{i}] (robot_{i}): not finite, got {tuple(cmd[i])}")
        return out

    def step(self, commands: np.ndarray, slip: np.ndarray | None = None) -> StepResult:
        """Drive every robot with its (v, ω) for one control period ``dt``.

        ``slip`` (N,) in (0, 1], default all 1: robot i moves ``slip[i]`` times its command and
        its odometry reports the true displacement divided by ``slip[i]`` (module doc).
        """
        if self._space_c is None:
            raise RuntimeError("World.step: this world's space went to the next episode's world")
        cmd = self.clip_commands(commands)
        start = self._pose
        scale = None if slip is None else np.asarray(slip, dtype=float)  # (N,)
        end = self._integrate(cmd if scale is None else cmd * scale[:, None])
        self._pose = self._guard(start, end)
        true_odo = between(start, self._pose)
        reported = true_odo if scale is None else true_odo / scale[:, None]
        noise = self.rngs["motion"].standard_normal((self.num_robots, 3)) * self._odo_sigma
        return StepResult(
            odometry=reported + noise,
            true_odometry=true_odo,
            collided=self._touched,  # a new array every step
            commands=cmd,
        )

    def _integrate(self, cmd: np.ndarray) -> np.ndarray:
        """Run the sub-steps; return the end poses (N, 3), θ unwrapped.

        Robots start the period at rest. Pymunk moves positions with the velocity solved in the
        previous sub-step, so the first sub-step does not move them and the translation solved
        in the last one is applied here by hand: each period moves by exactly ``substeps``
        solved sub-steps and turns by exactly ``ω dt``. Each sub-step moves along the chord of
        its arc (mid-step heading, speed × sinc(ω h / 2)), so a free robot lands exactly on the
        unicycle arc; force m·v/h gives velocity v (damping 0). Sets ``_touched``: the robots
        whose end is off their free end (module doc).
        """
        n, h = self.config.substeps, self._h
        th0 = self._pose[:, 2]  # (N,)
        force = np.empty((self.num_robots, n, 2))
        kernels.drive_forces(th0, cmd, h, n, self.config.robot.mass, force)
        forces = force.tolist()
        # Robots with v = 0 need no force (damping 0 stops them) but may still be pushed.
        driven = [(b, forces[i]) for i, b in enumerate(self._bodies_c) if cmd[i, 0] != 0.0]
        set_force, space_step, space = chipmunk.cpBodySetForce, chipmunk.cpSpaceStep, self._space_c
        for k in range(n):
            for body, f in driven:
                set_force(body, f[k])
            space_step(space, h)
        end = np.empty((self.num_robots, 3))
        for i, (body, active) in enumerate(zip(self._bodies_c, self.active.tolist(), strict=True)):
            if active:
                p, vel = chipmunk.cpBodyGetPosition(body), chipmunk.cpBodyGetVelocity(body)
                chipmunk.cpBodySetPosition(body, (p.x + vel.x * h, p.y + vel.y * h))
                chipmunk.cpBodySetVelocity(body, (0.0, 0.0))
            p = chipmunk.cpBodyGetPosition(body)
            end[i, 0], end[i, 1] = p.x, p.y
        # The heading turns by ω dt; free motion is the sum of the sub-steps' velocities f·h/m,
        # each held for h: a robot whose end is off that was pushed.
        self._touched = np.empty(self.num_robots, dtype=bool)
        drift = h * h / self.config.robot.mass
        kernels.motion_end(
            self._pose, cmd, self.config.dt, force, drift, PUSH_TOLERANCE, end, self._touched
        )
        return end

    def _guard(self, start: np.ndarray, end: np.ndarray) -> np.ndarray:
        """Put back any robot whose centre crossed a wall or ended inside one (module doc).

        start, end (N, 3); returns the poses after the guard (``end``, changed), and syncs the
        bodies' angles. Wall segments come from the static index around each robot's path.
        """
        bad = np.empty(self.num_robots, dtype=bool)
        wall_gap, pillar_gap = self._clearance
        kernels.guard_violations(
            start, end, self.active, wall_gap, pillar_gap, *self._walls, self.pillars, bad
        )
        for i in bad.nonzero()[0].tolist():
            end[i] = start[i]
            chipmunk.cpBodySetPosition(self._bodies_c[i], (float(start[i, 0]), float(start[i, 1])))
            self._touched[i] = True
            self.guard_reverts += 1
        active = self.active.tolist()
        for body, th, a in zip(self._bodies_c, end[:, 2].tolist(), active, strict=True):
            if a:
                chipmunk.cpBodySetAngle(body, th)
        return end

    # -- sensing ----------------------------------------------------------------------------
    def true_scan(self) -> np.ndarray:  # (N, B)
        """Noiseless ranges of every robot's beams (``inf`` = no return)."""
        return self.range_sensor.true_ranges(
            self._pose, self.walls, self.pillars, self.config.robot.radius
        )

    def scan(self) -> np.ndarray:  # (N, B)
        """Noisy ranges (noise from ``rngs["sensor"]``), clipped to ≥ 0; no return is ``inf``."""
        return self.range_sensor.measure(
            self._pose, self.walls, self.pillars, self.rngs["sensor"], self.config.robot.radius
        )

    def scan_with_truth(self) -> tuple[np.ndarray, np.ndarray]:  # (N, B) each
        """Noiseless and noisy ranges from one ray cast; the noisy ones are exactly what
        :meth:`scan` would return (same draws from ``rngs["sensor"]``)."""
        true = self.true_scan()
        return true, self.range_sensor.add_noise(true, self.rngs["sensor"])

    def sense_pillars(self) -> list[PillarReading]:
        """Per robot, the pillars it sees (noise from ``rngs["pillar_sensor"]``; failed robots
        see none). Needs ``config.pillar_sensor.enabled``."""
        if self.pillar_sensor is None:
            raise RuntimeError("sense_pillars: the pillar sensor is off (pillar_sensor.enabled)")
        return self.pillar_sensor.sense(
            self._pose, self.active, self.walls, self.rngs["pillar_sensor"]
        )

    def camera(self) -> list[list[Detection]]:
        """Per robot, the other robots it sees (noise from ``rngs["camera"]``)."""
        return self.camera_frame().lists()

    def camera_frame(self) -> CameraFrame:
        """:meth:`camera` as arrays (the same draws)."""
        return self.camera_sensor.frame(
            self._pose, self.active, self.walls, self.pillars, self.rngs["camera"]
        )
