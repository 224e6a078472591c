"""Free surfaces: detection, and what the shifting does near them.

Detection (psph.compute.free_surface: Marrone et al. 2010, seed 004 ref. [25]; lambda of thesis eq. 6.28)
flags each fluid particle SURFACE (on the free surface), REGION (within a kernel support of a surface
particle: seed 004's "free-surface particles and their neighbouring particles") or 0 (interior), in the
particle field `free_surface`, with lambda in `surface_lambda` and the outward normal in `surface_normal` (in
the region, the surface's normal nearby; zero inside), all written to the snapshots; with outflow faces,
`outflow_band` marks the particles within a kernel support of one, and with inflow buffers `inflow_band`
the fluid within a kernel support of a buffer particle. It runs at the start of
every time step of an explicit law, at the start of every IIPS call, and for every history row.

Near a free surface the shifting would push the surface particles outward, where no particle holds them
(grad C points into the fluid there). So:
- explicit laws: thesis eq. 6.29 (Sun et al.'s delta+-SPH): in the region, du = 0 where lambda < 0.4 and
  du = (I - n (x) n) du elsewhere (seed 001 section 6.3: du . n = 0 close to the free surface);
- IIPS: the fluid within a kernel support of an outflow face or of an inflow buffer's particle is fixed
  (see FreeSurface.unknowns); and the whole region is fixed, not unknowns: the surface particles, as
  thesis section 10.2.1 fixes the interface particles (which it finds by a grad C threshold), and their
  neighbours too, whose supports the surface cuts. There grad C cannot vanish, and with only the surface
  row fixed the Newton iteration drives the next rows through it (a slab perturbed by 0.1 dx: out of the
  domain within one call of 20 iterations; README, Free surfaces);
- the history's L2/Linf(grad C) are taken over the interior particles.

A scene without a free surface, or whose shifting is none, gets NoFreeSurface: no pass, no field (the IIPS
pre-procedure makes its own FreeSurface).
"""

import numpy as np

from psph.compute import sums
from psph.compute.free_surface import (
    SURFACE,
    TIE,
    mark_region,
    outward_normals,
    region_normals,
    restrict_shift,
    scan_surface,
)
from psph.diagnostics import fluid_mask
from psph.parallel.comm import allreduce_sum
from psph.particles import FieldSpec, Kind
from psph.profiling import phase

FIELDS = (FieldSpec("free_surface", (), np.int8), FieldSpec("surface_lambda"), FieldSpec("surface_normal", ("d",)))
# with outflow faces: 1 for the particles within a kernel support of one at detection (IIPS keeps that fluid fixed)
BAND = FieldSpec("outflow_band", (), np.int8)
# with inflow buffers: 1 for the fluid within a kernel support of a buffer particle at detection (the same)
INFLOW_BAND = FieldSpec("inflow_band", (), np.int8)


class NoFreeSurface:
    """No free surface to detect: every fluid particle is interior."""

    active = False
    fields = ()

    def detect(self, system) -> None:
        pass

    def restrict(self, system, du, walls=None, t=0.0) -> None:
        pass

    def interior(self, system) -> np.ndarray:
        """Owned fluid particles away from any free surface (those the history's grad C is measured on)."""
        return fluid_mask(system)

    def unknowns(self, system) -> np.ndarray:
        """Owned particles that IIPS moves."""
        return fluid_mask(system)

    def count(self, system) -> int:
        return 0

    def describe(self) -> str:
        return ""


