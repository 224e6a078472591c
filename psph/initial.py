"""Initial particle distributions."""

import numpy as np

from psph.analytic import EllipticalDrop, taylor_green
from psph.compute.random import gaussian_by_gid
from psph.errors import SceneError
from psph.parallel.comm import allreduce_max, allreduce_sum
from psph.particles import FieldSpec, Kind, ParticleSet


def lattice_block(domain_spec, rank: int, size: int):
    """Cell-centred lattice points with gids in this rank's contiguous block of the global numbering.

    gid = row-major index over the lattice (axis 0 slowest). Returns (gid, positions).
    """
    shape = domain_spec.lattice_shape()
    total = int(np.prod(shape))
    start, stop = total * rank // size, total * (rank + 1) // size
    gid = np.arange(start, stop, dtype=np.int64)
    index = np.stack(np.unravel_index(gid, shape), axis=1).astype(np.float64)
    lower = np.asarray(domain_spec.lower, dtype=np.float64)
    return gid, lower + (index + 0.5) * domain_spec.dx


def perturb(gid: np.ndarray, pos: np.ndarray, sigma: float, seed: int) -> None:
    """Add a seeded Gaussian displacement of standard deviation `sigma` to every position, in place.

    The displacement of a particle depends only on (seed, gid): identical on any rank count.
    """
    if sigma > 0.0 and len(gid):
        pos += sigma * gaussian_by_gid(seed, gid, pos.shape[1])


def _check_inside(scene, comm, gid, pos) -> None:
    """Refuse, on every rank, a perturbed lattice (initial.sigma_over_dx) that puts a particle outside the
    domain along a bounded axis (a failure audit: the first neighbour search stopped it as an escaped
    particle, exit 3, naming neither the stage nor the key, with no state written). Collective."""
    from psph.parallel.comm import raise_if_any

    d = scene.domain
    out, open_faces = np.zeros(len(gid), dtype=bool), d.outflow_faces()  # (past an outflow face it just leaves)
    for a in range(d.dimension):
        if not d.periodic[a]:
            out |= ((pos[:, a] < d.lower[a]) & ((a, -1) not in open_faces)) \
                | ((pos[:, a] > d.upper[a]) & ((a, 1) not in open_faces))
    error = None
    if out.any():
        k = int(np.flatnonzero(out)[0])
        error = SceneError("initial.sigma_over_dx", f"{scene.initial.sigma_over_dx:g} (seed {scene.initial.seed}) "
                           f"moves particle gid {int(gid[k])} to {np.array2string(pos[k], precision=6)}, outside the "
                           "domain: lower it, or keep the fill region off the bounded faces (initial.fill_lower / "
                           "fill_upper)")
    raise_if_any(comm, error)


def initial_fields(scene, pos) -> dict:
    """Fields the scene's initial condition sets at the fluid positions `pos`: the analytic Taylor-Green
    velocity and pressure, a uniform velocity (the first inflow's, or initial.uniform_velocity), or the
    hydrostatic pressure (none for initial.velocity = zero, pressure = zero)."""
    fields = {}
    if scene.initial.velocity == "taylor_green":
        d = scene.domain
        vel, p = taylor_green(pos, 0.0, U=scene.physics.reference_velocity, L=d.upper[0] - d.lower[0],
                              rho=scene.physics.density, lower=d.lower)
        fields = {"velocity": vel, "pressure": p}
    if scene.initial.velocity == "elliptical_drop":
        vel, p = elliptical_drop(scene).fields(pos, 0.0)
        fields = {"velocity": vel, "pressure": p}
    if scene.initial.velocity == "inflow":  # its profile too, by the transverse coordinates (0 beside it)
        from psph.boundaries.open import Inflow

        fields = {"velocity": Inflow(scene.inflow[0], scene.domain.dx).velocity_at(0.0, pos)}
    if scene.initial.velocity == "uniform":
        fields = {"velocity": np.tile(np.asarray(scene.initial.uniform_velocity, dtype=np.float64), (len(pos), 1))}
    if scene.initial.pressure == "hydrostatic":
        fields["pressure"] = hydrostatic_pressure(scene, pos)
    return fields


