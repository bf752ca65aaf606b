"""The filament lattice of the film: a spatially periodic unit cell of 3 thick and 6 thin filaments.

Across the fibre the thick (myosin) filaments sit on a hexagonal lattice of
spacing ``a`` (``a = 2 d10 / sqrt(3)``), each ringed by six thin (actin)
filaments at the trigonal points, two thin per thick.  The paper's unit cell
holds 3 thick and 6 thin filaments: the sqrt(3) x sqrt(3) supercell, spanned by

    B1 = a (3/2, sqrt(3)/2),   B2 = a (0, sqrt(3)),

the smallest cell that can hold a "superlattice" like the frog's (Luther and
Squire 1980), in which neighbouring thick filaments differ in rotation; by
default one thick filament of the three is turned 60 degrees about its axis
relative to the other two (``thick_turn``).  The
cell is stored in the orthorhombic fundamental domain
``[0, 3a/2) x [0, sqrt(3) a) x [0, L)``: leaving it through ``x = 3a/2``
re-enters at ``x = 0`` shifted by ``-sqrt(3) a / 2`` in y.  Two copies of the
cell (the second shifted by B1) fill the orthorhombic box
``(3a, sqrt(3) a, L)`` (:attr:`Lattice.box`), which is what a periodic mesh
needs.

Along the fibre: F-actin has 13 subunits in 6 left-handed turns of the genetic
helix, 2.75 nm rise, so 13 subunits (35.75 nm) make one crossover and the
twist is exactly -360 * 6 / 13 = -166.15 degrees (the -166.6 degrees often
quoted is not periodic with 13/6; the cell needs exact periodicity).  The thick
filament has crowns every 14.3 nm, three pairs of heads per crown (120 degrees
apart) and 40 degrees between crowns.  6 crossovers (214.5 nm) equal 5 myosin
repeats of 42.9 nm, so ``L = 214.5`` nm is periodic for both: 78 subunits per
thin filament, 15 crowns per thick filament, 270 heads per cell.

Units are nanometres and radians.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (unit cell
   of 6 actin and 3 myosin filaments).
.. [2] J. M. Squire, "The Structural Basis of Muscular Contraction", Plenum
   1981 (14.3 nm crowns, 42.9 nm repeat, 3 pairs of heads per crown).
.. [3] P. K. Luther and J. M. Squire, "Three-dimensional structure of the
   vertebrate muscle A-band II. The myosin filament superlattice", J. Mol.
   Biol. 141, 409-439 (1980).
.. [4] B. M. Millman, "The filament lattice of striated muscle", Physiol.
   Rev. 78, 359-391 (1998) (d10 about 37 nm in relaxed frog muscle).
.. [5] K. C. Holmes, D. Popp, W. Gebhard and W. Kabsch, "Atomic model of the
   actin filament", Nature 347, 44-49 (1990) (13/6 helix, 2.75 nm rise).
"""

from dataclasses import dataclass

import numpy as np

from ..errors import DataError

D10 = 37.0
"""Lattice plane spacing d10, nm (relaxed frog sartorius)."""

ACTIN_RISE = 2.75
ACTIN_PER_CROSSOVER = 13
ACTIN_TURNS = 6
ACTIN_TWIST = -2 * np.pi * ACTIN_TURNS / ACTIN_PER_CROSSOVER
"""Radians per subunit (-166.15 degrees): exactly 6 left-handed turns per 13 subunits."""

CROWN_RISE = 14.3
CROWN_TWIST = np.deg2rad(40.0)
HEADS_PER_CROWN = 3
"""Myosin molecules (pairs of heads) per crown."""

CELL_LENGTH = 6 * ACTIN_PER_CROSSOVER * ACTIN_RISE
"""214.5 nm: 6 actin crossovers = 5 myosin repeats of 3 crowns."""

THIN_RADIUS = 4.5
"""Collision radius of a thin filament (F-actin is about 9-10 nm across)."""

THICK_RADIUS = 7.0
"""Backbone radius of a thick filament (about 14 nm across)."""

PIVOT_RADIUS = 9.0
"""Radius of the head-S2 junction (where each head's hinge sits) on the thick filament."""

HEAD_SPLAY = np.deg2rad(35.0)
"""Azimuthal splay of the two heads of one myosin molecule from their pair's direction."""

SUPERLATTICE_TURNS = (0.0, np.pi / 3, np.pi / 3)
"""Thick-filament azimuths in the cell: one filament turned 60 degrees from the other two (a choice, see above)."""


