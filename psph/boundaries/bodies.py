"""Walls and bodies: profiles, prescribed rigid motion, solid particles and the per-body bookkeeping.

A body's material points follow x(t) = c0 + d(t) + R(theta(t)) (x_ref - c0), with velocity
v(t) + omega e_z x (x - c) and acceleration a(t) + alpha e_z x r - omega^2 r (r = x - c). The translation
follows the body's motion law, the rotation its rotation_law (the same law unless given; MotionSpec). A
box body may have a lid: its top side moves tangentially with `lid_velocity` while the particles stay in
place (a cavity).
"""

import math

import numpy as np

from psph.boundaries.geometry import (
    Profile,
    counterclockwise,
    distance_to_polygon,
    ellipse_profile,
    inside,
    nearest_nodes,
    polygon_centroid,
    polygon_profile,
    rectangle_profile,
    shape_spec,
    sharp_corner_points,
    solid_particles,
)
from psph.particles import Kind

SPHERIC6 = (2.8209512, 0.525652151, 0.14142151)  # amplitude, centre, width of the benchmark acceleration
MOTION_SAMPLES = 5000  # check_placement: most times at which a prescribed motion is checked
PERIOD_STEPS = 20  # check_placement: fewest time steps an oscillation's period may span


def smooth_ramp(t, ramp):
    """(displacement, velocity, acceleration) at time t of a unit velocity reached smoothly over `ramp`,
    tau^2 (3 - 2 tau) with tau = t / ramp (a body's "ramp" law, an inflow's ramp_time); ramp = 0: the unit
    velocity from t = 0."""
    tau = t / ramp if ramp > 0.0 else math.inf
    if tau >= 1.0:
        return ramp * 0.5 + (t - ramp), 1.0, 0.0
    return ramp * (tau**3 - 0.5 * tau**4), tau * tau * (3.0 - 2.0 * tau), 6.0 * tau * (1.0 - tau) / ramp


class MotionLaw:
    """Scalar law s(t), s'(t), s''(t) scaled so that s'(t) reaches 1 (times the body's velocity vector, or
    its angular velocity). law: another law than spec.law with spec's parameters (the rotation's)."""

    def __init__(self, spec, law=None):
        self.law, self.ramp, self.period = law or spec.law, spec.ramp_time, spec.period
        if self.law == "spheric6":  # tabulate the integral of the benchmark velocity once
            t = np.linspace(0.0, 1.0, 20001)
            v = self._spheric_velocity(t)
            self._t, self._v = t, v / v[-1]
            self._d = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]) * np.diff(t))]) / v[-1]

    @staticmethod
    def _spheric_velocity(t):
        amp, mu, sigma = SPHERIC6
        k = sigma * math.sqrt(2.0)
        erf = np.vectorize(math.erf)
        return amp * sigma * math.sqrt(math.pi / 2.0) * (erf((np.asarray(t) - mu) / k) + math.erf(mu / k))

    def __call__(self, t):
        """(displacement, velocity, acceleration) of the unit law at time t."""
        if self.law == "fixed":
            return 0.0, 0.0, 0.0
        if self.law == "constant":
            return t, 1.0, 0.0
        if self.law == "oscillate":
            k = 2.0 * math.pi / self.period
            return math.sin(k * t) / k, math.cos(k * t), -k * math.sin(k * t)
        if self.law == "ramp":
            return smooth_ramp(t, self.ramp)
        # spheric6
        if t >= 1.0:
            return float(self._d[-1]) + (t - 1.0), 1.0, 0.0
        amp, mu, sigma = SPHERIC6
        accel = amp * math.exp(-((t - mu) ** 2) / (2.0 * sigma**2)) / self._v_scale()
        return float(np.interp(t, self._t, self._d)), float(np.interp(t, self._t, self._v)), accel

    def _v_scale(self):
        return float(self._spheric_velocity(np.array([1.0]))[0])


