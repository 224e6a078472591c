"""The walls' part of a fluid scheme: body motion, per-stage geometry, the clone-particle terms and the
fixed-ghost baseline.

Solid particles are ordinary rows of the particle set (kinds WALL and BODY) whose positions follow their
body's rigid motion, whose velocity is the body's and whose other fields are never integrated; every
fluid-solid interaction is computed pair by pair from mirrored values (psph.compute.walls.clone_rhs).
The body forces of the last right-hand side evaluation are kept for the history. A box with model =
"ghost" has no solid particles: the fluid near its sides sees mirror images of the fluid instead
(psph.compute.walls.ghost_rhs; the box's forces are not accumulated).
"""

import numpy as np

from psph.boundaries.bodies import make_bodies
from psph.boundaries.geometry import contour_distance, nearest_nodes
from psph.compute.walls import (
    NO_MATRIX,
    clone_rhs,
    clone_viscous_weight,
    ghost_grad_c,
    ghost_images,
    ghost_rhs,
    near_wall_rows,
    off_walls,
)
from psph.parallel.comm import allreduce_sum
from psph.particles import Kind
from psph.profiling import phase

NEAR_NODES = 16  # WallTerms.keep_shift_off: the body nodes a row looks at (within dx/2: 5 on a side, ds = dx/4)
MOTIONS = {"fixed": "fixed", "constant": "constant velocity", "ramp": "ramped velocity",
           "spheric6": "SPHERIC 6 acceleration law", "oscillate": "oscillating"}


class NoWalls:
    """A scene without bodies: the walls' terms are no-ops, so that the scheme and the driver call them
    without testing for walls (STYLE.md 5; a style audit found `walls is not None` at 16 places). Where a
    call would still cost (a collective), its callers read `active`."""

    active = False
    ghost = None
    clones = ()
    fields = ()  # the solid particles' fields (WallTerms: boundaries.SOLID_FIELDS)
    halo_fields = ()

    def describe(self) -> list:
        return []

    def link_nodes(self, system) -> None:
        pass

    def place(self, system, t, positions=True) -> None:
        pass

    def add(self, system, scheme, t, d_rho, d_mom) -> None:
        pass

    def add_ghost_grad_c(self, system, coeff, power, w_ref, out, mat=None) -> None:
        pass

    def keep_shift_off(self, system, t, region, du) -> None:
        pass

    def viscous_weight(self, system, rows, t, directional) -> np.ndarray:
        return np.zeros((0, system.particles.dim, system.particles.dim))

    def trespassers(self, pos, t, margin, gid):
        return None

    def body_forces(self, comm) -> dict:
        return {}


NO_WALLS = NoWalls()


def make_walls(scene):
    """The scene's walls (WallTerms) or, without bodies, NO_WALLS."""
    return WallTerms(scene) if scene.bodies else NO_WALLS


