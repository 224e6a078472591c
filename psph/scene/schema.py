"""The scene: what a TOML file may say, with types, defaults and limits.

Key paths are part of psph's interface (scripts set them with --set): keep them stable.
"""

import math
from dataclasses import dataclass

import numpy as np

from psph.compute.smoothing import KERNEL_NAMES
from psph.errors import SceneError
from psph.scene.validate import option

# Linf(grad C) at which a distribution is level to round-off (sums of ~50 terms of O(1) carry ~1e-14): IIPS
# takes no Newton step from there, whatever the procedure or threshold (psph.shifting.iips). Its right-hand
# side is noise, which the solve cannot reduce by rtol (BCGS ended DIVERGED_DTOL or BREAKDOWN, on some rank
# counts and not others); a threshold below it is never reached
ROUNDOFF_LINF = 1e-12
# the largest h/dx at which the particle packing does not pair particles with the cubic spline (a packing
# audit's sweep of a drop at dx = 0.1: closest pair 0.88, 0.77, 0.23, 0.00 dx at h/dx = 1.0, 1.2, 1.3, 1.5)
CUBIC_PACKING_H_OVER_DX = 1.2

OUTFLOW_FACES = ("x-", "x+", "y-", "y+", "z-", "z+")


def _supersonic(key, what, speed, c0) -> SceneError:
    """The refusal of a prescribed speed (a body's, an inflow's) not below the speed of sound."""
    return SceneError(key, f"{what} at {speed:g}, not below the speed of sound physics.sound_speed = {c0:g} (a "
                      "weakly compressible fluid needs it about 10 times the flow's speed)")


def _overlap(lo, hi, other_lo, other_hi, margin=0.0) -> bool:
    """Do boxes [lo, hi] and [other_lo, other_hi] share more than `margin` along every axis?"""
    return bool(np.all(np.minimum(hi, other_hi) - np.maximum(lo, other_lo) > margin))