@dataclass(frozen=True)
class Lattice:
    """The periodic unit cell.

    Attributes
    ----------
    spacing : float
        Thick-thick distance ``a`` (nm).
    length : float
        Cell length along the fibre (z), nm.
    thick_xy : (3, 2) array
        Thick filament axes.
    thick_turn : (3,) array
        Azimuth of each thick filament's first crown, radians.
    thick_z0 : (3,) array
        Height of each thick filament's first crown.
    thin_xy : (6, 2) array
        Thin filament axes.
    thin_turn : (6,) array
        Azimuth of each thin filament's first subunit, radians.
    thin_z0 : (6,) array
        Height of each thin filament's first subunit.
    """

    spacing: float
    length: float
    thick_xy: np.ndarray
    thick_turn: np.ndarray
    thick_z0: np.ndarray
    thin_xy: np.ndarray
    thin_turn: np.ndarray
    thin_z0: np.ndarray

    @property
    def domain(self):
        """(3,) size of the orthorhombic fundamental domain ``(3a/2, sqrt(3) a, L)``."""
        a = self.spacing
        return np.array([1.5 * a, np.sqrt(3) * a, self.length])

    @property
    def box(self):
        """(3,) orthorhombic box ``(3a, sqrt(3) a, L)`` holding two copies of the cell."""
        a = self.spacing
        return np.array([3 * a, np.sqrt(3) * a, self.length])

    @property
    def shift(self):
        """(3,) the cell vector B1 that maps the cell onto its second copy in :attr:`box`."""
        a = self.spacing
        return np.array([1.5 * a, np.sqrt(3) / 2 * a, 0.0])

    @property
    def subunits_per_filament(self):
        return int(round(self.length / ACTIN_RISE))

    @property
    def crowns_per_filament(self):
        return int(round(self.length / CROWN_RISE))

    def wrap(self, points):
        """Points (..., 3) mapped into the fundamental domain (periodic images are identified)."""
        p = np.array(points, dtype=np.float64)
        box, d, b1 = self.box, self.domain, self.shift
        p = p - np.floor(p / box) * box
        upper = p[..., 0] >= d[0]
        p[upper] -= b1
        p = p - np.floor(p / box) * box
        p = np.where(p >= box, p - box, p)  # floor rounding at the top edge
        return p

    def min_image(self, delta):
        """The shortest periodic image of displacements ``delta`` (..., 3)."""
        d = np.asarray(delta, dtype=np.float64)
        box = self.box
        a = d - np.round(d / box) * box
        b = d - self.shift
        b = b - np.round(b / box) * box
        return np.where((np.einsum("...i,...i->...", a, a) <= np.einsum("...i,...i->...", b, b))[..., None], a, b)

    def to_box(self, points):
        """Points of the cell and their copies shifted by B1, all wrapped into :attr:`box`: (2n, 3)."""
        p = self.wrap(points).reshape(-1, 3)
        q = p + self.shift
        q = q - np.floor(q / self.box) * self.box
        return np.concatenate([p, q])


def unit_cell(d10=D10, length=CELL_LENGTH, thick_turn=SUPERLATTICE_TURNS, thin_turn=None, thin_z0=None):
    """The 3-thick, 6-thin unit cell.

    Parameters
    ----------
    d10 : float
        Lattice plane spacing, nm; the thick-thick distance is ``2 d10 / sqrt(3)``.
    length : float
        Cell length along the fibre; must hold whole actin crossovers and whole
        myosin repeats (a multiple of 214.5 nm).
    thick_turn : 3 floats
        Azimuth of each thick filament (radians).
    thin_turn, thin_z0 : 6 floats, optional
        Azimuth and height of each thin filament's first subunit (default: spread
        so that neighbouring filaments are not in register).

    Returns
    -------
    Lattice
    """
    # The thick-thin distance is a / sqrt(3) = 2 d10 / 3.
    if not (np.isfinite(d10) and 2 * d10 / 3 > THICK_RADIUS + THIN_RADIUS):
        raise DataError(f"d10 = {d10} nm leaves no room between filaments", field="d10")
    reps = length / CELL_LENGTH
    if not (np.isfinite(reps) and reps >= 1 and abs(reps - round(reps)) < 1e-9):
        raise DataError(f"must be a positive multiple of {CELL_LENGTH} nm, got {length}", field="length")
    a = 2 * d10 / np.sqrt(3)
    a1, a2 = np.array([a, 0.0]), np.array([a / 2, a * np.sqrt(3) / 2])
    dom = np.array([1.5 * a, np.sqrt(3) * a])
    ij = np.stack(np.meshgrid(np.arange(-3, 4), np.arange(-3, 4), indexing="ij"), -1).reshape(-1, 2)
    base = ij @ np.stack([a1, a2])

    def inside(p):
        eps = 1e-9 * a
        return p[np.all((p > -eps) & (p < dom - eps), axis=1)]

    thick = inside(base)
    tri = (a1 + a2) / 3
    thin = inside(np.concatenate([base + tri, base + 2 * tri]))
    thick = thick[np.lexsort((thick[:, 0], thick[:, 1]))]
    thin = thin[np.lexsort((thin[:, 0], thin[:, 1]))]
    assert len(thick) == 3 and len(thin) == 6, (len(thick), len(thin))
    thick_turn = np.asarray(thick_turn, np.float64).reshape(3)
    # Default thin phases: azimuths and axial offsets spread over one subunit step.
    thin_turn = (np.arange(6) * 2 * np.pi / 6 * 0.37 if thin_turn is None
                 else np.asarray(thin_turn, np.float64).reshape(6))
    thin_z0 = np.arange(6) * ACTIN_RISE / 6 if thin_z0 is None else np.asarray(thin_z0, np.float64).reshape(6)
    return Lattice(a, float(length), thick, thick_turn, np.zeros(3), thin, thin_turn, thin_z0)