class FreeSurface(NoFreeSurface):
    active = True
    fields = FIELDS

    def __init__(self, spec, inflow=False):
        """inflow: the scene has inflow buffers (their fluid neighbours get `inflow_band`)."""
        self.spec = spec
        self.inflow = inflow
        # the scheme's WallTerms when it has ghost walls: their images complete the support in lambda
        self.ghost_walls = None

    def detect(self, system) -> None:
        """Flag the surface and its region, with lambda and the outward normals (owned rows; the halo gets the
        flags). Collective."""
        p, k = system.particles, system.kernel
        for spec in FIELDS:
            p.add_field(spec)
        system.refresh(["volume"])  # a field update may have changed the owned volumes since the last exchange
        n, d = p.n_owned, p.dim
        pos, vol, ptr, idx = p["position"], p["volume"], system.nbr_ptr, system.nbr_idx
        with phase("free_surface"):
            mat, grad = np.empty((n, d, d)), np.empty((n, d))
            sums.renormalisation_and_grad_c(pos, vol, ptr, idx, k.params, mat, grad)
            if self.ghost_walls is not None:  # else the fluid along a ghost wall would count as a surface
                self.ghost_walls.add_ghost_grad_c(system, 0.0, 1.0, 1.0, grad, mat)
            lam = p.owned("surface_lambda")
            sums.smallest_eigenvalue(mat, lam)
            normal = p.owned("surface_normal")
            outward_normals(mat, lam, grad, k.h, 1e-3, normal)
            fluid = p["kind"] == Kind.FLUID
            flag = p["free_surface"]
            # a wall's solid particles across an air gap do not close the surface (a jet's front coming down
            # on a plate): only fluid and inflow particles fill the scan region
            blocks = (p["kind"] != Kind.WALL) & (p["kind"] != Kind.BODY)
            scan_surface(pos, fluid, blocks, lam, normal, ptr, idx, self.spec.scan_radius * k.h,
                         self.spec.lambda_surface, self.spec.lambda_interior, flag)
            system.refresh(["free_surface", "surface_normal"])
            mark_region(pos, fluid, ptr, idx, k.support, flag)
            region_normals(pos, flag, ptr, idx, k.params, p["surface_normal"])
            if system.domain.outflow:
                p.add_field(BAND)
                p.owned(BAND.name)[:] = system.domain.past_outflow(p.owned("position"), -k.support * (1.0 - TIE))
            if self.inflow:
                p.add_field(INFLOW_BAND)
                nearest = np.empty(n)  # to the nearest inflow particle (group 0; every other particle is group 1)
                sums.nearest_distance(pos, ptr, idx, np.zeros(p.n_local, np.int8),
                                      (p["kind"] != Kind.INLET).astype(np.int8), nearest)
                p.owned(INFLOW_BAND.name)[:] = nearest < k.support

    def restrict(self, system, du, walls=None, t=0.0) -> None:
        """Thesis eq. 6.29 on the owned shifting velocities `du` (in place); then, with `walls` (the
        scheme's WallTerms at time t), no shifting into a wall in the region (WallTerms.keep_shift_off)."""
        p = system.particles
        restrict_shift(p.owned("free_surface"), p.owned("surface_lambda"), p.owned("surface_normal"),
                       self.spec.lambda_normal, du)
        if walls is not None:
            walls.keep_shift_off(system, t, p.owned("free_surface") > 0, du)

    def interior(self, system) -> np.ndarray:
        return fluid_mask(system) & (system.particles.owned("free_surface") == 0)

    def unknowns(self, system) -> np.ndarray:
        """The interior fluid, but for the fluid within a kernel support of an outflow face, which IIPS keeps
        fixed as the thesis does the inflow and outflow particles (section 10.2.1). Beside an outflow buffer
        that is still filling, that fluid's support is cut while its lambda is an interior particle's (0.83 one
        dx above a face with one buffer row): IIPS pulled it by 0.7 dx towards the face in one call. Without
        a buffer most of it is the cut face's surface region already, but not where a wall's solids fill its
        support (the impinging jet's sheet along the plate), which IIPS moved with a cut support too. So is
        the fluid within a kernel support of an inflow buffer's particle: the buffer's fields are prescribed,
        so the NFTS update's fluxes between it and a moved neighbour made or lost mass (the impinging jet at
        H/dx = 10: the mass budget off by 1.8% at t U/H = 10, 0.35% with this band; docs/results.md, "Impinging
        jet"). The bands are taken where detect() found the particles (fields outflow_band, inflow_band), so
        that the unknowns stay those of the call's start. IIPS measures its Linf(grad C) (threshold, stall,
        divergence) over these; the history's L2/Linf(grad C) over interior()."""
        unknowns = self.interior(system)
        for band in (BAND, INFLOW_BAND):
            if band.name in system.particles:
                unknowns &= system.particles.owned(band.name) == 0
        return unknowns

    def count(self, system) -> int:
        """Surface particles on all ranks (collective)."""
        return int(allreduce_sum(system.comm, int(np.count_nonzero(system.particles.owned("free_surface")
                                                                    == SURFACE))))

    def describe(self) -> str:
        s = self.spec
        return (f"free-surface detection (Marrone et al. 2010): lambda <= {s.lambda_surface:g} surface, "
                f"> {s.lambda_interior:g} interior, scan region between; explicit shifting du . n = 0 in the "
                f"region, du = 0 where lambda < {s.lambda_normal:g} (thesis eq. 6.29); IIPS fixes the "
                "surface particles and their neighbours, and the fluid within a kernel support of an outflow face"
                + (" or of an inflow buffer" if self.inflow else ""))


def make_free_surface(scene, pre_procedure=False):
    """FreeSurface where a fluid or static scene has a free surface and its shifting method moves the particles
    (or, with pre_procedure, for the IIPS pre-procedure, whatever the method: Scene.shifts_free_surface);
    NoFreeSurface elsewhere."""
    if scene.shifts_free_surface(pre_procedure):
        return FreeSurface(scene.free_surface, inflow=bool(scene.inflow))
    return NoFreeSurface()