def elliptical_drop(scene, t_end=0.0):
    """The scene's drop as an analytic.EllipticalDrop (A0 = reference_velocity / drop_radius), solved to t_end."""
    ini, ph = scene.initial, scene.physics
    return EllipticalDrop(ini.drop_radius, ph.reference_velocity / ini.drop_radius, t_end,
                          center=scene.domain.center, rho=ph.density)


def reset_initial_fields(scene, particles) -> None:
    """Set the initial-condition fields again at the owned fluid particles' current positions (after the
    pre-procedure or the packing moved them)."""
    fluid = particles.owned("kind") == Kind.FLUID
    for name, values in initial_fields(scene, particles.owned("position")[fluid]).items():
        particles.owned(name)[fluid] = values


INITIAL_FIELD_SPECS = {"velocity": FieldSpec("velocity", ("d",)), "pressure": FieldSpec("pressure")}


def hydrostatic_pressure(scene, pos) -> np.ndarray:
    """p = rho0 |g| (y_s - y): gravity along -y, free surface y_s at the top of the fluid region."""
    g = abs(scene.physics.gravity[1]) if len(scene.physics.gravity) > 1 else 0.0
    top = scene.initial.fill_upper[1] if scene.initial.fill_upper else scene.domain.upper[1]
    return scene.physics.density * g * (top - pos[:, 1])


def create_particles(scene, comm, specs=()) -> ParticleSet:
    """This rank's share of the initial particles (not yet spatially distributed): the fluid lattice
    (within the fill region and the walls, outside immersed bodies and inflow buffers), then the bodies'
    solid particles, then the inflow buffers' particles (psph.boundaries.open). Collective."""
    from psph.boundaries import SOLID_FIELDS, in_fluid_region, solid_arrays

    dspec = scene.domain
    particles = ParticleSet(dspec.dimension)
    for spec in specs:
        particles.add_field(spec)
    if scene.bodies:
        for spec in SOLID_FIELDS:
            particles.add_field(spec, fill=-1 if spec.name == "body" else 0)
    gid, pos = lattice_block(dspec, comm.rank, comm.size)
    keep = in_fluid_region(scene, pos)
    gid, pos = gid[keep], pos[keep]
    if not scene.inflow and not allreduce_sum(comm, len(gid)):  # (a jet may start empty: its buffer fills it)
        ini = scene.initial
        key = ("initial.drop_radius" if ini.drop_radius > 0 else "initial.fill_upper" if ini.fill_upper else
               "initial.fill_lower" if ini.fill_lower else "domain.dx")
        raise SceneError(key, f"no lattice node of dx = {dspec.dx:g} lies in the fluid's region (the fill region or "
                         "drop, outside the bodies): no fluid particle")
    perturb(gid, pos, scene.initial.sigma_over_dx * dspec.dx, scene.initial.seed)
    if not any(b.container for b in scene.bodies):  # (in a container, the initial state's check names the wall
        _check_inside(scene, comm, gid, pos)  # crossed and writes the state; an immersed body walls no face)
    fields = initial_fields(scene, pos)
    for name in fields:
        particles.add_field(INITIAL_FIELD_SPECS[name])
    particles.append_owned({"gid": gid, "position": pos, "kind": np.full(len(gid), Kind.FLUID),
                            "volume": np.full(len(gid), dspec.dx ** dspec.dimension), **fields}, fill={"body": -1})
    solids = solid_arrays(scene, comm.rank, comm.size, int(np.prod(dspec.lattice_shape())))
    if solids is not None:
        particles.append_owned(solids)  # pressure 0 in the solids (their own is mirrored from the fluid)
    if scene.inflow:
        from psph.boundaries.open import initial_inflow_particles

        last = int(particles.owned("gid").max()) if particles.n_owned else -1
        inflow = initial_inflow_particles(scene, comm, int(allreduce_max(comm, last)) + 1)
        for name in ("velocity", "pressure"):
            particles.add_field(INITIAL_FIELD_SPECS[name])
        particles.append_owned({k: v for k, v in inflow.items() if k in particles}, fill={"body": -1})
    return particles