def rot_z(phi):
    """Rotations (..., 3, 3) by ``phi`` radians about z."""
    c, s = np.cos(phi), np.sin(phi)
    r = np.zeros(np.shape(phi) + (3, 3))
    r[..., 0, 0], r[..., 0, 1], r[..., 1, 0], r[..., 1, 1], r[..., 2, 2] = c, -s, s, c, 1.0
    return r


@dataclass
class Subunits:
    """Actin subunit frames: subunit ``k`` is the model turned by ``rotations[k]`` and moved to ``centers[k]``."""

    rotations: np.ndarray  # (m, 3, 3)
    origins: np.ndarray  # (m, 3): the point on the filament axis at the subunit's height
    filament: np.ndarray  # (m,) thin filament index
    index: np.ndarray  # (m,) subunit index along the filament


def actin_subunits(lattice, slide=None):
    """Frames of every actin subunit in the cell (78 per thin filament at the default length).

    Parameters
    ----------
    lattice : Lattice
    slide : (6,) floats, optional
        Axial displacement of each thin filament (filament sliding), nm.

    Returns
    -------
    Subunits
        Heights wrapped into ``[0, L)``.
    """
    slide = np.zeros(6) if slide is None else np.asarray(slide, np.float64).reshape(6)
    n = lattice.subunits_per_filament
    j = np.arange(n)
    f = np.repeat(np.arange(6), n)
    jj = np.tile(j, 6)
    phi = lattice.thin_turn[f] + jj * ACTIN_TWIST
    z = np.mod(lattice.thin_z0[f] + jj * ACTIN_RISE + slide[f], lattice.length)
    origins = np.column_stack([lattice.thin_xy[f], z])
    return Subunits(rot_z(phi), origins, f, jj)


@dataclass
class Heads:
    """Myosin heads of the cell, each hinged at a pivot on its thick filament."""

    pivots: np.ndarray  # (n, 3) hinge points
    rest: np.ndarray  # (n, 3) unit directions of the relaxed heads (radially out, splayed)
    radial: np.ndarray  # (n, 3) unit radial direction of the molecule
    thick: np.ndarray  # (n,) thick filament index
    crown: np.ndarray  # (n,) crown index
    molecule: np.ndarray  # (n,) myosin molecule index; its two heads share it
    s2_start: np.ndarray  # (n, 3) where the molecule's tail (S2) leaves the backbone

    def __len__(self):
        return len(self.pivots)


def myosin_heads(lattice):
    """Pivot points and rest directions of all heads (2 per molecule, 3 molecules per crown).

    Returns
    -------
    Heads
        Ordered thick filament, crown, molecule, head; 270 heads at the default length.
    """
    nc = lattice.crowns_per_filament
    t, c, m, h = (x.reshape(-1) for x in np.meshgrid(np.arange(3), np.arange(nc), np.arange(HEADS_PER_CROWN),
                                                      np.arange(2), indexing="ij"))
    az = lattice.thick_turn[t] + c * CROWN_TWIST + m * 2 * np.pi / HEADS_PER_CROWN
    radial = np.column_stack([np.cos(az), np.sin(az), np.zeros_like(az)])
    z = np.mod(lattice.thick_z0[t] + c * CROWN_RISE, lattice.length)
    axis = np.column_stack([lattice.thick_xy[t], z])
    pivots = axis + PIVOT_RADIUS * radial
    s2 = axis + THICK_RADIUS * radial - np.array([0, 0, 4.0])  # S2 leans along the backbone
    head_az = az + np.where(h == 0, -HEAD_SPLAY, HEAD_SPLAY)
    rest = np.column_stack([np.cos(head_az), np.sin(head_az), np.zeros_like(az)])
    molecule = (t * nc + c) * HEADS_PER_CROWN + m
    return Heads(pivots, rest, radial, t, c, molecule, s2)