class Body:
    """One wall or immersed body of the scene."""

    def __init__(self, spec, index, dx, stream, domain=None):
        """`domain` (the scene's DomainSpec): along a periodic axis, which it spans, a container is its plates,
        continued across the axis' edges (_periodic_plates)."""
        self.spec, self.index, self.name = spec, index, spec.name
        self.dx = dx
        ds = dx / 4.0
        if spec.shape == "ellipse":
            self.profile = ellipse_profile(spec.center, spec.size, spec.angle, ds, fluid_inside=False)
        elif spec.shape == "polygon":
            self.profile = polygon_profile(spec.vertices, ds, fluid_inside=spec.container)
        else:
            self.profile = rectangle_profile(spec.center, spec.size, spec.angle, ds,
                                             fluid_inside=spec.shape == "box")
        periodic = tuple(domain.periodic) if domain is not None and spec.container else (False, False)
        if any(periodic):
            self.profile = _periodic_plates(self.profile, domain, ds)
        self.center0 = np.asarray(spec.center or polygon_centroid(spec.vertices), dtype=np.float64)
        self.velocity = np.asarray(spec.motion.velocity or (0.0, 0.0), dtype=np.float64)
        # drag acts along the flow seen from the body: against its motion, or along the free stream (+x
        # without one) for a body at rest
        speed = float(np.linalg.norm(self.velocity))
        stream = np.asarray(stream, dtype=np.float64)
        self.drag_direction = -self.velocity / speed if speed > 0 else stream / np.linalg.norm(stream)
        self.omega = spec.motion.angular_velocity
        self.law = MotionLaw(spec.motion)
        self.turning = MotionLaw(spec.motion, spec.motion.turning_law)
        self.kind = Kind.WALL if spec.container else Kind.BODY
        self.no_slip = spec.wall == "no_slip"
        self.lid = np.zeros(len(self.profile.nodes), dtype=bool)
        if spec.lid_velocity:  # nodes on the top side of the box, its two corners excepted (none along periodic x)
            local = (self.profile.nodes - self.center0) @ _rot(spec.angle)
            tol = 1e-9 * max(spec.size)
            self.lid = local[:, 1] > spec.size[1] / 2.0 - tol
            if not periodic[0]:
                self.lid &= np.abs(local[:, 0]) < spec.size[0] / 2.0 - tol
        # given along the lid (the box's own frame): turned with the box (an audit: a box at 30 degrees moved
        # its lid at -0.5 U through itself)
        self.lid_velocity = np.asarray(spec.lid_velocity or (0.0, 0.0), dtype=np.float64) @ _rot(spec.angle).T
        self._fixed_nodes = None
        if spec.reference_length > 0:
            self.reference_length = spec.reference_length
        elif spec.shape == "polygon":  # its width
            lo, hi = bounds(spec)
            self.reference_length = hi[0] - lo[0]
        else:  # an ellipse's major axis, a rectangle's width
            self.reference_length = 2.0 * max(spec.size) if spec.shape == "ellipse" else spec.size[0]

    @property
    def moves(self) -> bool:
        return self.spec.motion.law != "fixed" or self.spec.motion.turning_law != "fixed"

    def rigid(self, t):
        """(centre, rotation matrix, velocity, omega, acceleration, alpha) at time t."""
        s, ds, dds = self.law(t)
        q, dq, ddq = self.turning(t)
        return (self.center0 + self.velocity * s, _rot_rad(self.omega * q), self.velocity * ds, self.omega * dq,
                self.velocity * dds, self.omega * ddq)

    def material(self, x_ref, t):
        """Positions, velocities and accelerations at time t of points with reference positions x_ref."""
        c, rot, v, om, a, al = self.rigid(t)
        r = (x_ref - self.center0) @ rot.T
        perp = np.stack([-r[:, 1], r[:, 0]], axis=1)
        return c + r, v + om * perp, a + al * perp - om * om * r

    def nodes(self, t):
        """Body nodes at time t: positions, normals and velocities (the lid's included); a fixed body's are
        computed once (read-only arrays)."""
        if not self.moves:
            if self._fixed_nodes is None:
                self._fixed_nodes = self._nodes(t)
                for a in self._fixed_nodes:
                    a.flags.writeable = False
            return self._fixed_nodes
        return self._nodes(t)

    def _nodes(self, t):
        pos, vel, _ = self.material(self.profile.nodes, t)
        _, rot, _, _, _, _ = self.rigid(t)
        normals = self.profile.normals @ rot.T
        vel = vel.copy()
        vel[self.lid] += self.lid_velocity @ rot.T
        return pos, normals, vel

    def solid_particles(self, lattice, volumes, thickness):
        """Reference positions, normals, distances, closest nodes and volumes of this body's solid particles
        (from the `lattice` points and their `volumes`; a polygon's corners sharper than 90 degrees on the
        solid side get one more each, with a lattice point's volume, geometry.sharp_corner_points)."""
        pos, node, dist, kept = solid_particles(self.profile, shape_spec(self.spec), lattice, thickness,
                                                with_index=True)
        vol = volumes[kept]
        if self.spec.shape == "polygon":
            tips, corners = sharp_corner_points(self.spec.vertices, self.spec.container, self.dx)
            # each takes its corner's node (the bisector's normal: the nearest node is one of the two beside the
            # corner, whichever a tie gives, which broke a symmetric flow's symmetry), dx/2 from the contour
            tip_node = nearest_nodes(self.profile, corners)[0]
            pos, node = np.vstack([pos, tips]), np.concatenate([node, tip_node])
            dist = np.concatenate([dist, np.full(len(tips), 0.5 * self.dx)])
            vol = np.concatenate([vol, np.full(len(tips), self.dx ** 2)])
        return pos, self.profile.normals[node], dist, node, vol