@dataclass(frozen=True)
class DomainSpec:
    dimension: int = option(doc="number of space dimensions", choices=(1, 2, 3))
    lower: tuple[float, ...] = option(doc="lower corner of the box", length="dimension")
    upper: tuple[float, ...] = option(doc="upper corner of the box", length="dimension")
    periodic: tuple[bool, ...] = option(doc="periodicity of each axis", length="dimension")
    dx: float = option(doc="initial particle spacing (the resolution)", gt=0.0)
    h_over_dx: float = option(2.0, doc="smoothing length over particle spacing", ge=1.0, le=4.0)
    kernel: str = option("wendland_c6", doc="smoothing kernel", choices=KERNEL_NAMES)
    outflow: tuple[str, ...] = option((), doc="open faces of the box (x-, x+, y-, y+, z-, z+ on non-periodic "
                                      "axes) through which fluid leaves: a fluid particle past one is removed "
                                      "(README, \"Open boundaries\")")
    outflow_buffer: bool = option(False, doc="keep the fluid past an outflow face for one kernel support, its "
                                  "density and velocity extrapolated from the fluid every step, so that sound "
                                  "leaves (2.4% of a pulse reflected, against 65% without: README, \"Open "
                                  "boundaries\")")
    outflow_relaxation: float = option(0.0, doc="outflow buffer: its pressure (1 - a) times the fluid's it is "
                                       "extrapolated from, a pull towards p = 0 that fixes the pressure level, "
                                       "which the zero-gradient buffer leaves free (a flow started from rest kept "
                                       "filling up), at the cost of a weak reflection (6.5% of a pulse at a = "
                                       "0.02: README, \"Open boundaries\")", ge=0.0, le=1.0)

    def check(self, path):
        faces = OUTFLOW_FACES[: 2 * self.dimension]
        for k, face in enumerate(self.outflow):
            if face not in faces:
                raise SceneError(f"{path}.outflow[{k}]", f"expected one of {', '.join(faces)}, got {face!r}")
            if self.periodic[faces.index(face) // 2]:
                raise SceneError(f"{path}.outflow[{k}]", f"face {face} lies on a periodic axis: fluid leaving "
                                 "there comes back on the other side")
        if len(set(self.outflow)) != len(self.outflow):
            raise SceneError(f"{path}.outflow", f"faces listed twice: {list(self.outflow)}")
        if self.outflow_buffer and not self.outflow:
            raise SceneError(f"{path}.outflow_buffer", "there is no outflow face (domain.outflow) to buffer")
        if self.outflow_relaxation and not self.outflow_buffer:
            raise SceneError(f"{path}.outflow_relaxation", "relaxes the outflow buffer's pressure: give "
                             "domain.outflow_buffer = true")
        for a in range(self.dimension):
            if not self.upper[a] > self.lower[a]:
                raise SceneError(f"{path}.upper[{a}]", f"must exceed lower[{a}] = {self.lower[a]}, "
                                 f"got {self.upper[a]}")
            length = self.upper[a] - self.lower[a]
            cells = length / self.dx
            if not math.isfinite(cells) or cells > 1e12:
                raise SceneError(f"{path}.dx", f"{self.dx:g} gives {cells:.3g} particle spacings along axis {a}, "
                                 "more than any machine holds")
            if self.periodic[a] and abs(cells - round(cells)) > 1e-8 * max(1.0, cells):
                raise SceneError(f"{path}.dx", f"must divide the periodic length {length:g} of axis {a} "
                                 f"(got {length:g}/{self.dx:g} = {cells:.6g} spacings)")

    @property
    def center(self) -> tuple:
        return tuple(0.5 * (lo + hi) for lo, hi in zip(self.lower, self.upper))

    @property
    def h(self) -> float:
        return self.h_over_dx * self.dx

    @property
    def support(self) -> float:
        return 2.0 * self.h

    def lattice_shape(self) -> tuple:
        """Particles per axis of the initial lattice."""
        return tuple(int(round((self.upper[a] - self.lower[a]) / self.dx)) for a in range(self.dimension))

    def estimated_particles(self) -> int:
        return math.prod(self.lattice_shape())

    def outflow_faces(self) -> tuple:
        """(axis, side) of every outflow face, side -1 for the lower face and +1 for the upper."""
        return tuple((OUTFLOW_FACES.index(f) // 2, 1 if f.endswith("+") else -1) for f in self.outflow)


@dataclass(frozen=True)
class InflowSpec:
    lower: tuple[float, ...] = option(doc="lower corner of the inflow buffer (a box inside the domain)")
    upper: tuple[float, ...] = option(doc="upper corner of the inflow buffer")
    velocity: tuple[float, ...] = option(doc="velocity of the fluid entering (with profile = parabolic, at the "
                                         "centre): along one axis, pointing from the buffer into the domain "
                                         "through the buffer's face on that side")
    density: str = option("extrapolated", doc="the buffer particles' density: extrapolated (the Shepard average "
                          "of the fluid's within a kernel support, the velocity staying prescribed: a velocity inlet "
                          "whose pressure follows the fluid) or prescribed (rho0, the pressure of rho0, which a flow "
                          "that needs a pressure at the inlet overfills; README, \"Open boundaries\")",
                          choices=("extrapolated", "prescribed"))
    profile: str = option("uniform", doc="the velocity across the buffer: uniform (velocity everywhere), or "
                          "parabolic (Poiseuille's: velocity at the centre of the buffer's cross-section, falling "
                          "to 0 at its sides as prod 4 s (1 - s), s across each transverse axis from 0 to 1; mean "
                          "2/3 of it in 2-D; in 3-D the product of two parabolas, which only approximates a "
                          "square duct's); each column of the buffer emits its rows at its own speed",
                          choices=("uniform", "parabolic"))
    ramp_time: float = option(0.0, doc="time over which the velocity rises from rest, smoothly (tau^2 (3 - 2 "
                              "tau), tau = t / ramp_time, a body's ramp law), so that the flow does not start with "
                              "a pressure shock of rho0 c0 U; 0: the full velocity from t = 0", ge=0.0)
    non_reflecting_time: float = option(0.0, doc="0: a velocity inlet, which reflects sound as a wall does; T > 0: "
                                        "sound leaves through it (density = extrapolated, a uniform profile): the "
                                        "buffer's speed follows the fluid's outgoing characteristic p - rho0 c0 u "
                                        "beside it, against a pressure level that relaxes to the fluid's over T, so "
                                        "that changes much faster than T leave and the mean speed stays the "
                                        "prescribed one (README, \"Open boundaries\")", ge=0.0)

    def check(self, path):
        lengths = {"lower": len(self.lower), "upper": len(self.upper), "velocity": len(self.velocity)}
        if len(set(lengths.values())) == 2:  # the key whose length the other two do not share
            common = max(lengths.values(), key=list(lengths.values()).count)
            odd = next(key for key, n in lengths.items() if n != common)
            raise SceneError(f"{path}.{odd}", f"{lengths[odd]} entries where the other two keys have {common}: "
                             "lower, upper and velocity need one entry per dimension")
        if len(set(lengths.values())) == 3:
            raise SceneError(path, f"lower, upper and velocity have {lengths['lower']}, {lengths['upper']} and "
                             f"{lengths['velocity']} entries: they need one per dimension")
        for a in range(len(self.lower)):
            if not self.upper[a] > self.lower[a]:
                raise SceneError(f"{path}.upper[{a}]", f"must exceed lower[{a}] = {self.lower[a]}, "
                                 f"got {self.upper[a]}")
        if self.profile == "parabolic" and len(self.lower) == 1:
            raise SceneError(f"{path}.profile", "a 1-D buffer has no cross-section for a profile to vary across")
        moving = [a for a, v in enumerate(self.velocity) if v != 0.0]
        if len(moving) != 1:
            raise SceneError(f"{path}.velocity", f"give exactly one non-zero component (the buffer's axis), got "
                             f"{list(self.velocity)}")
        if self.non_reflecting_time > 0.0:
            for key, value, needed in (("density", self.density, "extrapolated"), ("profile", self.profile, "uniform")):
                if value != needed:
                    raise SceneError(f"{path}.{key}", f"non_reflecting_time needs {key} = {needed!r}, got {value!r}: "
                                     "the buffer's pressure follows the fluid's, and the whole section moves at one "
                                     "speed")

    @property
    def axis(self) -> int:
        return next(a for a, v in enumerate(self.velocity) if v != 0.0)


MOTION_LAWS = ("fixed", "constant", "ramp", "spheric6", "oscillate")


@dataclass(frozen=True)
class MotionSpec:
    law: str = option("fixed", doc="rigid motion's law (the translation's, and the rotation's unless "
                      "rotation_law is given): fixed; constant (velocity from t = 0); ramp (velocity reached "
                      "smoothly over ramp_time, tau^2 (3 - 2 tau)); spheric6 (the SPHERIC benchmark 6 "
                      "acceleration a(t) = 2.8209512 exp(-(t - 0.525652151)^2 / (2 0.14142151^2)) up to t = 1); "
                      "oscillate (velocity times cos(2 pi t / period): it starts at the centre at full speed, "
                      "as constant does, and swings |velocity| period / (2 pi) either side; drag stays "
                      "measured against the velocity given, so it changes sign with the motion)",
                      choices=MOTION_LAWS)
    velocity: tuple[float, ...] = option((), doc="translation velocity reached (spheric6: its direction and "
                                         "size are scaled to this vector; oscillate: the peak velocity)")
    angular_velocity: float = option(0.0, doc="rotation rate reached [rad per time unit], about the centre")
    rotation_law: str = option("", doc="the rotation's own law (same choices as law; empty: the rotation "
                               "follows law)", choices=("",) + MOTION_LAWS)
    ramp_time: float = option(1.0, doc="ramp: time to reach the velocity", gt=0.0)
    period: float = option(1.0, doc="oscillate: period of the motion", gt=0.0)

    @property
    def turning_law(self) -> str:
        """The rotation's law."""
        return self.rotation_law or self.law


@dataclass(frozen=True)
class BodySpec:
    name: str = option(doc="body name (suffix of its force columns when a scene has several)")
    shape: str = option(doc="box or polygon (fluid inside: tank or cavity walls), rectangle or ellipse (immersed); "
                        "a polygon with fluid = \"outside\" is immersed too",
                        choices=("box", "polygon", "rectangle", "ellipse"))
    center: tuple[float, ...] = option((), doc="centre (not for a polygon)")
    size: tuple[float, ...] = option((), doc="box/rectangle: width and height; ellipse: semi-axes a and b (not for "
                                     "a polygon)", gt=0.0)
    angle: float = option(0.0, doc="rotation of the shape [degrees] (not for a polygon)")
    vertices: tuple[tuple[float, ...], ...] = option((), doc="polygon: its corners [[x, y], ...] in order, either "
                                                    "sense")
    fluid: str = option("", doc="polygon only: where the fluid is, inside (a tank: the default) or outside (an "
                        "immersed body, which may move, turning about its area centroid)",
                        choices=("", "inside", "outside"))
    wall: str = option("no_slip", doc="no_slip or free_slip", choices=("no_slip", "free_slip"))
    model: str = option("clone", doc="clone: solid particles with local mirroring (seed 004); ghost: fixed ghost "
                        "particles, mirror images of the fluid across a straight wall (seed 001 section 6.2; "
                        "an axis-aligned box, the baseline)", choices=("clone", "ghost"))
    lid_velocity: tuple[float, ...] = option((), doc="box: tangential velocity of its top side (a cavity lid)")
    motion: MotionSpec = option(MotionSpec(), doc="prescribed rigid motion")
    reference_length: float = option(0.0, doc="length D of the force coefficients 2 F / (rho0 U^2 D) (0: the "
                                     "width for rectangles and boxes, the major axis for ellipses, the x extent "
                                     "for polygons)", ge=0.0)

    @property
    def container(self) -> bool:
        """Whether the fluid is inside (tank walls) rather than around (an immersed body)."""
        return self.shape == "box" or (self.shape == "polygon" and self.fluid != "outside")

    def check(self, path):
        if not self.name.strip():
            raise SceneError(f"{path}.name", "give the body a name (its force columns carry it)")
        if self.fluid and self.shape != "polygon":
            raise SceneError(f"{path}.fluid", f"a {self.shape} has the fluid "
                             f"{'inside' if self.shape == 'box' else 'outside'}: fluid is a polygon's key")
        if self.shape == "polygon":
            self._check_polygon(path)
        else:
            for key in ("center", "size"):
                if len(getattr(self, key)) != 2:
                    raise SceneError(f"{path}.{key}", f"expected 2 entries, got {len(getattr(self, key))}")
            if self.vertices:
                raise SceneError(f"{path}.vertices", f"corners define a polygon, not a {self.shape}")
        if self.lid_velocity and self.shape != "box":  # (a new user's audit: one message said "give 2 entries")
            raise SceneError(f"{path}.lid_velocity", f"a lid is the top side of a box (the fluid inside), not of "
                             f"a {self.shape}")
        if self.lid_velocity and len(self.lid_velocity) != 2:
            raise SceneError(f"{path}.lid_velocity", f"expected 2 entries, got {len(self.lid_velocity)}")
        if self.lid_velocity and self.lid_velocity[1] != 0.0:
            raise SceneError(f"{path}.lid_velocity", "a lid slides along the box's top side: give [U, 0] (the "
                             "second entry, normal to the lid, must be 0)")
        if self.lid_velocity and self.wall == "free_slip":  # the wall's tangential velocity never enters
            raise SceneError(f"{path}.lid_velocity", "a free-slip wall (wall = \"free_slip\") exerts no shear, so "
                             "its lid would move no fluid: give wall = \"no_slip\"")
        if self.model == "ghost" and (self.shape != "box" or self.angle != 0.0):
            raise SceneError(f"{path}.model", "ghost walls mirror across straight walls: an axis-aligned box "
                             "(shape = box, angle = 0)")
        m = self.motion
        if self.container and (m.law != "fixed" or m.turning_law != "fixed"):
            key = "law" if m.law != "fixed" else "rotation_law"
            raise SceneError(f"{path}.motion.{key}", f"a {self.shape} (the fluid's container) stays fixed"
                             + (" (give the lid a velocity instead)" if self.shape == "box" else
                                " (fluid = \"outside\" makes it an immersed body, which may move)"))
        if m.velocity and len(m.velocity) != 2:
            raise SceneError(f"{path}.motion.velocity", f"give 2 entries, got {len(m.velocity)}")
        turns = m.turning_law == m.law and m.angular_velocity  # the law moves the rotation
        if m.law != "fixed" and not any(m.velocity) and not turns:
            raise SceneError(f"{path}.motion.velocity", f"a body moving by law {m.law!r} needs a non-zero "
                             "velocity (2 entries)" + ("" if m.turning_law != m.law else " or angular_velocity"))
        if m.rotation_law not in ("", "fixed") and not m.angular_velocity:
            raise SceneError(f"{path}.motion.angular_velocity", f"a body turning by rotation_law "
                             f"{m.rotation_law!r} needs a non-zero angular_velocity")
        if m.law == "fixed" and any(m.velocity):
            raise SceneError(f"{path}.motion.velocity", "a fixed body does not move: give motion.law (constant, "
                             "ramp, spheric6, oscillate) or drop the velocity")
        if m.turning_law == "fixed" and m.angular_velocity:
            raise SceneError(f"{path}.motion.angular_velocity", "the rotation's law is fixed: give motion."
                             + ("rotation_law" if m.rotation_law else "law or motion.rotation_law")
                             + " or drop the angular velocity")

    def _check_polygon(self, path):
        for key in ("center", "size"):
            if getattr(self, key):
                raise SceneError(f"{path}.{key}", "a polygon is given by its corners (vertices) alone")
        if self.angle != 0.0:
            raise SceneError(f"{path}.angle", "a polygon is given by its corners (vertices): turn them instead")
        v = self.vertices
        if len(v) < 3:
            raise SceneError(f"{path}.vertices", f"a polygon needs at least 3 corners, got {len(v)}")
        for k, corner in enumerate(v):
            if len(corner) != 2:
                raise SceneError(f"{path}.vertices[{k}]", f"expected 2 entries [x, y], got {len(corner)}")
        m = len(v)
        span = max(max(c[0] for c in v) - min(c[0] for c in v), max(c[1] for c in v) - min(c[1] for c in v))
        for k in range(m):
            if math.dist(v[k], v[(k + 1) % m]) <= 1e-12 * span:
                raise SceneError(f"{path}.vertices[{(k + 1) % m}]", f"repeats corner {k}")
        area2 = sum(v[k][0] * v[(k + 1) % m][1] - v[(k + 1) % m][0] * v[k][1] for k in range(m))
        if abs(area2) <= 1e-12 * span * span:
            raise SceneError(f"{path}.vertices", "the corners enclose no area")
        for k in range(m):  # a side running back along the one before it
            a, b, c = v[k - 1], v[k], v[(k + 1) % m]
            if abs(_cross(a, b, c)) <= 1e-12 * span * span and (b[0] - a[0]) * (c[0] - b[0]) + (b[1] - a[1]) * (
                    c[1] - b[1]) < 0:
                raise SceneError(f"{path}.vertices[{k}]", "the polygon folds back on itself at this corner")
        for k in range(m):  # sides that do not share a corner must not meet
            for j in range(k + 2, m - (k == 0)):
                if _segments_cross(v[k], v[(k + 1) % m], v[j], v[(j + 1) % m]):
                    raise SceneError(f"{path}.vertices", f"side {k} (corners {k}-{(k + 1) % m}) crosses side {j} "
                                     f"(corners {j}-{(j + 1) % m}): the polygon must be simple")


def _cross(p, q, r) -> float:
    """(q - p) x (r - p): positive when p, q, r turn anticlockwise."""
    return (q[0] - p[0]) * (r[1] - p[1]) - (q[1] - p[1]) * (r[0] - p[0])


def _segments_cross(a, b, c, d) -> bool:
    """Whether the closed segments ab and cd share a point."""
    def orient(p, q, r):
        value = _cross(p, q, r)
        return (value > 0) - (value < 0)

    def on(p, q, r):  # r on segment pq, given collinear
        return min(p[0], q[0]) <= r[0] <= max(p[0], q[0]) and min(p[1], q[1]) <= r[1] <= max(p[1], q[1])

    o1, o2, o3, o4 = orient(a, b, c), orient(a, b, d), orient(c, d, a), orient(c, d, b)
    if o1 != o2 and o3 != o4:
        return True
    return any(o == 0 and on(p, q, r) for o, p, q, r in ((o1, a, b, c), (o2, a, b, d), (o3, c, d, a), (o4, c, d, b)))


@dataclass(frozen=True)
class InitialSpec:
    type: str = option("lattice", doc="initial particle arrangement", choices=("lattice",))
    sigma_over_dx: float = option(0.0, doc="std. deviation of the Gaussian position perturbation, in dx",
                                  ge=0.0, le=1.0)
    seed: int = option(0, doc="seed of the perturbation (results do not depend on the rank count)",
                       ge=0, lt=2**63)
    velocity: str = option("zero", doc="initial velocity and pressure: zero (no fields), the analytic "
                           "taylor_green vortex (2-D bi-periodic square), or elliptical_drop: u = A0 x, v = -A0 y "
                           "and p = rho0 A0^2 / 2 (R^2 - r^2) about the drop's centre, A0 = reference_velocity / "
                           "drop_radius (seed 002 eq. 3.19-3.20), or inflow: the fill region moves with the first "
                           "inflow's velocity, in its profile (a jet already on its way), or uniform: the fluid "
                           "moves at initial.uniform_velocity",
                           choices=("zero", "taylor_green", "elliptical_drop", "inflow", "uniform"))
    uniform_velocity: tuple[float, ...] = option((), doc="initial.velocity = uniform: the fluid's velocity at t = 0, "
                                                 "one entry per axis (the pressure stays initial.pressure's)")
    drop_radius: float = option(0.0, doc="2-D: the fluid fills the disc of this radius R at the domain's centre, "
                                "a drop whose rim is a free surface (0: no drop)", ge=0.0)
    fill_lower: tuple[float, ...] = option((), doc="lower corner of the region the fluid fills (default: "
                                           "the domain)")
    fill_upper: tuple[float, ...] = option((), doc="upper corner of the fluid region (a tank's free surface)")
    pressure: str = option("zero", doc="initial pressure without an analytic velocity field: zero, or "
                           "hydrostatic (rho0 |g| (y_s - y), the depth below the free surface y_s = fill_upper's y "
                           "or the domain's top, with gravity along -y)",
                           choices=("zero", "hydrostatic"))


@dataclass(frozen=True)
class PackingSpec:
    iterations: int = option(0, doc="fluid runs: at most this many iterations of Colagrossi et al.'s particle "
                             "packing before the flow starts (seed 002 eq. 2.16; 0: none): the particles settle "
                             "where grad Gamma = grad sum_j W_ij V0 vanishes, held by the walls' solid particles "
                             "and by fixed frame particles outside every free surface (removed afterwards)", ge=0)
    alpha: float = option(0.01, doc="damping zeta = alpha sqrt(beta) / V0^(1/d) (seed 002 eq. 2.15 suggests "
                          "1e-3 to 5e-3; 0.01 levels the drop's grad Gamma 46 times further in 1000 "
                          "iterations than 0.002: docs/results.md, \"Particle packing and the "
                          "elliptical drop\")", gt=0.0, le=1.0)
    cfl: float = option(1.0, doc="time step cfl V0^(1/d) / sqrt(beta) (seed 002 eq. 2.17: 1), at most "
                        "cfl h / (2 sqrt(beta))", gt=0.0, le=2.0)
    tolerance: float = option(1e-8, doc="stop once the specific kinetic energy sum_i |u_i|^2 / 2 falls below this "
                              "x beta (seed 002 fig. 6: particles are practically motionless below 1e-8 beta)",
                              gt=0.0)
    start: str = option("", doc="fluid runs: a psph snapshot (OUT/snapshot_NNNNNN.h5, its path relative to the "
                        "working directory) whose fluid positions, by gid, replace the lattice's before any "
                        "packing.iterations: snapshot_000000.h5 of a packed run of this scene starts another "
                        "packed, without packing again. It must hold this scene's fluid particles, within dx/2 of its "
                        "fluid region, and its walls (same dx, fill and bodies); the fields are set afresh")


@dataclass(frozen=True)
class FreeSurfaceSpec:
    lambda_surface: float = option(0.2, doc="a fluid particle whose lambda (smallest eigenvalue of sum_j (x_j - "
                                   "x_i) (x) grad W_ij V_j, thesis eq. 6.28) is at most this is on the free "
                                   "surface (Marrone et al. 2010)", gt=0.0, lt=1.0)
    lambda_interior: float = option(0.75, doc="above this lambda a particle is interior; between the two, "
                                    "Marrone et al.'s scan region decides", gt=0.0, lt=1.0)
    lambda_normal: float = option(0.4, doc="explicit shifting near the free surface (thesis eq. 6.29): du = 0 "
                                  "below this lambda, du . n = 0 above", ge=0.0, lt=1.0)
    scan_radius: float = option(1.0, doc="radius of Marrone et al.'s scan region, in units of h (half the kernel "
                                "support; the region reaches 2 scan_radius h from the particle). Marrone et al. "
                                "scale it with their own kernel's h, which other codes take as 1.33 dx: 0.67 at h/dx "
                                "= 2. Smaller finds narrower air gaps and cavities (a 3 dx gap's faces: none at 1, "
                                "all at 0.67) and flags more of a disordered interior (README, \"Free surfaces\")",
                                gt=0.0, le=1.0)
    lambda_diffusion: float = option(0.0, doc="delta_ale family with a free surface: the diffusive terms D^rho "
                                     "and D^m act on a pair of fluid particles only where both have lambda above "
                                     "this (seed 001 section 6.3: 0.2, no diffusion in thin jets and drops, where "
                                     "the renormalisation is ill-conditioned; the pair rule keeps D^m's mass "
                                     "conservation); 0: everywhere", ge=0.0, lt=1.0)

    def check(self, path):
        if not self.lambda_surface < self.lambda_interior:
            raise SceneError(f"{path}.lambda_interior", f"must exceed lambda_surface = {self.lambda_surface:g}, "
                             f"got {self.lambda_interior:g}")


FLUID_SCHEMES = ("delta_ale", "delta_ale_const_mass", "delta_ale_const_volume", "riemann_ale")


# the physics keys only the fluid schemes read (static and kinematic runs take rho0, gravity and U for their
# initial fields, and kinematic runs U, c0 and the frozen field)
FLUID_PHYSICS = ("reference_length", "reynolds", "artificial_viscosity", "eos", "viscosity", "delta", "delta_m",
                 "free_stream", "free_stream_ramp", "muscl_limiter", "riemann_dissipation", "tensile_switch",
                 "wall_adhesion", "max_density_variation", "max_volume_variation")


@dataclass(frozen=True)
class PhysicsSpec:
    scheme: str = option("none", doc="what moves the particles: none (a static distribution), kinematic "
                         "(advected by a frozen analytic velocity field, thesis 8.3.2), or a fluid scheme: "
                         "delta_ale, delta_ale_const_mass, delta_ale_const_volume (seed 001 eq. 13, 23, 25), "
                         "riemann_ale (thesis eq. 5.48: Riemann fluxes, no diffusive terms)",
                         choices=("none", "kinematic") + FLUID_SCHEMES)
    velocity_field: str = option("taylor_green", doc="kinematic: the frozen field (thesis eq. 8.33; 2-D, a "
                                 "bi-periodic square)",
                                 choices=("taylor_green",))
    reference_velocity: float = option(1.0, doc="reference velocity U (the analytic fields' amplitude; U_max "
                                       "of the shifting laws)", gt=0.0)
    reference_length: float = option(1.0, doc="reference length L (Re = U L / nu)", gt=0.0)
    reynolds: float = option(100.0, doc="Reynolds number U L / nu", gt=0.0)
    artificial_viscosity: float = option(0.0, doc="alpha of Monaghan's artificial viscosity, in place of "
                                         "reynolds where > 0: nu = alpha h c0 / (2 (d + 2)), which makes the "
                                         "pi_ij operator of seed 001 eq. 11 the artificial-viscosity term alpha h "
                                         "c0 rho0 sum_j pi_ij grad_i W_ij V_j / K (seed 001 section 6.3 runs its "
                                         "dam break with it); 0: nu = U L / reynolds", ge=0.0, le=1.0)
    sound_speed: float = option(10.0, doc="speed of sound c0 (kinematic: dt = cfl dx / c0)", gt=0.0)
    density: float = option(1.0, doc="reference density rho0", gt=0.0)
    eos: str = option("linear", doc="equation of state: linear p = c0^2 (rho - rho0), or tait (thesis eq. 5.4, "
                      "gamma = 7)", choices=("linear", "tait"))
    viscosity: str = option("monaghan", doc="viscous operator: monaghan, seed 001 eq. 11 (pi_ij, K = 2(d+2), "
                            "the papers' choice), or morris, 2 sum_j (u_j - u_i) F_ij V_j (Morris et al. 1997): "
                            "free of the square lattice's anisotropy error (eq. 11 at h/dx = 2: an effective "
                            "viscosity 6% low for a shear across a lattice axis, Couette and Poiseuille flows 5-10% "
                            "fast; 8-9% high for the Taylor-Green's diagonal waves)",
                            choices=("monaghan", "morris"))
    gravity: tuple[float, ...] = option((), doc="gravity vector (empty: none)")
    delta: float = option(0.1, doc="coefficient of the density diffusion D^rho (seed 001 eq. 14; "
                          "not in riemann_ale, whose Riemann fluxes diffuse)", ge=0.0, le=1.0)
    delta_m: float = option(0.1, doc="coefficient of the mass diffusion D^m (delta_ale; 0 switches it off)",
                            ge=0.0, le=1.0)
    free_stream: tuple[float, ...] = option((), doc="drive the fluid's mean velocity to this vector with a "
                                            "uniform body force, past fixed bodies in a periodic box (a wind "
                                            "tunnel: the force also balances the bodies' drag); empty: none")
    free_stream_ramp: float = option(1.0, doc="free_stream: time over which the mean velocity rises from rest, "
                                     "U (t/T - sin(2 pi t/T)/(2 pi)), with no jump in acceleration at either end",
                                     gt=0.0)
    muscl_limiter: str = option("minmod", doc="riemann_ale: the MUSCL reconstruction's limiter, minmod (thesis "
                                "eq. 5.49) or none (the gradients' own slopes: less dissipation in smooth flows)",
                                choices=("minmod", "none"))
    riemann_dissipation: str = option("full", doc="riemann_ale: the pressure of the Riemann solver, full "
                                      "(linearised acoustic) or low (Zhang, Hu and Adams 2017: dissipation only "
                                      "where particles approach, scaled by their approach speed)",
                                      choices=("full", "low"))
    tensile_switch: bool = option(True, doc="use p_j - p_i where p_i < 0 (tensile-instability control; "
                                  "delta_ale family only)")
    wall_adhesion: bool = option(False, doc="clone walls with a free surface: true keeps seed 004's solid "
                                 "pressures (eq. 8-9) everywhere, whose extension is negative behind a particle "
                                 "under a roof and holds drops and films on walls and roofs; false, in the "
                                 "free-surface region (where air can come between the fluid and the wall), takes a "
                                 "solid neighbour's pressure as max(p_j, 0) wherever eq. 8-9 carried to the wall "
                                 "gives a negative wall pressure: a wall pushes, never pulls")
    max_density_variation: float = option(0.1, doc="stop when |rho / rho0 - 1| exceeds this (weak "
                                          "compressibility violated)", gt=0.0)
    max_volume_variation: float = option(0.5, doc="delta_ale and riemann_ale: stop when a particle volume drifts "
                                         "by more than this fraction of its initial value (seed 001 fig. 6: "
                                         "without D^m volumes drift by 50%)", gt=0.0)

    def kinematic_viscosity(self, domain) -> float:
        """nu: U L / reynolds, or alpha h c0 / (2 (d + 2)) with an artificial viscosity alpha."""
        if self.artificial_viscosity > 0.0:
            return self.artificial_viscosity * domain.h * self.sound_speed / (2.0 * (domain.dimension + 2))
        return self.reference_velocity * self.reference_length / self.reynolds

    def check(self, path):
        if self.gravity and len(self.gravity) not in (1, 2, 3):
            raise SceneError(f"{path}.gravity", "expected 1 to 3 entries")
        if (exponent := math.log10(self.density) + 2.0 * math.log10(self.sound_speed)) > 300.0:  # rho0 c0^2
            raise SceneError(f"{path}.sound_speed", f"{self.sound_speed:g}: rho0 c0^2 = 10^{exponent:.4g} is "
                             "beyond floating point (at most 1e300)")


SHIFTING_METHODS = ("none", "iips", "explicit_iterative", "lind", "skillen", "oger", "delta_plus", "neuhauser")
EXPLICIT_LAWS = ("lind", "skillen", "oger", "delta_plus", "neuhauser")


def _methods_named(doc: str) -> set:
    """The shifting methods a key's text begins with ("lind and oger: ..."), or none."""
    named = set(doc.split(":")[0].replace(" and ", ", ").split(", "))
    return named if named <= set(SHIFTING_METHODS) else set()


@dataclass(frozen=True)
class ShiftingSpec:
    method: str = option("none", doc="particle shifting: none, iips, explicit_iterative (static and kinematic "
                         "runs), or an explicit law inside a fluid scheme or a kinematic run: lind, skillen, oger, "
                         "delta_plus, neuhauser", choices=SHIFTING_METHODS)
    diffusion: float = option(0.4, doc="explicit_iterative: D / h^2 in dx = -D grad C (thesis eq. 6.13). Lind et "
                              "al.'s 0.5 diverges with Wendland C6 at h/dx = 2 (stable up to 0.47; 0.40 at h/dx = "
                              "1.6, 0.27 at 1.3: a run above its kernel's limit is warned about)", gt=0.0, le=10.0)
    lind_diffusion: float = option(0.2, doc="lind: D / h^2 in dx = -D grad C^ per step (thesis eq. 6.15-6.16, which "
                                   "prints 0.5). The corrected gradient lowers the lattice's limit: 0.24 / 0.33 / "
                                   "0.38 in 1-/2-/3-D with Wendland C6 at h/dx = 2, 0.12-0.15 at 1.3 (a run above "
                                   "its kernel's limit is warned about)", gt=0.0, le=10.0)
    max_iterations: int = option(1000, doc="explicit_iterative: iterations of a static run", ge=1)
    iterations_per_step: int = option(1, doc="explicit_iterative: iterations per time step", ge=1)
    # bounded so that the factor stays finite: W_ij / W(dx) reaches 17 (C6, h/dx = 1), and n = 3000 overflowed
    # it to NaN positions (a delta-ALE audit); Monaghan's tensile correction takes R = 0.2-0.3, n = 4
    delta_plus_r: float = option(0.2, doc="delta_plus: R in [1 + R (W_ij / W(dx))^n] (seed 001 eq. 17)", ge=0.0,
                                 le=10.0)
    delta_plus_n: float = option(4.0, doc="delta_plus: n (seed 001 eq. 17)", gt=0.0, le=16.0)
    skillen_a: float = option(2.0, doc="skillen: the constant A of thesis eq. 6.18", gt=0.0)
    neuhauser_ps: float = option(10.0, doc="neuhauser: particle-shifting coefficient P_S (thesis eq. 7.1; "
                                 "1 = the original formulation)", gt=0.0)
    fictitious_pressure: bool = option(False, doc="neuhauser: use the fictitious pressure P^F (thesis eq. 7.4) "
                                       "instead of P_S")


@dataclass(frozen=True)
class IIPSSpec:
    procedure: str = option("B", doc="A: at least one Newton iteration per call; B: only above the threshold "
                            "(thesis Algorithms 2-3)", choices=("A", "B"))
    threshold: float = option(0.0, doc="absolute threshold on Linf(grad C) = h max|grad C| (0: none)", ge=0.0)
    beta: float = option(0.0, doc="threshold = beta x Linf(grad C) after the pre-procedure (thesis eq. 8.34; "
                         "0: unused)", ge=0.0)
    beta_from: str = option("last", doc="the Linf(grad C)_Init that iips.beta scales: the pre-procedure's last "
                            "iterate (the distribution the run starts from), or the lowest it passed through "
                            "(the thesis' 'initial minimal value')", choices=("last", "lowest"))
    max_newton: int = option(20, doc="Newton iterations per call at most (a static run: exactly, without "
                             "threshold, unless Linf(grad C) reaches round-off, 1e-12)", ge=1, le=100000)
    pre_newton: int = option(0, doc="Newton iterations of the static pre-procedure before a time-dependent "
                             "run, whatever the shifting method (thesis: 100); from a perturbed lattice "
                             "(initial.sigma_over_dx) it gives a relaxed start", ge=0)
    divergence_factor: float = option(100.0, doc="a call whose Linf(grad C) grows by this factor, counted from "
                                      "1e-4 at least (a relaxed distribution's level: growth from round-off to "
                                      "below this factor x 1e-4 is no divergence), has diverged",
                                      gt=1.0)
    backtrack: int = option(0, doc="a Newton step that raises L2(grad C) is halved, up to this many times, "
                            "and undone if that does not help, which ends the call (a stall if above the "
                            "threshold); 0: never, the thesis takes every full step", ge=0, le=30)
    operator: str = option("auto", doc="assembled: a PETSc AIJ matrix (BAIJ with -iips_mat_type baij), "
                           "any preconditioner; matrix_free: the product computed pair by pair, no pattern "
                           "to build (faster per Newton iteration), preconditioner jacobi or none; auto: "
                           "matrix_free where the preconditioner allows and no -iips_mat_type is given, else "
                           "assembled",
                           choices=("auto", "assembled", "matrix_free"))
    update: str = option("none", doc="fluid runs: field update after IIPS moved the particles: none, nfts "
                         "(fictitious time step, thesis eq. 9.7), mls1, mls2 (MLS re-interpolation, eq. 9.8-9.9), "
                         "mls1_increment, mls2_increment (only the MLS fit's change between the old and the new "
                         "position is added, the Taylor correction of eq. 6.10: no smoothing per call)",
                         choices=("none", "nfts", "mls1", "mls2", "mls1_increment", "mls2_increment"))
    mls_fit: str = option("fluid", doc="mls1, mls2: the particles re-fitted after an IIPS call: fluid (every "
                          "fluid particle, as thesis section 9.1.2 does, which smooths the free-surface region "
                          "IIPS holds at every call) or moved (only the particles IIPS moved; README, \"IIPS: "
                          "method and options\")", choices=("fluid", "moved"))
    on_failure: str = option("stop", doc="KSP divergence or Newton divergence: stop the run; reject the "
                             "call (undo its displacements, report, continue); or warn (keep them, report, "
                             "continue; a diverged KSP solve still stops the run: its step is no correction)",
                             choices=("stop", "reject", "warn"))
    on_stall: str = option("best", doc="threshold not reached after max_newton iterations: keep the call's "
                           "iterate of lowest Linf(grad C) and report it (best; the thesis caps the iterations "
                           "for cost, section 10.1.1), or stop, reject, warn as on_failure",
                           choices=("best", "stop", "reject", "warn"))
    stall_max_shift: float = option(0.0, doc="on_stall = best: keep the iterate of lowest Linf(grad C) among "
                                    "those that move no particle farther than this many h from the call's start "
                                    "(the start itself always qualifies); 0: any iterate", ge=0.0)

    def check(self, path):
        if self.threshold > 0 and self.beta > 0:
            raise SceneError(f"{path}.beta", "give either iips.threshold or iips.beta, not both")
        if 0.0 < self.threshold < ROUNDOFF_LINF:
            raise SceneError(f"{path}.threshold", f"{self.threshold:g} is below round-off ({ROUNDOFF_LINF:g}, "
                             "where IIPS takes no step): no call would reach it")


@dataclass(frozen=True)
class TimeSpec:
    t_end: float = option(0.0, doc="end time of the simulation", ge=0.0)
    cfl: float = option(0.2, doc="CFL number: kinematic dt = cfl dx / c0 (thesis 8.3.2); fluid "
                        "dt = cfl min h / (c0 + |u + du|) (thesis eq. 5.52), also kept under the viscous "
                        "operator's stability limit (psph.schemes.viscous_limit)",
                        gt=0.0, le=2.0)
    integrator: str = option("rk3", doc="fluid time integrator: rk3 (Kutta, thesis eq. 5.51) or rk4",
                             choices=("rk3", "rk4"))
    retries: int = option(0, doc="fluid runs: on a numerical failure in a step, restore the state before it and "
                          "retry with half the time step, down to 2^-retries of it (0: stop; costs a copy of the "
                          "particles every step); the step then doubles back after every 10 steps without a "
                          "failure", ge=0, le=20)


@dataclass(frozen=True)
class OutputSpec:
    every: float = option(0.0, doc="simulated time between snapshots (0: initial and final only)", ge=0.0)
    history_every: int = option(1, doc="time steps between history.csv rows", ge=1)
    checkpoint_every: int = option(0, doc="flow and kinematic runs: steps between checkpoints "
                                   "OUT/checkpoint_NNNNNN.h5 (0: none); `psph run --restart FILE` continues a run",
                                   ge=0)
    checkpoint_minutes: float = option(0.0, doc="flow and kinematic runs: wall-clock minutes between checkpoints "
                                       "(0: none)", ge=0.0)
    probes: tuple[tuple[float, ...], ...] = option((), doc="flow runs: points [[x, y], ...] where the fluid's "
                                                   "pressure and velocity go to OUT/probes.csv at every history "
                                                   "row (Shepard interpolation; nan where no fluid reaches)")


@dataclass(frozen=True)
class DiagnosticsSpec:
    test_wavelength: float = option(
        0.5, doc="wavelength l of the test function f = sin(2 pi x/l) + cos(2 pi y/l), in domain length "
        "units; l/dx particles per wavelength. The thesis prints sin(pi x/lambda) + cos(pi y/lambda) (eq. 3.6), "
        "whose period is 2 lambda, but counts lambda/dx particles per wavelength (40 for lambda = L at dx/L = "
        "0.0125): psph follows the counts, l = lambda/2", gt=0.0)
    impinging_jet: bool = option(False, doc="fluid runs, 2-D: compare the wall pressure with Taylor's solution for a "
                                 "jet impinging normally on a plate (thesis eq. 3.3): the jet is inflow[0] (along "
                                 "-y, half-width H its half cross-section), the plate the top of bodies[0]")
    dam_break: bool = option(False, doc="fluid runs, 2-D: history columns front_x (the surge front, from the back "
                             "wall) and column_height (the fluid's height at the back wall) of a dam break: the "
                             "fluid column initial.fill_lower .. fill_upper collapses along +x under gravity along "
                             "-y (seed 001 section 6.3)")
    stop_at_cartesian: float = option(
        0.0, doc="static runs: stop shifting once L2(d f/dx) <= this x its Cartesian-lattice value (0: never)",
        ge=0.0)


SKIN_MAX = 1.0  # neighbours.skin's largest value (a failed step's advice names it)


@dataclass(frozen=True)
class NeighboursSpec:
    skin: float = option(0.1, doc="Verlet skin of the neighbour lists, as a fraction of the kernel support",
                         ge=0.0, le=SKIN_MAX)
    rebalance_threshold: float = option(
        1.1, doc="rebalance the ranks when max/mean owned particles exceeds this at a rebuild", ge=1.0)


@dataclass(frozen=True)
class Scene:
    name: str = option(doc="name of the scene")
    domain: DomainSpec = option(doc="the box and its discretisation")
    initial: InitialSpec = option(InitialSpec(), doc="initial condition")
    physics: PhysicsSpec = option(PhysicsSpec(), doc="physical model")
    shifting: ShiftingSpec = option(ShiftingSpec(), doc="particle shifting")
    iips: IIPSSpec = option(IIPSSpec(), doc="implicit iterative particle shifting")
    time: TimeSpec = option(TimeSpec(), doc="time integration")
    output: OutputSpec = option(OutputSpec(), doc="what is written and when")
    diagnostics: DiagnosticsSpec = option(DiagnosticsSpec(), doc="diagnostics")
    neighbours: NeighboursSpec = option(NeighboursSpec(), doc="neighbour lists and load balance")
    packing: PackingSpec = option(PackingSpec(), doc="particle packing before a flow (seed 002)")
    free_surface: FreeSurfaceSpec = option(FreeSurfaceSpec(), doc="free-surface detection and the shifting "
                                           "near a free surface")
    bodies: tuple[BodySpec, ...] = option((), doc="solid walls and bodies ([[bodies]] tables; clone particles or "
                                          "ghost walls), 2-D only (seed 004's clone particles are 2-D)")
    inflow: tuple[InflowSpec, ...] = option((), doc="inflow buffers ([[inflow]] tables): particles move at the "
                                            "prescribed velocity and join the fluid as they leave the buffer "
                                            "(README, \"Open boundaries\")")

    def _check_ghost_walls(self, fluid):
        ghosts = [k for k, b in enumerate(self.bodies) if b.model == "ghost"]
        if not ghosts:
            return
        key = f"bodies[{ghosts[0]}].model"
        if len(ghosts) > 1:
            raise SceneError(f"bodies[{ghosts[1]}].model", "at most one box of ghost walls")
        if not fluid:
            raise SceneError(key, "ghost walls mirror a fluid's fields: they need a fluid scheme")
        if self.shifting.method in ("iips", "neuhauser"):
            raise SceneError(key, f"ghost walls work with the delta_plus, lind, skillen and oger laws or none; "
                             f"shifting.method = {self.shifting.method} needs clone walls")
        box, d = self.bodies[ghosts[0]], self.domain
        for a in range(2):
            lo, hi = box.center[a] - box.size[a] / 2.0, box.center[a] + box.size[a] / 2.0
            if d.periodic[a] and (lo > d.lower[a] or hi < d.upper[a]):
                raise SceneError(key, f"along periodic axis {a} the box must span the domain (its sides there "
                                 "are not mirrored)")
            if not d.periodic[a] and hi - lo <= 2.0 * d.support:
                raise SceneError(key, f"the box is too narrow along axis {a} for ghost images (needs more than "
                                 f"two kernel supports, {2.0 * d.support:g})")
            if not d.periodic[a] and (lo < d.lower[a] - 1e-9 * d.dx or hi > d.upper[a] + 1e-9 * d.dx):
                raise SceneError(key, f"along axis {a} the box leaves the domain: the fluid at the domain's "
                                 "edge would have no wall")

    def _check_drop(self, fluid):
        ini, d = self.initial, self.domain
        if ini.velocity == "elliptical_drop" and ini.drop_radius == 0:
            raise SceneError("initial.velocity", "elliptical_drop needs initial.drop_radius > 0")
        if ini.drop_radius > 0:
            if d.dimension != 2:
                raise SceneError("initial.drop_radius", "a drop is a 2-D disc: domain.dimension must be 2")
            if ini.fill_lower or ini.fill_upper or self.bodies:
                raise SceneError("initial.drop_radius", "a drop fills its disc: give no initial.fill_lower, "
                                 "fill_upper or bodies with it")
            if ini.drop_radius < 2.0 * d.dx:
                raise SceneError("initial.drop_radius", f"{ini.drop_radius:g} is less than 2 dx = {2 * d.dx:g}")
            room = min(d.upper[a] - d.lower[a] for a in range(2)) / 2.0 - ini.drop_radius
            if room < d.support + d.dx:
                raise SceneError("initial.drop_radius", f"the drop must clear the domain's sides by a kernel "
                                 f"support plus dx ({d.support + d.dx:g}); it clears them by {room:g}")
            if ini.velocity == "elliptical_drop" and fluid:
                from psph.initial import elliptical_drop

                t_end, half = self.time.t_end, (d.upper[0] - d.lower[0]) / 2.0 - d.dx
                # the tip speed A a never falls below A0 R (d(A a)/dt = 2 A^2 a b^2 / (a^2 + b^2)), so a(t_end)
                # is at least R + U t_end: no need to solve the ODE when that is already too far
                bound = ini.drop_radius + self.physics.reference_velocity * t_end
                solved = bound <= half
                a = float(elliptical_drop(self, t_end).state(t_end)[0]) if solved else bound
                if not a <= half:
                    raise SceneError("domain.upper", "the drop stretches to a semi-axis of "
                                     f"{'' if solved else 'at least '}{a:.4g} along x by t_end = {t_end:g}: the "
                                     "domain's half-width along x, "
                                     f"{half + d.dx:g}, must exceed it by dx")
            if ini.pressure == "hydrostatic":
                raise SceneError("initial.pressure", "a drop has no hydrostatic pressure (its free surface is all "
                                 "round): use zero or initial.velocity = elliptical_drop")
        if ini.velocity == "elliptical_drop" and any(self.physics.gravity):
            raise SceneError("physics.gravity", "the elliptical drop's analytic solution has no gravity: leave "
                             "physics.gravity out")

    def _check_packing(self, fluid):
        d = self.domain
        if self.packing.start and not fluid:
            raise SceneError("packing.start", "a packed start initialises a flow: it needs a fluid scheme, not "
                             f"physics.scheme = {self.physics.scheme!r}")
        if self.packing.iterations > 0:
            if not fluid:
                raise SceneError("packing.iterations", "packing initialises a flow: it needs a fluid scheme, not "
                                 f"physics.scheme = {self.physics.scheme!r}")
            for axis in self.free_surface_axes():  # (every one: a packing audit found the second unchecked)
                if d.periodic[axis]:
                    raise SceneError("packing.iterations", f"the fill region's free surface lies along periodic "
                                     f"axis {axis}: its far side faces the empty band across the periodic edge, "
                                     "which the packing's frame does not close")
            bare = self._bare_faces()
            if bare:
                raise SceneError("packing.iterations", f"the fill region reaches the bounded face(s) "
                                 f"{', '.join(bare)} with no wall there, and the packing pushes the particles along "
                                 "it out of the domain (a packing audit: 'diverged, lower packing.cfl' at any cfl): "
                                 "put a container body around the fluid, or make the axis periodic")
            if d.kernel == "cubic_spline" and d.h_over_dx > CUBIC_PACKING_H_OVER_DX:
                raise SceneError("domain.kernel", f"the packing pairs particles with the cubic spline at h/dx = "
                                 f"{d.h_over_dx:g} (its pairing instability, from h/dx = 1.3; measured): use a "
                                 f"Wendland kernel, or h/dx <= {CUBIC_PACKING_H_OVER_DX:g}")
            ghosts = [k for k, b in enumerate(self.bodies) if b.model == "ghost"]
            if ghosts:
                raise SceneError(f"bodies[{ghosts[0]}].model", "packing holds the fluid with the walls' solid "
                                 "particles: ghost walls have none (use clone walls)")

    def _check_open(self, fluid):
        d = self.domain
        if self.initial.velocity == "uniform" and len(self.initial.uniform_velocity) != d.dimension:
            raise SceneError("initial.uniform_velocity", f"initial.velocity = \"uniform\" needs {d.dimension} "
                             f"entries (domain.dimension), got {list(self.initial.uniform_velocity)}")
        if self.initial.velocity == "uniform" and fluid:  # (1e160 ran to a time step of 0 at step 1)
            speed = math.hypot(*self.initial.uniform_velocity)
            if not speed < self.physics.sound_speed:
                raise _supersonic("initial.uniform_velocity", "the fluid would start", speed,
                                  self.physics.sound_speed)
        if self.initial.velocity == "inflow" and not self.inflow:
            raise SceneError("initial.velocity", "inflow sets the fluid moving with the first [[inflow]]: the "
                             "scene has none")
        if self.initial.velocity == "inflow" and self.inflow[0].ramp_time > 0.0:
            raise SceneError("inflow[0].ramp_time", "initial.velocity = \"inflow\" starts the fluid at the inflow's "
                             "full velocity, its ramp from rest: give one or the other")
        if d.outflow and not fluid:
            raise SceneError("domain.outflow", f"outflow faces belong to a flow, not physics.scheme = "
                             f"{self.physics.scheme!r}")
        if d.outflow_buffer and self.physics.scheme == "riemann_ale":
            raise SceneError("domain.outflow_buffer", "outflow buffers need a delta_ale scheme, not "
                             "physics.scheme = 'riemann_ale'")
        if (self.inflow or d.outflow) and self.packing.iterations > 0:
            raise SceneError("packing.iterations", "the packing's frame closes no open boundary: pack without "
                             "[[inflow]] and domain.outflow (or start from the lattice)")
        from psph.boundaries.bodies import bounds

        for k, face in enumerate(d.outflow):
            a, side = d.outflow_faces()[k]
            for j, b in enumerate(self.bodies):
                if b.container and (bounds(b)[side > 0][a] - (d.upper[a] if side > 0 else d.lower[a])) * side > -d.dx:
                    raise SceneError(f"domain.outflow[{k}]", f"bodies[{j}] (a {b.shape}) has a wall along face "
                                     f"{face}: no fluid would reach it")
                if d.outflow_buffer and not b.container:
                    self._check_wall_through_buffer(j, b, face, a, side)
        if not self.inflow:
            return
        if not fluid or self.physics.scheme == "riemann_ale":
            raise SceneError("inflow", f"inflow buffers need a delta_ale scheme, not physics.scheme = "
                             f"{self.physics.scheme!r}")
        boxes = []
        for k, f in enumerate(self.inflow):
            boxes.append(self._check_buffer(k, f))
            speed = math.hypot(*f.velocity)
            if speed >= self.physics.sound_speed:  # (1e200 made the time step 0, and the run stood at t = 0)
                raise _supersonic(f"inflow[{k}].velocity", "the fluid would enter", speed, self.physics.sound_speed)
        for k, (lo, hi) in enumerate(boxes):
            for j in range(k):
                if _overlap(lo, hi, *boxes[j], 1e-9 * d.dx):
                    raise SceneError(f"inflow[{k}]", f"the buffer overlaps inflow[{j}]'s")
        if not self.describe_free_surface():
            raise SceneError("inflow", "the fluid fills a closed domain: what the buffers bring in has nowhere to "
                             "go (give domain.outflow, or a fill region with a free surface)")

    def _check_wall_through_buffer(self, j, b, face, a, side):
        """A body beside the fluid that reaches outflow face `face` (axis a, side) must go on a kernel support
        past it, as the outflow buffer does: a wall that ended at the face left the buffer beside it with no
        wall, and a channel drained through it (a new user's audit: plates ending at the outlet, mass -6% by
        t = 1.06, then the density failed at the corner; with the plates continued 0.4 past it the run went
        on)."""
        from psph.boundaries.bodies import bounds

        d = self.domain
        lo, hi = bounds(b)
        face_at = d.upper[a] if side > 0 else d.lower[a]
        reach = ((hi if side > 0 else lo)[a] - face_at) * side  # how far the body goes past the face
        fill_lo = np.asarray(self.initial.fill_lower or d.lower, dtype=float)[:2]
        fill_hi = np.asarray(self.initial.fill_upper or d.upper, dtype=float)[:2]
        beside = _overlap(np.delete(lo - d.support, a), np.delete(hi + d.support, a), np.delete(fill_lo, a),
                          np.delete(fill_hi, a))
        if beside and -0.5 * d.dx < reach < d.support - 1e-6 * d.dx:
            end = face_at + side * d.support
            raise SceneError(f"bodies[{j}].size", f"bodies[{j}] ({b.name!r}) reaches the outflow face {face} and "
                             f"ends {max(reach, 0.0):.3g} past it (domain.outflow_buffer = true): its wall must go "
                             f"on a kernel support past the face, to {'xyz'[a]} = {end:g} or beyond, as the buffer "
                             "does; beside a wall that ended at the face the buffer had none, and the fluid drained "
                             "through it")

    def _check_buffer(self, k, f):
        """One inflow buffer: inside the domain, on the fluid's lattice, at least a kernel support deep, its
        downstream face inside the domain, no fluid upstream of it, no body in it. Returns its corners."""
        d, path, tol = self.domain, f"inflow[{k}]", 1e-6
        for key in ("lower", "upper"):
            if len(getattr(f, key)) != d.dimension:
                raise SceneError(f"{path}.{key}", f"expected {d.dimension} entries (domain.dimension)")
        lo, hi = np.asarray(f.lower, dtype=float), np.asarray(f.upper, dtype=float)
        for a in range(d.dimension):
            if lo[a] < d.lower[a] - tol * d.dx:
                raise SceneError(f"{path}.lower", f"the buffer leaves the domain along axis {a}")
            if hi[a] > d.upper[a] + tol * d.dx:
                raise SceneError(f"{path}.upper", f"the buffer leaves the domain along axis {a}")
            for key, value in (("lower", lo[a]), ("upper", hi[a])):
                cells = (value - d.lower[a]) / d.dx
                if abs(cells - round(cells)) > tol:
                    raise SceneError(f"{path}.{key}", f"{key}[{a}] = {value:g} is off the fluid's lattice: give "
                                     f"domain.lower[{a}] + k dx (dx = {d.dx:g}), so buffer and fluid rows line up")
        a = f.axis
        if d.periodic[a]:
            raise SceneError(f"{path}.velocity", f"the buffer's axis {a} is periodic: its particles would come "
                             "round again")
        depth = hi[a] - lo[a]
        if depth < d.support * (1.0 - tol):
            raise SceneError(f"{path}.upper", f"the buffer is {depth:g} deep along its axis {a}: it must be at "
                             f"least one kernel support ({d.support:g}) deep, so the fluid beside it has a full "
                             "support")
        downstream = hi[a] if f.velocity[a] > 0 else lo[a]
        if not d.lower[a] + tol * d.dx < downstream < d.upper[a] - tol * d.dx:
            raise SceneError(f"{path}.velocity", f"it points out of the domain: the buffer's downstream face "
                             f"(axis {a} at {downstream:g}) must lie inside it")
        fill_lo = np.asarray(self.initial.fill_lower or d.lower, dtype=float)
        fill_hi = np.asarray(self.initial.fill_upper or d.upper, dtype=float)
        # the buffer's cross-section upstream of it (the fluid's lattice leaves out the buffer itself)
        upstream_lo, upstream_hi = lo.copy(), hi.copy()
        if f.velocity[a] > 0:
            upstream_lo[a], upstream_hi[a] = d.lower[a] - d.dx, lo[a]
        else:
            upstream_lo[a], upstream_hi[a] = hi[a], d.upper[a] + d.dx
        if self.initial.drop_radius == 0 and _overlap(fill_lo, fill_hi, upstream_lo, upstream_hi, tol * d.dx):
            raise SceneError(f"{path}.lower", "fluid fills the buffer's cross-section upstream of it "
                             "(initial.fill_lower/fill_upper, the whole domain by default): the buffer's rows "
                             "would run into it")
        from psph.boundaries.bodies import bounds

        for j, b in enumerate(self.bodies):
            if b.container:
                continue
            # (a margin: a plate whose edge is 0.9999999999999999 touches a buffer ending at 1, a new user's audit)
            if _overlap(lo[:2], hi[:2], *bounds(b), tol * d.dx):
                raise SceneError(path, f"the buffer overlaps bodies[{j}] ({b.name!r}) at t = 0")
        if any(b.model == "ghost" for b in self.bodies):
            raise SceneError(path, "inflow buffers work with clone walls, not ghost walls")
        return lo, hi

    def _check_probes(self, fluid):
        d = self.domain
        if self.output.probes and not fluid:
            raise SceneError("output.probes", f"probes sample a flow, not physics.scheme = {self.physics.scheme!r}")
        for k, point in enumerate(self.output.probes):
            if len(point) != d.dimension:
                raise SceneError(f"output.probes[{k}]", f"expected {d.dimension} entries (domain.dimension), "
                                 f"got {len(point)}")
            for a in range(d.dimension):
                if not d.lower[a] <= point[a] <= d.upper[a]:
                    raise SceneError(f"output.probes[{k}]", f"{list(point)} lies outside the domain along axis {a}")

    def _needs_2d_fluid(self, key):
        """Refuse the diagnostics `key` without a fluid scheme or in a dimension other than 2."""
        if self.physics.scheme not in FLUID_SCHEMES:
            raise SceneError(key, f"needs a fluid scheme, not physics.scheme = {self.physics.scheme!r}")
        if self.domain.dimension != 2:
            raise SceneError(key, "needs a 2-D scene")

    def _check_jet(self):
        if not self.diagnostics.impinging_jet:
            return
        key = "diagnostics.impinging_jet"
        self._needs_2d_fluid(key)
        if not self.inflow or self.inflow[0].velocity[1] >= 0.0 or self.inflow[0].velocity[0] != 0.0:
            raise SceneError(key, "needs inflow[0] with a velocity [0, -U] (the jet falls along -y)")
        if self.inflow[0].profile != "uniform":
            raise SceneError("inflow[0].profile", "Taylor's wall pressure (diagnostics.impinging_jet) is a uniform "
                             "jet's: give profile = \"uniform\"")
        if not self.bodies or self.bodies[0].shape != "rectangle" or self.bodies[0].angle != 0.0:
            raise SceneError(key, "needs bodies[0], an unrotated rectangle whose top is the plate")

    def _check_dam_break(self):
        if not self.diagnostics.dam_break:
            return
        key, d = "diagnostics.dam_break", self.domain
        self._needs_2d_fluid(key)
        g = self.physics.gravity
        if len(g) != 2 or g[0] != 0.0 or g[1] >= 0.0:
            raise SceneError(key, "needs physics.gravity along -y, [0, -g]")
        if not self.initial.fill_upper or self.initial.fill_upper[0] > d.upper[0] - 0.5 * d.dx:
            raise SceneError(key, "needs initial.fill_upper short of the domain along x: the column collapses "
                             "along +x")
        if self.diagnostics.impinging_jet:
            raise SceneError(key, "a scene is a dam break or an impinging jet (diagnostics.impinging_jet), not both")

    def has_clone_walls(self) -> bool:
        """Whether some body is made of clone particles (bodies[].model)."""
        return any(b.model == "clone" for b in self.bodies)

    def unread_keys(self) -> list:
        """Keys set away from their defaults that this run does not read, "section.key" each: a scene file
        may hold several methods' settings and switch between them with --set, so they are not refused;
        psph run and psph info name them. The shifting section's keys whose text names one method
        ("delta_plus: ...") outside it, the IIPS call's keys without IIPS (the pre-procedure's with neither
        it nor a pre-procedure), the fluid runs' time keys in static and kinematic runs, and the time and
        output keys a static run does not read (it iterates, and writes its first and last states)."""
        scheme, method = self.physics.scheme, self.shifting.method
        fluid = scheme in FLUID_SCHEMES
        keys = [f"shifting.{name}" for name, f in ShiftingSpec.__dataclass_fields__.items()
                if _methods_named(f.metadata["doc"]) and method not in _methods_named(f.metadata["doc"])]
        if method != "iips":
            pre = self.iips.pre_newton > 0 and scheme != "none"
            keys += [f"iips.{name}" for name in IIPSSpec.__dataclass_fields__  # (the pre-procedure has no
                     if not pre or name in ("procedure", "threshold", "beta", "beta_from", "max_newton",  # threshold
                                            "on_failure", "on_stall", "stall_max_shift")]  # and stops on failure)
        if self.iips.beta == 0.0 and "iips.beta_from" not in keys:
            keys.append("iips.beta_from")
        if not fluid:  # (an audit: a kinematic run's physics.reference_length, not its L, went unmentioned)
            keys += ["time.retries", "time.integrator"] + [f"physics.{name}" for name in FLUID_PHYSICS]
            # only the initial fields read these (psph.initial.initial_fields; a new user's audit: gravity
            # went unnamed in static and kinematic runs), and the kinematic step c0 and U
            analytic = self.initial.velocity in ("taylor_green", "elliptical_drop")  # (p from rho0 and U)
            hydrostatic = self.initial.pressure == "hydrostatic"
            keys += [] if hydrostatic else ["physics.gravity"]
            keys += [] if analytic or hydrostatic else ["physics.density"]
            if scheme == "none":
                keys += ["physics.sound_speed"] + ([] if analytic else ["physics.reference_velocity"])
        else:
            keys.append("diagnostics.test_wavelength")
        if scheme == "none":
            keys += ["time.t_end", "time.cfl", "output.every", "output.history_every"]
        if self.iips.update not in ("mls1", "mls2"):
            keys.append("iips.mls_fit")
        if self.initial.velocity != "uniform":
            keys.append("initial.uniform_velocity")
        # (a keys audit: the following were read nowhere in such runs, and went unnamed)
        if scheme == "riemann_ale":  # its fluxes have no tensile switch
            keys.append("physics.tensile_switch")
        if scheme in ("delta_ale_const_mass", "delta_ale_const_volume"):  # volumes follow the density there
            keys.append("physics.max_volume_variation")
        if self.physics.artificial_viscosity > 0.0:  # nu from alpha, not from U L / Re
            keys += ["physics.reynolds", "physics.reference_length"]
        if scheme != "none":  # a static run's
            keys.append("diagnostics.stop_at_cartesian")
        if method not in EXPLICIT_LAWS:  # restricts an explicit law's shifting velocity only
            keys.append("free_surface.lambda_normal")
        if method == "neuhauser" and self.shifting.fictitious_pressure:  # P^F replaces P_S
            keys.append("shifting.neuhauser_ps")
        if method == "explicit_iterative":  # a static run's count, or a time-dependent run's
            keys.append("shifting.iterations_per_step" if scheme == "none" else "shifting.max_iterations")
        if not self.detects_free_surface():  # (a free-surface audit: they went unnamed)
            keys += [f"free_surface.{name}" for name in FreeSurfaceSpec.__dataclass_fields__]
        return [key for key in dict.fromkeys(keys) if self._set(key)]

    def detects_free_surface(self) -> bool:
        """Whether the run detects a free surface, which the free_surface keys tune: a shifting method or the
        IIPS pre-procedure moves the particles of a scene with one (shifts_free_surface), or a delta_ale
        scheme reads the flags at every step (switches_free_surface)."""
        pre = self.physics.scheme != "none" and self.iips.pre_newton > 0
        return self.shifts_free_surface(pre_procedure=pre) or self.switches_free_surface()

    def shifts_free_surface(self, pre_procedure=False) -> bool:
        """Whether a fluid or static scene has a free surface and its shifting method (or, with
        pre_procedure, the IIPS pre-procedure, whatever the method) moves the particles: the shifting is
        then restricted there (boundaries.free_surface.make_free_surface, thesis eq. 6.29)."""
        shifts = pre_procedure or self.shifting.method != "none"
        return shifts and self.physics.scheme in (*FLUID_SCHEMES, "none") and bool(self.describe_free_surface())

    def surface_switches(self) -> bool:
        """Whether a fluid scheme's switches know the free-surface region: a fluid scheme in a scene with a
        free surface (schemes.delta_ale.DeltaALE; riemann_ale's only switch is its clone walls' no-pull)."""
        return self.physics.scheme in FLUID_SCHEMES and bool(self.describe_free_surface())

    def switches_free_surface(self) -> bool:
        """Whether such a scheme detects the surface at every step: for its tensile switch (off in the
        free-surface region, seed 004 eq. 3), its diffusion switch (free_surface.lambda_diffusion, seed 001
        section 6.3) or its clone walls that never pull (physics.wall_adhesion = false)."""
        phys = self.physics
        tensile = phys.tensile_switch and phys.scheme != "riemann_ale"  # (its fluxes have none)
        return self.surface_switches() and (tensile or self.free_surface.lambda_diffusion > 0.0
                                            or (self.has_clone_walls() and not phys.wall_adhesion))

    def _set(self, key) -> bool:
        """Whether `key` ("section.name") differs from its default."""
        section, name = key.split(".")
        spec = getattr(self, section)
        return getattr(spec, name) != type(spec).__dataclass_fields__[name].default

    def describe_free_surface(self) -> str:
        """Where the fluid has a free surface, in words ("" for none): a drop's rim, or the fill region
        stopping short of the domain."""
        if self.initial.drop_radius > 0:
            return "the drop's rim (initial.drop_radius)"
        axis = self.free_surface_axis()
        if axis is not None:
            return f"the fill region's side along axis {axis} (initial.fill_lower/fill_upper)"
        if self.domain.outflow:  # the fluid is cut off there: its particles have half a support
            return f"the fluid's cut at the outflow faces {', '.join(self.domain.outflow)} (domain.outflow)"
        return ""

    def _bare_faces(self) -> list:
        """The bounded faces of the domain ("x-", "y+", ...) that the fill region reaches, with no container
        (a box or polygon around the fluid) to wall them (an immersed body walls none; a drop reaches none)."""
        d, lo, hi = self.domain, self.initial.fill_lower, self.initial.fill_upper
        if any(b.container for b in self.bodies) or self.initial.drop_radius > 0:
            return []
        faces = []
        for a in range(d.dimension):
            if not d.periodic[a]:
                if not lo or lo[a] <= d.lower[a] + 0.5 * d.dx:
                    faces.append("xyz"[a] + "-")
                if not hi or hi[a] >= d.upper[a] - 0.5 * d.dx:
                    faces.append("xyz"[a] + "+")
        return faces

    def bare_fluid_faces(self) -> list:
        """A flow's bounded faces that its fluid reaches with nothing there, _bare_faces but for the outflow
        faces and the faces the inflows feed from (behind their velocity's axis and direction): the particles
        there have no neighbour beyond, and leave (psph run warns)."""
        if self.physics.scheme not in FLUID_SCHEMES:
            return []
        held = set(self.domain.outflow)
        for inflow in self.inflow:
            axis = int(np.argmax(np.abs(inflow.velocity)))
            held.add("xyz"[axis] + ("-" if inflow.velocity[axis] > 0 else "+"))
        return [face for face in self._bare_faces() if face not in held]

    def fluid_height(self) -> float:
        """The height H of the initial fluid along physics.gravity, across its bounded axes (along a periodic
        axis the fluid falls freely, no column builds up): the drop's diameter, else the fill region (the
        domain by default) cut by the domain. The hydrostatic density variation at its foot is g H / c0^2."""
        d, g = self.domain, np.asarray(self.physics.gravity[:self.domain.dimension], dtype=float)
        norm = float(np.linalg.norm(g))
        if norm == 0.0:
            return 0.0
        if self.initial.drop_radius > 0:
            return 2.0 * self.initial.drop_radius
        lo = np.maximum(self.initial.fill_lower or d.lower, d.lower)
        hi = np.minimum(self.initial.fill_upper or d.upper, d.upper)
        bounded = ~np.asarray(d.periodic, dtype=bool)
        return float(np.sum((np.abs(g) / norm * np.maximum(hi - lo, 0.0))[bounded]))

    def free_surface_axes(self) -> list:
        """The axes along which the fluid's fill region stops short of the domain (a free surface there)."""
        d, lo, hi = self.domain, self.initial.fill_lower, self.initial.fill_upper
        return [a for a in range(d.dimension)
                if (lo and lo[a] > d.lower[a] + 0.5 * d.dx) or (hi and hi[a] < d.upper[a] - 0.5 * d.dx)]

    def free_surface_axis(self):
        """The first of free_surface_axes, or None."""
        return next(iter(self.free_surface_axes()), None)

    def _check_fill_wraps(self):
        """A fill region reaching past the domain along a periodic axis: the lattice covers the domain only, so
        the part beyond would be dropped, not wrapped round (it was, silently: an audit). Along a bounded axis
        the face cuts the fluid, which is a container's design or a bare face (refused or warned)."""
        d = self.domain
        for key, bound, sign in (("fill_lower", d.lower, -1.0), ("fill_upper", d.upper, 1.0)):
            given = getattr(self.initial, key)
            for a in range(d.dimension):
                if given and d.periodic[a] and sign * (given[a] - bound[a]) > 0.5 * d.dx:
                    raise SceneError(f"initial.{key}", f"{given[a]:g} along axis {a} lies beyond the domain "
                                     f"({bound[a]:g}) on a periodic axis: the fill region does not wrap round; "
                                     f"give it within domain.lower .. upper")

    def _check_hydrostatic_surface(self):
        """A hydrostatic start whose free surface (initial.fill_upper, or the domain's top) lies above the
        fluid's top: the fluid is cut below it, by the domain or by a container, and its pressure was taken
        from the surface given, above the cut (an audit: a fill 0.3 above the tank's roof ran so, silently).
        The fluid's top is found on the lattice: the fill region's top row, and the rows below it, as
        psph.boundaries.in_fluid_region fills them, so that any container (box, rotated, polygon) is covered, to
        the lattice's resolution: a surface less than dx/2 above a roof passes, and so does a roof that
        cuts the top row only in part (a tilted one). A fill given wider than a container, as the scenes
        give it, is cut by the walls by design."""
        ini, d, g = self.initial, self.domain, self.physics.gravity
        if ini.pressure != "hydrostatic":
            return
        if ini.velocity in ("taylor_green", "elliptical_drop"):  # (an audit: it replaced Taylor-Green's silently)
            raise SceneError("initial.pressure", f"\"hydrostatic\" with initial.velocity = \"{ini.velocity}\": that "
                             "field comes with its own analytic pressure; give initial.pressure = \"zero\"")
        if d.dimension < 2:  # (a dimensions audit: the message below offered a 2-D gravity to a 1-D scene)
            raise SceneError("initial.pressure", "\"hydrostatic\" (p = rho0 |g| (y_s - y)) needs a y axis: a 2-D or "
                             "3-D scene")
        if not (len(g) == d.dimension and g[1] < 0.0
                and all(v == 0.0 for a, v in enumerate(g) if a != 1)):  # (a fuzzing audit: 0 or the wrong sign)
            raise SceneError("initial.pressure", f"\"hydrostatic\" (p = rho0 |g| (y_s - y)) needs gravity along -y, "
                             f"physics.gravity = [0, -g]{' or [0, -g, 0]' if d.dimension == 3 else ''} with g > 0; "
                             f"got {list(g)} in {d.dimension}-D")
        given = ini.fill_upper[1] if ini.fill_upper else d.upper[1]
        if given > d.upper[1] + 1e-9 * d.dx:
            raise SceneError("initial.fill_upper", f"the hydrostatic pressure's free surface {given:g} is above "
                             f"the domain's top, {d.upper[1]:g}, where the fluid is cut: give at most {d.upper[1]:g}")
        if not any(b.container for b in self.bodies):  # (bodies are 2-D: a row of the lattice is short)
            return
        from psph.boundaries import in_fluid_region  # geometry: numpy and the body profiles

        axes = [d.lower[a] + (np.arange(n) + 0.5) * d.dx for a, n in enumerate(d.lattice_shape())]

        def filled(y) -> bool:
            nodes = np.stack([c.ravel() for c in np.meshgrid(*axes[:1], [y], *axes[2:], indexing="ij")], axis=1)
            return bool(in_fluid_region(self, nodes).any())

        rows = axes[1][axes[1] <= given][::-1]  # from the fill region's top row down
        k = next((k for k, y in enumerate(rows) if filled(y)), None)  # None: no fluid (create_particles says so)
        if k:
            y = rows[k]
            raise SceneError("initial.fill_upper", f"the hydrostatic pressure's free surface {given:g}"
                             f"{'' if ini.fill_upper else ' (not given: the domain top)'} is above the fluid's top "
                             f"lattice row, y = {y:g}, {k} row(s) below the fill region's: a wall or body cuts the "
                             f"fluid there; give at most {y + 0.5 * d.dx:g}")

    def _check_subsonic(self, k, body):
        """A body (or lid) whose surface reaches the speed of sound: the weakly compressible fluid cannot follow
        it (the run stopped at step 1 blaming 'the flow'). Its peak speed: |velocity| + |angular_velocity| x
        the farthest point of its outline from its centre."""
        if self.physics.scheme not in FLUID_SCHEMES:
            return
        m, c0 = body.motion, self.physics.sound_speed
        reach = (max(body.size) if body.shape == "ellipse" else 0.5 * math.hypot(*body.size)) if body.size else 0.0
        peak = {"motion.velocity": math.hypot(*m.velocity) if m.velocity else 0.0,
                "motion.angular_velocity": abs(m.angular_velocity) * reach,
                "lid_velocity": abs(body.lid_velocity[0]) if body.lid_velocity else 0.0}
        if peak["motion.velocity"] + peak["motion.angular_velocity"] >= c0 or peak["lid_velocity"] >= c0:
            raise _supersonic(f"bodies[{k}].{max(peak, key=peak.get)}", "the body's surface would move",
                              max(peak["lid_velocity"], peak["motion.velocity"] + peak["motion.angular_velocity"]), c0)

    def check(self, path):
        for key in ("fill_lower", "fill_upper"):  # (first: the checks below index them by axis)
            value = getattr(self.initial, key)
            if value and len(value) != self.domain.dimension:
                raise SceneError(f"initial.{key}", f"expected {self.domain.dimension} entries (domain.dimension)")
        fluid = self.physics.scheme in FLUID_SCHEMES
        surface = self.describe_free_surface()
        if self.physics.scheme == "kinematic" and surface:
            raise SceneError("initial", f"a kinematic run advects a distribution that fills its periodic domain; "
                             f"this one has a free surface ({surface})")
        if self.physics.scheme == "none" and surface and self.shifting.method == "explicit_iterative":
            raise SceneError("shifting.method", f"explicit_iterative has no free-surface treatment, and would push "
                             f"the particles of {surface} out: use iips, which keeps them (thesis 10.2.1)")
        bare = self._bare_faces()
        if self.physics.scheme in ("none", "kinematic") and self.shifting.method != "none" and bare:
            raise SceneError("domain.periodic", f"{list(self.domain.periodic)}: the particles along the bounded "
                             f"face(s) {', '.join(bare)} have no neighbour beyond it and no wall, and the shifting "
                             "pushes them out of the domain (an audit: exit 3 at iteration 1): make the axis "
                             "periodic, put a container body around the particles, or leave a free surface there "
                             "(initial.fill_lower / fill_upper)")
        if self.physics.scheme == "none" and self.iips.pre_newton > 0:  # ran silently without either
            raise SceneError("iips.pre_newton", "a static run is itself the pre-procedure (its iterations are "
                             "iips.max_newton); pre_newton and beta apply to kinematic and fluid runs")
        if self.iips.beta > 0 and self.iips.pre_newton == 0:
            raise SceneError("iips.beta", "a static run has no pre-procedure to scale: give iips.threshold"
                             if self.physics.scheme == "none" else
                             "iips.beta scales Linf(grad C) after a pre-procedure: give iips.pre_newton > 0")
        if self.bodies:
            if self.domain.dimension != 2:
                raise SceneError("bodies", "solid bodies are 2-D (seed 004 gives the 2-D clone particles)")
            if not fluid and self.physics.scheme != "none":
                raise SceneError("bodies", f"bodies need a fluid scheme or a static run, not {self.physics.scheme!r}")
            names = [b.name for b in self.bodies]
            if len(set(names)) != len(names):
                raise SceneError("bodies", f"body names must be unique, got {names}")
            self._check_ghost_walls(fluid)
            from psph.boundaries.bodies import check_placement  # geometry: numpy and the body profiles

            for k, b in enumerate(self.bodies):  # before the motion is sampled (a huge speed overflows there)
                self._check_subsonic(k, b)
            check_placement(self)
            d = self.domain
            for k, b in enumerate(self.bodies):
                if b.lid_velocity and d.periodic[1] and b.center[1] + b.size[1] / 2.0 >= d.upper[1] - 1e-9 * d.dx:
                    raise SceneError(f"bodies[{k}].lid_velocity", "the box's top side is not inside the periodic "
                                     "y axis (a box spanning it keeps only its side plates): the lid would be ignored")
        lo = self.initial.fill_lower or self.domain.lower
        hi = self.initial.fill_upper or self.domain.upper
        for a in range(self.domain.dimension):
            if hi[a] <= lo[a]:
                key = "initial.fill_upper" if self.initial.fill_upper else "initial.fill_lower"
                raise SceneError(key, f"the fill region is empty along axis {a}: upper {hi[a]:g} <= lower {lo[a]:g}")
        self._check_fill_wraps()
        method = self.shifting.method
        self._check_drop(fluid)
        self._check_packing(fluid)
        self._check_open(fluid)
        self._check_hydrostatic_surface()  # (after the inflows' check: it fills the lattice)
        self._check_jet()
        self._check_dam_break()
        self._check_probes(fluid)
        surface = self.describe_free_surface()
        if fluid and surface and (method != "none" or self.iips.pre_newton > 0):
            ghosts = [k for k, b in enumerate(self.bodies) if b.model == "ghost"]
            if ghosts:
                raise SceneError(f"bodies[{ghosts[0]}].model", f"shifting with a free surface ({surface}) needs "
                                 "clone walls: it relies on the walls' solid particles (IIPS takes them as "
                                 "neighbours of grad C, WallTerms.keep_shift_off holds an explicit law's shifting "
                                 "off them), which ghost walls do not have")
        if self.physics.wall_adhesion and not (fluid and surface and self.has_clone_walls()):
            raise SceneError("physics.wall_adhesion", "keeps the clone walls' pull on the fluid near a free surface: "
                             "this scene has " + ("no clone walls" if not self.has_clone_walls() else
                                                  "no free surface" if not surface else "no fluid scheme"))
        if self.free_surface.lambda_diffusion > 0.0 and not (fluid and surface
                                                               and self.physics.scheme != "riemann_ale"):
            raise SceneError("free_surface.lambda_diffusion", "switches the diffusive terms of a delta_ale scheme off "
                             "near a free surface: this scene has " + (
                                 "no free surface" if not surface else f"physics.scheme = {self.physics.scheme!r}"
                                 + (", whose fluxes have no diffusive terms: set it to 0"
                                    if self.physics.scheme == "riemann_ale" else "")))
        if fluid and method == "explicit_iterative":
            raise SceneError("shifting.method", "explicit_iterative is for static and kinematic runs; fluid "
                             "schemes take iips or an explicit law (lind, skillen, oger, delta_plus, neuhauser)")
        if method in EXPLICIT_LAWS and not (fluid or self.physics.scheme == "kinematic"):
            raise SceneError("shifting.method", f"{method} shifts inside a fluid scheme or a kinematic run; "
                             f"physics.scheme is {self.physics.scheme!r}")
        if (method == "neuhauser" and self.shifting.fictitious_pressure
                and self.physics.scheme in ("delta_ale_const_volume", "kinematic")):  # (an audit of the laws)
            raise SceneError("shifting.fictitious_pressure", "P^F = p_ref V0 / V (thesis eq. 7.3) is p_ref "
                             f"throughout under physics.scheme = {self.physics.scheme!r}, whose volumes stay V0: "
                             "it would be Neuhauser with P_S = 1 (set shifting.neuhauser_ps = 1 for that)")
        if fluid and self.time.t_end <= 0.0:
            raise SceneError("time.t_end", "a fluid run needs t_end > 0")
        if self.iips.update != "none" and not (fluid and method == "iips"):  # (a style audit: a kinematic run
            # with iips was told its method was wrong)
            wrong = (f"shifting.method = {method!r}" if fluid else
                     f"physics.scheme = {self.physics.scheme!r}, not a fluid scheme")
            raise SceneError("iips.update", f"{self.iips.update!r}: field updates apply to fluid runs with "
                             f"shifting.method = iips, and this scene has {wrong} (set iips.update = \"none\")")
        out = self.output
        if (out.checkpoint_every or out.checkpoint_minutes) and self.physics.scheme == "none":  # (psph info
            # passed it: only psph run refused it, a style audit)
            key = "output.checkpoint_every" if out.checkpoint_every else "output.checkpoint_minutes"
            raise SceneError(key, "checkpoints are written by time-dependent runs (flow, kinematic), not static "
                                  "ones (physics.scheme = 'none')")
        if self.iips.update == "nfts" and self.physics.scheme not in ("delta_ale", "riemann_ale"):
            raise SceneError("iips.update", "nfts updates masses and volumes: it needs physics.scheme = delta_ale "
                             "or riemann_ale")
        for key, default in (("muscl_limiter", "minmod"), ("riemann_dissipation", "full")):
            if getattr(self.physics, key) != default and self.physics.scheme != "riemann_ale":
                raise SceneError(f"physics.{key}", "the Riemann fluxes belong to physics.scheme = riemann_ale, "
                                 f"not {self.physics.scheme!r}")
        unread = {"riemann_ale": ("delta", "delta_m"), "delta_ale_const_mass": ("delta_m",),
                  "delta_ale_const_volume": ("delta_m",)}.get(self.physics.scheme, ())
        for key in unread:  # the Riemann fluxes replace D^rho and D^m; only delta_ale's masses diffuse
            if getattr(self.physics, key) != PhysicsSpec.__dataclass_fields__[key].default:
                raise SceneError(f"physics.{key}", f"physics.scheme = {self.physics.scheme!r} has no "
                                 f"{'mass' if key == 'delta_m' else 'density'} diffusion to scale (delta_ale"
                                 f"{'' if key == 'delta_m' else ' family'} only)")
        if fluid and self.neighbours.skin == 0.0:
            raise SceneError("neighbours.skin", "a flow needs a skin: with 0 the neighbour lists cannot hold a time "
                             "step's stages (the default is 0.1)")
        if self.physics.gravity and len(self.physics.gravity) != self.domain.dimension:
            raise SceneError("physics.gravity", f"expected {self.domain.dimension} entries (domain.dimension)")
        if self.physics.scheme == "kinematic":
            if self.time.t_end <= 0.0:
                raise SceneError("time.t_end", "a kinematic run needs t_end > 0")
            d = self.domain
            if not (d.dimension == 2 and all(d.periodic)
                    and math.isclose(d.upper[0] - d.lower[0], d.upper[1] - d.lower[1])):
                raise SceneError("physics.velocity_field", "taylor_green needs a 2-D bi-periodic square domain")
        if self.physics.free_stream:
            if len(self.physics.free_stream) != self.domain.dimension:
                raise SceneError("physics.free_stream", f"expected {self.domain.dimension} entries (domain.dimension)")
            if not (fluid and all(self.domain.periodic) and self.initial.velocity == "zero"):
                raise SceneError("physics.free_stream", "needs a fluid scheme starting from rest in a fully "
                                 "periodic domain (walls would take the momentum the force puts in)")
            if not any(self.physics.free_stream):
                raise SceneError("physics.free_stream", "a zero free stream: leave the key out for none")
        if self.initial.velocity == "taylor_green":
            d = self.domain
            square = d.dimension == 2 and all(d.periodic) and math.isclose(
                d.upper[0] - d.lower[0], d.upper[1] - d.lower[1])
            if not square:
                raise SceneError("initial.velocity", "taylor_green needs a 2-D bi-periodic square domain")
        reach = (1.0 + self.neighbours.skin) * self.domain.support
        for a in range(self.domain.dimension):
            length = self.domain.upper[a] - self.domain.lower[a]
            if self.domain.periodic[a] and length <= reach:
                raise SceneError("domain.dx", f"periodic axis {a} (length {length:g}) must be longer than the "
                                 f"kernel support plus skin ({reach:g}); refine dx or lower h_over_dx")
        wavelength = self.diagnostics.test_wavelength
        for a in range(min(self.domain.dimension, 2)):
            # (read by static and kinematic runs only: a 3-D audit found its default refusing fluid boxes)
            if self.domain.periodic[a] and self.physics.scheme in ("none", "kinematic"):
                waves = (self.domain.upper[a] - self.domain.lower[a]) / wavelength
                if not math.isfinite(waves) or waves > 1e12:
                    raise SceneError("diagnostics.test_wavelength", f"{wavelength:g} is too short for axis {a} "
                                     f"({waves:.3g} waves)")
                if round(waves) < 1:
                    raise SceneError("diagnostics.test_wavelength", f"{wavelength:g} is longer than the periodic "
                                     f"length of axis {a}: the test function would be constant")
                if abs(waves - round(waves)) > 1e-8 * max(1.0, waves):
                    raise SceneError("diagnostics.test_wavelength",
                                     f"must divide the periodic length of axis {a} (got {waves:.6g} waves)")