class WallTerms:
    active = True

    def __init__(self, scene):
        self.bodies = make_bodies(scene)
        self.ds = scene.domain.dx / 4.0
        self.shift_reach = scene.domain.dx / 2.0  # keep_shift_off
        self.no_slip = np.array([b.no_slip for b in self.bodies], dtype=np.bool_)
        self.centers = np.zeros((len(self.bodies), 2))
        # NaN until the first right-hand side measures them: the history's row at t = 0, written before it,
        # gave a tank's load as 0.0 against the water's weight (a diagnostics audit)
        self.force = np.full((len(self.bodies), 2, 2), np.nan)
        self.torque = np.full((len(self.bodies), 2), np.nan)
        self.measured = False
        # the owned fluid rows' pressure forces on the solids at the last right-hand side, and where the rows
        # were then (the particle order may change before they are read): the load along a wall
        self.particle_force = np.zeros((0, 2))
        self.particle_force_at = np.zeros((0, 2))
        self.gravity = np.zeros(2)
        if scene.physics.gravity:
            self.gravity[:] = scene.physics.gravity
        self.u_ref = scene.physics.reference_velocity
        self.rho0 = scene.physics.density
        self.clones = [b for b in self.bodies if b.spec.model == "clone"]
        self._fixed_trees = {}  # boundaries.clone.WallTerms._node_trees
        # caches of what a stage would otherwise derive again (a speed audit: 20-24% of the dam break's and the
        # cavity's time went to the walls' Python path); each says what it is valid for
        self._near_rows = (None, None, None)  # _near_wall_rows: (the lists, a copy of the kinds, near_wall_rows)
        self._fixed_placed = None  # _place: the wall_velocity array whose fixed bodies' rows it has written
        self.periodic = scene.domain.periodic
        self.ghost = _ghost_walls(scene, [b for b in self.bodies if b.spec.model == "ghost"])

    def describe(self) -> list:
        out = []
        for b in self.bodies:
            m = b.spec.motion
            how = MOTIONS[m.law] if m.turning_law == m.law else f"{MOTIONS[m.law]}, turning: {MOTIONS[m.turning_law]}"
            lid = f", lid velocity {tuple(b.lid_velocity)}" if b.lid.any() else ""
            model = ("clone particles with local mirroring (seed 004 eq. 5-9)" if b.spec.model == "clone" else
                     "fixed ghost particles, mirror images of the fluid (seed 001 section 6.2)")
            shape = "immersed polygon" if b.spec.shape == "polygon" and not b.spec.container else b.spec.shape
            out.append(f"body {b.name!r}: {shape}, {b.spec.wall.replace('_', '-')}, {how}{lid}; {model}")
        return out

    def trespassers(self, pos, t, margin, gid):
        """(row, body name) of the one of lowest `gid` among `pos` (fluid positions, `gid` theirs) that lie more
        than `margin` inside an immersed body or outside a container (box, polygon) at time t, or None (the
        lowest gid, not the first row: the particle named does not depend on the rank count, a review)."""
        from psph.boundaries.bodies import within_walls
        from psph.boundaries.geometry import inside, shape_spec

        found = None
        for b in self.bodies:
            center, rot = b.rigid(t)[:2]
            angle = b.spec.angle + np.degrees(np.arctan2(rot[1, 0], rot[0, 0]))
            shape = "ellipse" if b.spec.shape == "ellipse" else "rectangle"
            if b.spec.shape == "polygon" and b.spec.container:  # fixed
                bad = ~inside(shape_spec(b.spec), pos) & (within_walls(b.spec, pos) > margin)
            elif b.spec.shape == "polygon":  # immersed: in its reference configuration
                reference = (pos - center) @ rot + b.center0
                bad = inside(shape_spec(b.spec), reference) & (within_walls(b.spec, reference) > margin)
            elif b.spec.shape == "box":
                bad = ~inside((shape, center, [s + 2.0 * margin for s in b.spec.size], angle), pos)
            else:
                size = [max(s - (margin if shape == "ellipse" else 2.0 * margin), 0.0) for s in b.spec.size]
                bad = inside((shape, center, size, angle), pos)
            if bad.any():
                rows = np.flatnonzero(bad)
                k = int(rows[np.argmin(gid[rows])])
                if found is None or gid[k] < gid[found[0]]:
                    found = (k, b.name)
        return found

    def reflect(self, pos, vel):
        """Fluid positions `pos` (owned fluid rows) that crossed a side of a fixed, unrotated box container,
        mirrored back across it with the normal velocity reversed (in place, `vel` likewise). Returns how far
        each row had gone past the side (0 for the others) and the name of the body it crossed. A guard: a
        particle that drifts into the solid layer is crushed there (|rho / rho0 - 1| > 0.5 in the dam break
        at H/dx = 40 while its right wall's solid rows stood 0.82 dx behind the wall, before
        boundaries.extended_lattice aligned them). Sides along a periodic axis are not walls."""
        depth = np.zeros(len(pos))
        body = np.full(len(pos), "", dtype=object)
        for b in self.bodies:
            if b.spec.shape != "box" or b.moves or b.spec.angle != 0.0:
                continue
            half = 0.5 * np.asarray(b.spec.size)
            for a, (lo, hi) in enumerate(zip(np.asarray(b.spec.center) - half, np.asarray(b.spec.center) + half)):
                if self.periodic[a]:
                    continue
                for side, sign in ((lo, 1.0), (hi, -1.0)):
                    past = sign * (side - pos[:, a])  # how far beyond this side, into the wall
                    beyond = past > 0.0
                    depth[beyond] = np.maximum(depth[beyond], past[beyond])
                    body[beyond] = b.name
                    pos[beyond, a] = 2.0 * side - pos[beyond, a]
                    vel[beyond, a] *= -1.0
        return depth, body

    def link_nodes(self, system) -> None:
        """Each owned solid particle's closest node on its body's profile (`wall_node`), that node's normal
        (`ref_normal`, and `normal` for a fixed body) and the distance to it (`wall_distance`), from its
        reference position, as psph.boundaries.solid_arrays makes them. A restart takes them again: a
        checkpoint's node indices point into the profile of the version that wrote it (the Couette plates'
        of 4c054d7, before the periodic plates, ran past the new profile's nodes: an IndexError)."""
        p = system.particles
        body = p.owned("body")
        for b in self.clones:
            rows = np.flatnonzero(body == b.index)
            node, dist = nearest_nodes(b.profile, p.owned("ref_position")[rows])
            p.owned("wall_node")[rows] = node
            p.owned("wall_distance")[rows] = dist
            p.owned("ref_normal")[rows] = b.profile.normals[node]
            if not b.moves:
                p.owned("normal")[rows] = b.profile.normals[node]
        self._fixed_placed = None  # (wall_node changed: _place writes the fixed bodies' wall velocities again)

    # ------------------------------------------------------------ kinematics
    @property
    def fields(self):
        from psph.boundaries import SOLID_FIELDS

        return SOLID_FIELDS

    @property
    def halo_fields(self):
        from psph.boundaries import SOLID_HALO_FIELDS

        return SOLID_HALO_FIELDS

    def place(self, system, t, positions=True):
        """Move the solid particles to time t (positions, normals, velocities, accelerations). Owned rows."""
        with phase("walls"):  # (a benchmark audit: 2 points of the walls' share fell outside it)
            self._place(system, t, positions)

    def _place(self, system, t, positions):
        """A fixed body's centre and wall velocities do not change with t: they are written once for the rows
        as they are, again after anything that replaced the particle arrays (a rebuild's migration and sort, an
        open boundary's emission or removal: Particles.set_owned and set_halo make new arrays, so the
        wall_velocity array itself tells) or moved the nodes (link_nodes)."""
        p = system.particles
        body = p.owned("body")
        fixed_placed = self._fixed_placed is p["wall_velocity"]
        self._fixed_placed = p["wall_velocity"]
        for b in self.bodies:
            if fixed_placed and not b.moves:
                continue
            rows = np.flatnonzero(body == b.index)
            self.centers[b.index] = b.rigid(t)[0]
            if len(rows):  # the wall velocity each solid particle mirrors: its own closest node's
                p.owned("wall_velocity")[rows] = b.nodes(t)[2][p.owned("wall_node")[rows]]
            if not b.moves or not len(rows):
                continue
            pos, vel, acc = b.material(p.owned("ref_position")[rows], t)
            if positions:
                p.owned("position")[rows] = pos
            p.owned("velocity")[rows] = vel
            p.owned("wall_accel")[rows] = acc
            p.owned("normal")[rows] = p.owned("ref_normal")[rows] @ b.rigid(t)[1].T

    def nearest_node_data(self, system, rows, t):
        """For each fluid row near a wall and each body (axis 1, the scene's body index; a ghost wall's
        entries unused, inf), the normal of its closest node on that body and its distance to that body's
        contour (geometry.contour_distance). The kernel
        mirrors each solid neighbour by the row's distance to the neighbour's own body: a row between two
        bodies (an immersed body a few dx from a wall) took the nearer one's for both, which scaled the other's
        mirrored velocities by the ratio of the two distances."""
        points = system.particles.owned("position")[rows]
        normals = np.zeros((len(points), len(self.bodies), 2))
        dist = np.full((len(points), len(self.bodies)), np.inf)
        if len(points):
            for b, (tree, nrm, _) in self._node_trees(t).items():
                k = tree.query(points)[1]
                dist[:, b] = contour_distance(tree.data, self.bodies[b].profile.ends, k, points)
                normals[:, b] = nrm[k]
        return normals, dist

    def _node_trees(self, t):
        """{body index: (k-d tree of its nodes at time t, their normals, the normals with a zero row appended
        for the tree's "no node", index tree.n)} of the clone bodies; a fixed body's built once."""
        from scipy.spatial import cKDTree

        trees = {}
        for b in self.clones:
            if b.index not in self._fixed_trees:
                pos, nrm, _ = b.nodes(t)
                trees[b.index] = (cKDTree(pos), nrm, np.vstack([nrm, np.zeros((1, 2))]))
                if not b.moves:
                    self._fixed_trees[b.index] = trees[b.index]
            else:
                trees[b.index] = self._fixed_trees[b.index]
        return trees

    def keep_shift_off(self, system, t, region, du) -> None:
        """No shifting into a wall in the free-surface region: each owned fluid row in `region` (bool, owned
        rows) closer than dx/2 (shift_reach) to a clone wall gets, for its shifting velocity `du` (owned
        rows, in place), the closest vector with no part into any wall that near (compute.walls.off_walls;
        the node normals point out of the fluid). The free-surface restriction (du . n = 0 at the surface,
        seed 001 section 6.3, thesis eq. 6.29) projects du on the surface's tangent, which crosses a wall
        where the surface meets it and along a film on it, and grad C does not hold a particle off a wall's
        line, which lies halfway between the first solid and the first fluid row: the dam break's film and
        floor particles were driven through the walls (docs/results.md, "Dam break"). Rows farther than dx/2 (the
        lattice's first row lies at dx/2, within round-off) stay free to be shifted back towards the wall.
        Within dx/2 of a convex corner every node's wall counts, so sliding along either face towards the
        other is held too (conservative). Ghost walls need no such rule: the scene refuses them with a free
        surface and a shifting law (schema)."""
        rows = np.flatnonzero(region & (system.particles.owned("kind") == Kind.FLUID))
        if not len(rows) or not self.clones:
            return
        points = system.particles.owned("position")[rows]
        found = []  # each body's nodes within reach (tree.n: none)
        close = np.zeros(len(rows), dtype=bool)  # the rows with a node within reach (the others keep du)
        trees = list(self._node_trees(t).values())
        for tree, _, _ in trees:
            _, nodes = tree.query(points, k=NEAR_NODES, distance_upper_bound=self.shift_reach)
            found.append(nodes)
            close |= (nodes < tree.n).any(axis=1)
        # the normals of the close rows' nodes, zero for none (unit normals: a row is close if any is nonzero)
        near = np.concatenate([padded[nodes[close]] for (_, _, padded), nodes in zip(trees, found)], axis=1)
        off_walls(near, rows[close], du)

    # ----------------------------------------------------------------- rhs
    def add(self, system, scheme, t, d_rho, d_mom):
        """Add the walls' terms (clone particles, ghost images) to the owned fluid rows' rates; keep the body
        forces. Not collective (the forces are reduced when asked, body_forces)."""
        with phase("walls"):
            self._add(system, scheme, t, d_rho, d_mom)

    def _add(self, system, scheme, t, d_rho, d_mom):
        p = system.particles
        self.force[:] = 0.0
        self.measured = True
        self.particle_force = np.zeros((system.particles.n_owned, 2))
        self.particle_force_at = system.particles.owned("position").copy()
        self.torque[:] = 0.0
        du = scheme.shift.du(p)
        switch = scheme.tensile_rows(system)
        no_pull = scheme.no_pull_rows(system)
        if self.clones:
            self._add_clones(system, scheme, t, du, switch, no_pull, d_rho, d_mom)
        if self.ghost is not None:
            rows, images = self._ghost_images(system)
            w = self.ghost
            ghost_rhs(p["position"], p["volume"], p["density"], p["velocity"], du, p["pressure"], rows, *images,
                      w["axis"], w["coord"], w["velocity"], w["no_slip"], system.kernel.params, scheme.c0,
                      scheme.rho0, scheme.eos.tait, scheme.mu, scheme.morris, self.gravity, scheme.wall_variant,
                      scheme.shift.active, switch, d_rho, d_mom)

    def _add_clones(self, system, scheme, t, du, switch, no_pull, d_rho, d_mom):
        p = system.particles
        rows = self._near_wall_rows(system)
        n_i, s_i = self.nearest_node_data(system, rows, t)
        clone_rhs(p["position"], p["volume"], p["density"], p["velocity"], du, p["pressure"], p["kind"],
                  p["body"], p["normal"], p["wall_distance"], p["wall_accel"], p["wall_velocity"], rows, n_i, s_i,
                  self.no_slip,
                  system.nbr_ptr, system.nbr_idx, system.kernel.params, scheme.c0, scheme.rho0, scheme.eos.tait,
                  scheme.mu, scheme.morris, self.gravity, self.ds, scheme.wall_variant, scheme.shift.active,
                  switch, no_pull, self.centers, d_rho, d_mom, self.force, self.torque, self.particle_force)

    def _near_wall_rows(self, system):
        """near_wall_rows of the current lists, computed again only when the lists (new arrays at every
        rebuild) or the kinds changed: it reads nothing else."""
        kind, lists = system.particles["kind"], (system.nbr_ptr, system.nbr_idx)
        cached_lists, cached_kind, rows = self._near_rows
        if (cached_lists is None or cached_lists[0] is not lists[0] or cached_lists[1] is not lists[1]
                or not np.array_equal(cached_kind, kind)):  # (open boundaries flip kinds in place, unrebuilt)
            rows = near_wall_rows(kind, *lists)
            self._near_rows = (lists, kind.copy(), rows)
        return rows

    def viscous_weight(self, system, rows, t, directional) -> np.ndarray:
        """The no-slip clone walls' extra weight in the viscous operators for the owned fluid `rows` at time t,
        (len(rows), 2, 2) (compute.walls.clone_viscous_weight; `directional`: pi_ij's), for the viscous step
        limit: with Morris' operator a Poiseuille flow between no-slip plates at the lattice's limit blew up (a
        new user's audit). Not collective."""
        p = system.particles
        out = np.zeros((len(rows), 2, 2))
        if not self.clones or not self.no_slip.any():
            return out
        near = self._near_wall_rows(system)
        at = np.searchsorted(rows, near)  # both sorted; near-wall rows are fluid rows
        _, s_i = self.nearest_node_data(system, near, t)
        part = np.zeros((len(near), 2, 2))
        clone_viscous_weight(p["position"], p["volume"], p["kind"], p["body"], p["normal"], p["wall_distance"],
                             near, s_i, self.no_slip, system.nbr_ptr, system.nbr_idx, system.kernel.params, self.ds,
                             directional, part)
        out[at] = part
        return out

    def _ghost_images(self, system):
        """Owned fluid rows within a support of a ghost wall and the images they see."""
        p, w = system.particles, self.ghost
        support = system.kernel.support
        pos = p.owned("position")
        dist = w["sign"][None, :] * (pos[:, w["axis"]] - w["coord"][None, :])
        rows = np.flatnonzero((p.owned("kind") == Kind.FLUID) & (dist < support).any(axis=1))
        return rows, ghost_images(p["position"], p["kind"], rows, w, system.nbr_ptr, system.nbr_idx, support)

    def add_ghost_grad_c(self, system, coeff, power, w_ref, out, mat=None):
        """Add the ghost images' part of grad C^ (psph.compute.walls.ghost_grad_c) to the owned rows of out, and
        with `mat` their part of the renormalisation matrix (the free-surface detection's)."""
        if self.ghost is None:
            return
        p, w = system.particles, self.ghost
        rows, images = self._ghost_images(system)
        ghost_grad_c(p["position"], p["volume"], rows, *images, w["axis"], w["coord"], system.kernel.params,
                     coeff, power, w_ref, out, NO_MATRIX if mat is None else mat)

    def body_forces(self, comm) -> dict:
        """Drag and lift coefficients 2 F / (rho0 U^2 D) of every immersed body, pressure and viscous parts,
        from the last right-hand side: drag along the flow seen from the body (against a moving body's
        velocity, along physics.free_stream or +x for a body at rest), lift 90 degrees anticlockwise from it;
        and the moment coefficient 2 T / (rho0 U^2 D^2) of the torque about the body's centre, anticlockwise
        positive (each pair's force applied at the solid particle's node on the profile); and of every
        clone-wall container (box, polygon), the force the fluid exerts on it, force_x_NAME and force_y_NAME,
        pressure and viscous parts together, in the scene's units (per unit depth in 2-D): for water at
        rest, its weight. NaN before the first right-hand side (the history's row at t = 0). Collective."""
        force = allreduce_sum(comm, self.force.copy())
        torque = allreduce_sum(comm, self.torque.copy())
        immersed = [b for b in self.bodies if b.kind == Kind.BODY]
        out = {}
        for b in self.clones:
            if b.kind == Kind.WALL:
                total = force[b.index].sum(axis=0)
                out[f"force_x_{b.name}"], out[f"force_y_{b.name}"] = float(total[0]), float(total[1])
        for b in immersed:
            scale = 2.0 / (self.rho0 * self.u_ref ** 2 * b.reference_length)
            suffix = f"_{b.name}" if len(immersed) > 1 else ""
            drag = b.drag_direction
            lift = np.array([-drag[1], drag[0]])
            for part, k in (("pressure", 0), ("viscous", 1)):
                out[f"cd_{part}{suffix}"] = scale * float(force[b.index, k] @ drag)
                out[f"cl_{part}{suffix}"] = scale * float(force[b.index, k] @ lift)
                out[f"cm_{part}{suffix}"] = scale / b.reference_length * float(torque[b.index, k])
        return out


def _ghost_walls(scene, boxes):
    """The ghost box's sides on non-periodic axes: axis, coordinate, inward sign, velocity (the lid's on the
    top side), and whether the walls are no-slip; None without a ghost box."""
    if not boxes:
        return None
    box = boxes[0]
    axis, coord, sign, vel = [], [], [], []
    for a in range(2):
        if scene.domain.periodic[a]:
            continue
        for side in (-1.0, 1.0):
            axis.append(a)
            coord.append(box.spec.center[a] + side * box.spec.size[a] / 2.0)
            sign.append(-side)
            top = a == 1 and side > 0
            vel.append(box.lid_velocity if top else np.zeros(2))
    return {"axis": np.array(axis, dtype=np.int64), "coord": np.array(coord), "sign": np.array(sign),
            "velocity": np.array(vel, dtype=np.float64).reshape(-1, 2), "no_slip": box.no_slip}