def _rot(angle_deg):
    return _rot_rad(np.deg2rad(angle_deg))


def _rot_rad(a):
    return np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])


def make_bodies(scene):
    stream = scene.physics.free_stream or (1.0, 0.0)
    return [Body(spec, k, scene.domain.dx, stream, scene.domain) for k, spec in enumerate(scene.bodies)]


def _periodic_plates(profile, domain, ds) -> Profile:
    """An unrotated box container's profile on a domain periodic along one axis, which the box spans
    (check_placement): its two plates, nodes every ~ds from the domain's lower edge along the axis, and
    their images one period to either side. Its sides have no solid particle behind them, and the fluid's
    closest node, whose distance s_i scales every clone's mirrored velocity (psph.compute.walls.clone_rhs),
    was a side's for the particles within dx/2 of the edges; nodes placed along the box's own width, not
    the domain's period, sat off the lattice by an amount that depended on that width (a walls audit, a
    review: the Couette flow varied along x by 2.4e-3 at t = 1 with plates as wide as the domain, 0.5, by
    2.3e-4 at t = 0.2 with 0.61, against round-off with the scene's, 10 wide)."""
    a = domain.periodic.index(True)
    period = domain.upper[a] - domain.lower[a]
    count = max(int(round(period / ds)), 1)
    along = domain.lower[a] + period * np.arange(-count, 2 * count) / count
    plate = np.abs(profile.normals[:, a]) < 1e-9
    nodes, normals, ends = [], [], []
    k = np.arange(len(along))
    for normal in (-1.0, 1.0):  # the plate whose normal (out of the fluid) points this way across the axis
        at = profile.nodes[plate & (profile.normals[:, 1 - a] == normal), 1 - a]
        points = np.empty((len(along), 2))
        points[:, a], points[:, 1 - a] = along, at[0]
        # each plate is an open line: its end nodes, a period beyond the domain, are their own neighbours
        ends.append(len(along) * len(nodes) + np.stack([np.maximum(k - 1, 0), np.minimum(k + 1, k[-1])], axis=1))
        nodes.append(points)
        normals.append(np.tile(np.eye(2)[1 - a] * normal, (len(along), 1)))
    return Profile(np.concatenate(nodes), np.concatenate(normals), profile.fluid_inside, np.concatenate(ends))


