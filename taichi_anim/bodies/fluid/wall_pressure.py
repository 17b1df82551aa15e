"""The walls' pressure on the liquid: mirrored across the wall with its hydrostatic part (Adami, Hu &
Adams, "A generalized wall boundary condition for smoothed particle hydrodynamics", JCP 231, 2012,
eq. 27, for walls at rest; Band et al., "Pressure Boundaries for Implicit Incompressible SPH", ACM TOG
37(2), 2018, make the same repair of Akinci's boundary pressure for implicit solvers).

Akinci's walls (2012, eq. 10) push a particle off a sample with the particle's own pressure once: in the
symmetric force -m_i psi_b (p_i/rho_i^2 + p_b/rho_b^2) grad W_ib the sample's p_b is left out. A settled
column then carries its weight on the layer next to the floor at about twice the pressure the wall
should give, and the layers above swing about the hydrostatic line: +328, -255, +14 Pa at 0.5, 1.5 and
2.5 spacings above the floor of a column 16 particles wide (DFSPH, 2 cm spacing, 1,000 kg/m^3), its
pressure's slope 3.8 % steep.

Here a wall sample takes the pressure of the particle across it plus the hydrostatic difference between
them, p_b = p_i + rho_i g.(x_b - x_i), g the acceleration that acts on every particle (gravity: the
terms' body_acceleration). With kappa = p / rho^2 the pair pushes with

    -psi_b (kappa_i + kappa_b) grad W_ib = -psi_b (2 kappa_i - g.(x_i - x_b) / rho_i) grad W_ib:

the solves push with 2 kappa_i (`_push_sum`, their factor alpha_i matched to it, dfsph.py), and the
hydrostatic part, known at the step's start, is added to v* before the density solve (`_wall_push_one`):

    v*_i += h (1 / rho_i) sum_b psi_b g.(x_i - x_b) grad W_ib.

A liquid with bodies in it (rigid bodies, cloth, spheres: bodies.py) keeps Akinci's walls for now:
mirrored walls with Akinci's bodies blew up a heavy box sinking onto the floor (the particles squeezed
between were pushed into the box), and bodies pushing with 2 kappa_i, their impulses doubled, floated a
plank 7 % high (the liquid stood further off its surface). Measured: the column
16 wide's layers at 0.5, 1.5 and 2.5 spacings -82, -19 and -9 Pa from the fitted line; a column 24
wide, its pressure's slope over ten starts -0.46 to +0.86 % (averaged over 1-2.5 s; +3.2 to +3.7 %
before, over 0.7-1.2 s); the dam break's front 10-21 % ahead of the experiment at 12, 16 and 24
particles across (8-19 % before; tests/test_fluid_hydrostatic.py, test_fluid_dam_break.py). The
hydrostatic part pushes a particle in full from a spacing's head of pressure, ramped to none at none:
given to spray flying at a wall, it threw a pour's splash above the jet's energy height
(tests/test_fluid_sources.py). Adding the last step's
kappa_i explicitly instead of pushing with 2 kappa_i in the solves held the column as well but ran the
dam break's front 16-29 % ahead at 24 particles across, 10-21 % at 16; pushing with 2 kappa_i without
the hydrostatic part made the wall layer bounce off a settling column (docs/guide/fluids.md)."""

import taichi as ti

from ...runtime import data_oriented
from .sph_kernel import cubic_w_grad


@data_oriented
class WallPressure:
    """Mixin of FluidDynamics: the walls' samples in the neighbourhood pass, their mirrored push in the
    solves, and the hydrostatic part in v*."""

    mirrors_wall_pressure = True  # position-based fluids: False (their walls push with their own lambda)

    def _make_wall_pressure(self, f) -> None:
        """Per slot sum_b psi_b g.(x_k - x_b) grad W_kb and the solves' push sum; g (a field, written by
        _clear_counts: another g compiles nothing). A liquid with bodies in it keeps Akinci's walls
        (module docstring)."""
        self.mirrors_wall_pressure = type(self).mirrors_wall_pressure and not self.coupled
        self.body_g = f("fluid_body_g", dims=(3,), shape=())
        if self.mirrors_wall_pressure:
            self.wall_hydro = f("fluid_wall_hydro", dims=(3,))
            self.wall_push = f("fluid_wall_push", dims=(3,))

    @ti.func
    def _add_boundary(self, k, b, d, acc: ti.template()):
        """A wall sample's share of the density, of the gradient sums (acc.wg, with the bodies'; acc.ww,
        the walls' alone) and of the hydrostatic sum (acc.bg: g); d = x_k - x_b."""
        w, g = cubic_w_grad(d, self.support)
        psi = self.boundary_psi[b]
        acc.bn += 1
        acc.rho += psi * w
        acc.wg += psi * g
        acc.ww += psi * g
        acc.wh += (psi * d.dot(acc.bg)) * g

    @ti.func
    def _keep_wall_sums(self, k, acc: ti.template()):
        """Slot k's sums for the solves' push and the hydrostatic part; returns the push sum (alpha's)."""
        push = acc.wg
        if ti.static(self.mirrors_wall_pressure):
            push = acc.wg + acc.ww  # the walls' samples twice: the particle's pressure mirrored
            self.wall_push[k] = push
            self.wall_hydro[k] = acc.wh
        return push

    @ti.func
    def _push_sum(self, k):
        """The boundary samples' gradient sum the solves push slot k with, times its kappa."""
        out = self.wall_grad[k]
        if ti.static(self.mirrors_wall_pressure):
            out = self.wall_push[k]
        return out

    @ti.func
    def _wall_push_one(self, state: ti.template(), k, h):
        """Slot k's v* with the walls' hydrostatic push (module docstring), in full for a particle whose
        last pressure is at least a spacing's hydrostatic head, ramped down to none at no pressure: a
        spray particle flying at a wall has no column above it to hold (a ramp, not a cut, so that
        round-off cannot switch it)."""
        if ti.static(self.walls and self.mirrors_wall_pressure):
            rho = self.rho[k]
            head = self.rest_density * self.spacing * self.body_g[None].norm()
            if rho > 0.0 and head > 0.0:
                share = ti.min(state.fluid_pressure[self.grid.sorted_id[k]] / head, 1.0)
                self.sv[k] += (share * h / rho) * self.wall_hydro[k]