def check_placement(scene) -> None:
    """Refuse bodies that psph would build wrongly, with a SceneError naming the body's key: a body thinner
    than 2 dx (no solid particle would fill it), a box leaving the domain along a bounded axis, and, at
    t = 0 and along its prescribed motion to t_end, an immersed body leaving the domain (but past an outflow
    face, where its solid particles stop a kernel support plus dx out: the fluid is gone by then) or coming within
    one kernel support of a periodic edge (shapes and their nearest-node search do not wrap), coming
    within dx of a container's walls, overlapping another immersed body or coming within dx of it (no fluid
    particle between them: they acted as one body), or (moving) entering an inflow buffer. The motion is
    sampled so that no point of a body moves more than dx between samples (every law's speed stays within its
    velocity and angular velocity), over one period when every moving body oscillates with the same period, and with
    at most MOTION_SAMPLES samples (coarser for a longer motion). An oscillation shorter than
    PERIOD_STEPS time steps (cfl h / c0, the largest a run takes) is refused: it would not be resolved."""
    from psph.errors import SceneError

    d, dx = scene.domain, scene.domain.dx
    lower, upper = np.asarray(d.lower, dtype=float), np.asarray(d.upper, dtype=float)
    margin = np.where(d.periodic, d.support, 0.0)
    # an immersed body may reach past an outflow face (a plate the fluid leaves along): its solid particles
    # stop a kernel support plus dx past it (boundaries.extended_lattice), further than any fluid there sees
    lower = np.where([(a, -1) in d.outflow_faces() for a in range(2)], -np.inf, lower)
    upper = np.where([(a, 1) in d.outflow_faces() for a in range(2)], np.inf, upper)
    boxes = [(k, b) for k, b in enumerate(scene.bodies) if b.container]
    immersed = []
    for k, b in enumerate(scene.bodies):
        path = f"bodies[{k}]"
        extent = 2.0 * min(b.size) if b.shape == "ellipse" else min(b.size or bounds(b)[1] - bounds(b)[0])
        if extent < 2.0 * dx:
            raise SceneError(f"{path}.{'vertices' if b.shape == 'polygon' else 'size'}", f"{b.name!r} is "
                             f"{extent:g} thick, less than 2 dx = {2 * dx:g}: no solid particle would fill it")
        if b.shape == "polygon":
            _check_polygon_walls(b, path, dx)
        if b.container and b.shape == "polygon" and any(d.periodic):
            raise SceneError(f"{path}.shape", f"{b.name!r}: a polygon closes the fluid on every side, which a "
                             "periodic axis does not allow (domain.periodic; a box spanning one keeps its plates)")
        if b.container and any(d.periodic) and b.angle != 0.0:
            raise SceneError(f"{path}.angle", f"{b.name!r}: a container spans a periodic axis with its plates, "
                             "which meet themselves across it only unrotated (give angle = 0)")
        if b.container and all(d.periodic):
            raise SceneError(f"{path}.shape", f"{b.name!r}: a container would span both periodic axes, and keep "
                             "no wall (domain.periodic)")
        lo, hi = bounds(b)
        key = {"box": "size", "polygon": "vertices"}.get(b.shape, "center")
        for a in range(2):  # before any profile is built (a mistyped huge size would take long)
            if b.container and d.periodic[a] and hi[a] - lo[a] < d.upper[a] - d.lower[a] - 1e-9 * dx:
                raise SceneError(f"{path}.{key}", f"{b.name!r} is {hi[a] - lo[a]:g} long along the periodic axis "
                                 f"{a}, shorter than the domain ({d.upper[a] - d.lower[a]:g}): a container spans a "
                                 "periodic axis (its plates), or the fluid would cross its sides there")
            bounded = not d.periodic[a] or not b.container
            box_lo, box_hi = (d.lower[a], d.upper[a]) if b.container else (lower[a], upper[a])
            if bounded and (lo[a] < box_lo - 1e-9 * dx or hi[a] > box_hi + 1e-9 * dx):
                if key == "size" and hi[a] - lo[a] <= box_hi - box_lo:  # it would fit: placed wrong
                    key = "center"
                raise SceneError(f"{path}.{key}", f"{b.name!r} leaves the domain along axis {a}"
                                 + (": the fluid at the domain's edge would have no wall" if b.container else ""))
        dt = scene.time.cfl * d.h / scene.physics.sound_speed
        if "oscillate" in (b.motion.law, b.motion.turning_law) and b.motion.period < PERIOD_STEPS * dt:
            raise SceneError(f"{path}.motion.period", f"{b.motion.period:g} is shorter than {PERIOD_STEPS} time "
                             f"steps (cfl h / c0 = {dt:.3g}): the oscillation would not be resolved")
        if not b.container:
            immersed.append((k, Body(b, k, 4.0 * dx, (1.0, 0.0))))  # nodes every dx are enough here
    if not immersed:
        return
    buffers = [(np.asarray(f.lower, dtype=float), np.asarray(f.upper, dtype=float)) for f in scene.inflow
               if len(f.lower) == len(f.upper) == 2]
    times = [0.0]
    moving = [body for _, body in immersed if body.moves]
    if moving:
        reach = max(np.linalg.norm(body.velocity) + abs(body.omega) * np.linalg.norm(
            body.profile.nodes - body.center0, axis=1).max() for body in moving)
        horizon = scene.time.t_end
        periods = {body.spec.motion.period for body in moving}
        if all({body.spec.motion.law, body.spec.motion.turning_law} <= {"fixed", "oscillate"} for body in moving) \
                and len(periods) == 1:  # the whole motion repeats after one period
            horizon = min(horizon, periods.pop())
        samples = min(MOTION_SAMPLES, reach * horizon / dx + 2.0)  # float: a huge velocity is no overflow
        times = np.linspace(0.0, horizon, int(samples))
    for t in times:
        nodes = {k: body.nodes(t)[:2] for k, body in immersed}
        for k, body in immersed:
            x, normals = nodes[k]  # (the normals point into the body)
            # later than t = 0, the motion took it there (its own, or the other body's in an overlap)
            placed = "vertices" if body.spec.shape == "polygon" else "center"
            key = f"bodies[{k}].{placed}" if t == 0.0 or not body.moves else f"bodies[{k}].motion"
            for a in range(2):
                if x[:, a].min() < lower[a] + margin[a] or x[:, a].max() > upper[a] - margin[a]:
                    raise SceneError(key, f"{body.name!r} leaves the domain along axis {a} "
                                     f"at t = {t:g}" + (f" (or comes within a kernel support, {margin[a]:g}, of "
                                                        "its periodic edge)" if d.periodic[a] else ""))
            for j, box in boxes:
                if np.any(~inside(shape_spec(box), x) | (within_walls(box, x) < dx)):
                    raise SceneError(key, f"{body.name!r} comes within dx of the walls of "
                                     f"bodies[{j}] ({box.name!r}) at t = {t:g}")
            for j, other in immersed:
                if j != k and np.any(_inside(other, t, x)):
                    culprit = f"bodies[{j}].motion" if t > 0.0 and other.moves and not body.moves else key
                    raise SceneError(culprit, f"{body.name!r} overlaps bodies[{j}] ({other.name!r}) at t = {t:g}")
            for j, other in immersed:  # a gap below dx holds no fluid particle: the two would act as one body
                if j != k and np.any(_inside(other, t, x - (1.0 - 1e-9) * dx * normals)):
                    culprit = f"bodies[{j}].motion" if t > 0.0 and other.moves and not body.moves else key
                    raise SceneError(culprit, f"{body.name!r} comes within dx of bodies[{j}] ({other.name!r}) at "
                                     f"t = {t:g}: no fluid particle would fit between them")
            for j, (lo, hi) in enumerate(buffers):  # at t = 0 the scene's buffer check names the buffer
                if t > 0.0 and body.moves and np.any(np.all((x > lo) & (x < hi), axis=1)):
                    raise SceneError(key, f"{body.name!r} enters inflow[{j}]'s buffer at t = {t:g}")


def _check_polygon_walls(spec, path, dx) -> None:
    """Refuse a polygon whose solid is thinner than 2 dx between two of its sides that share no corner (a
    container's partition between two parts of the fluid, an immersed body's thin plate), which its bounding
    box does not show: no solid particle fills it, and fluid crossed it unseen (a failure audit: a tank's
    partition 0.8 dx thick let 63 particles through, and the run ended with exit 0). From points along every
    side (dx from its ends), a probe 2 dx long into the solid (out of a container, into an immersed body)
    along the side's normal must meet no other side but its neighbours (the solid coming to a point at a
    corner, a weir's crest or a sill, is no partition: a review)."""
    from psph.errors import SceneError

    v = np.asarray(spec.vertices, dtype=float)
    n = len(v)
    edges = np.roll(v, -1, axis=0) - v
    area = 0.5 * float(np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1]))

    def cross(a, b):
        return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]

    for i, (start, edge) in enumerate(zip(v, edges)):
        length = float(np.hypot(*edge))
        if length <= 2.0 * dx:
            continue
        # into the solid: out of the polygon (to the right of a counter-clockwise side) for a container
        outward = np.array([edge[1], -edge[0]]) / length * np.sign(area) * (1.0 if spec.container else -1.0)
        points = start + np.arange(dx, length - dx + 1e-9 * dx, 0.5 * dx)[:, None] * edge / length
        others = [j for j in range(n) if j not in (i, (i - 1) % n, (i + 1) % n)]
        if not others:
            continue
        a, b = v[others], edges[others]  # the other sides: a + u b, u in [0, 1]
        rel = a[None, :, :] - points[:, None, :]  # (point, side, 2)
        denom = cross(outward, b)  # (side,): parallel sides never meet the probe
        with np.errstate(divide="ignore", invalid="ignore"):
            depth = cross(rel, b[None]) / denom  # along the probe
            u = cross(rel, np.broadcast_to(outward, rel.shape)) / denom
        hits = (denom != 0.0) & (depth > 0.0) & (depth < 2.0 * dx * (1.0 - 1e-9)) & (u >= 0.0) & (u <= 1.0)
        if hits.any():
            k, m = np.unravel_index(np.argmin(np.where(hits, depth, np.inf)), hits.shape)
            at = points[k]
            raise SceneError(f"{path}.vertices", f"the wall of {spec.name!r} between its sides {i} ({start.tolist()} "
                             f"to {(start + edge).tolist()}) and {others[m]} is {depth[k, m]:.3g} thick at "
                             f"({at[0]:.6g}, {at[1]:.6g}), less than 2 dx = {2 * dx:g}: no solid particle would "
                             "fill it, and the fluid would cross it")


def within_walls(spec, points) -> np.ndarray:
    """Distance of points inside a container (box or polygon) to its walls (of any point to an immersed
    polygon's sides)."""
    if spec.shape == "polygon":
        return distance_to_polygon(spec.vertices, points)
    local = np.abs((points - np.asarray(spec.center)) @ _rot(spec.angle))
    return (np.asarray(spec.size, dtype=float) / 2.0 - local).min(axis=1)


def bounds(spec) -> tuple:
    """(lower, upper) corners of the axis-aligned box around a body at t = 0."""
    if spec.shape == "polygon":
        v = np.asarray(spec.vertices, dtype=float)
        return v.min(axis=0), v.max(axis=0)
    center = np.asarray(spec.center, dtype=float)
    return center - half_extent(spec), center + half_extent(spec)


def container_sides(spec) -> list:
    """The straight sides (a, b) of a container at t = 0 (box: its four, rotated; polygon: its edges), going
    counter-clockwise round the fluid, so that the solid lies to the right of each (along (b - a) rotated by
    -90 degrees): within a support of the sides."""
    if spec.shape == "polygon":
        corners = counterclockwise(spec.vertices)
    else:
        w, h = np.asarray(spec.size, dtype=float) / 2.0
        corners = np.asarray(spec.center) + np.array([[-w, -h], [w, -h], [w, h], [-w, h]]) @ _rot(spec.angle).T
    return [(corners[k], corners[(k + 1) % len(corners)]) for k in range(len(corners))]


def half_extent(spec):
    """Half the axis-aligned extent of a (possibly rotated) rectangle or ellipse (size: its semi-axes)."""
    c, s = abs(math.cos(math.radians(spec.angle))), abs(math.sin(math.radians(spec.angle)))
    if spec.shape == "ellipse":
        a, b = spec.size
        return np.array([math.hypot(a * c, b * s), math.hypot(a * s, b * c)])
    w, h = np.asarray(spec.size, dtype=float) / 2.0
    return np.array([w * c + h * s, w * s + h * c])


def _inside(body, t, points):
    """Points inside an immersed body at time t (taken back to its reference configuration)."""
    c, rot = body.rigid(t)[:2]
    spec = body.spec
    reference = (points - c) @ rot + body.center0
    return inside(shape_spec(spec), reference)
