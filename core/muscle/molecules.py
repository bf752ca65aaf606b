"""The film's molecules as sums of Gaussian ellipsoids (nanometres).

* Actin subunit: ellipsoids fitted to the atoms of the skeletal-muscle
  alpha-actin subunit (``molecules/mol1.pqr``, 5,877 atoms, from the APBS
  actin-dimer example).  The target is the atoms' own Gaussian molecular
  surface: every atom a Gaussian of weight ``exp(B)`` and sigma
  ``r / sqrt(2 B)`` (``r`` its radius, blobbiness ``B`` = 2.3), contoured at
  :data:`LEVEL` = 1, so a lone atom's surface is its van der Waals sphere.
  The fit: k-means clusters of atoms (or the four subdomains), one ellipsoid
  per cluster from its moments, then a least-squares fit of all ellipsoid
  parameters to the surface.  The PQR frame is the filament frame: the
  dimer in ``complex.pqr`` is this subunit and its neighbour 2.75 nm up the
  z axis, turned by -166.2 degrees about it, so z is the filament axis and
  the subunit's centre of mass lies 1.70 nm from it.
* Myosin head (S1): motor domain and lever arm (the "neck", the
  light-chain-binding domain) shaped from the chicken skeletal S1 crystal
  structure's published dimensions, 16.5 x 6.5 x 4.0 nm overall, lever about
  8.5 nm (Rayment et al. 1993).
* Myosin tails (S2): cylinders of radius 1 nm (the 2 nm alpha-helical coiled
  coil).

Every model uses the same contour value :data:`LEVEL`, so molecules summed
into one field (a head bound to actin) blend into one surface.

References
----------
.. [1] N. Max and R. Crawfis, "Advances in Scientific Visualization" (muscle
   molecules as contour surfaces of sums of ellipsoidal densities).
.. [2] J. F. Blinn, "A generalization of algebraic surface drawing", ACM TOG
   1(3), 235-256 (1982).
.. [3] J. A. Grant and B. T. Pickup, "A Gaussian description of molecular
   shape", J. Phys. Chem. 99, 3503-3510 (1995).
.. [4] W. Kabsch, H. G. Mannherz, D. Suck, E. F. Pai and K. C. Holmes,
   "Atomic structure of the actin:DNase I complex", Nature 347, 37-44 (1990)
   (subdomains 1-4 by residue).
.. [5] I. Rayment et al., "Three-dimensional structure of myosin
   subfragment-1: a molecular motor", Science 261, 50-58 (1993).
.. [6] S. Lowey, H. S. Slayter, A. G. Weeds and H. Baker, "Substructure of
   the myosin molecule", J. Mol. Biol. 42, 1-29 (1969) (2 nm rod).
"""

import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import DataError
from ..surface.mesh import Mesh
from .blobby import blobby_field, blobby_surface

LEVEL = 1.0
"""Contour value of every molecule model."""

BLOBBINESS = 2.3
"""Atom Gaussians ``exp(B (1 - d^2 / r^2))`` (Grant and Pickup's form)."""

ACTIN_RISE = 2.75
ACTIN_TWIST = -166.6
"""F-actin: nm and degrees per subunit along the genetic helix (13 subunits in 6 turns)."""

SUBDOMAINS = {1: ((1, 32), (70, 144), (338, 375)), 2: ((33, 69),), 3: ((145, 180), (270, 337)), 4: ((181, 269),)}
"""Actin subdomains by residue (Kabsch et al. 1990)."""

S1_LENGTH, S1_WIDTH, S1_DEPTH = 16.5, 6.5, 4.0
"""Myosin S1 overall dimensions, nm (Rayment et al. 1993)."""

LEVER_LENGTH = 8.5
"""Light-chain-binding domain (lever arm, "neck"), nm."""

HEAD_WEIGHT = 4.0
"""Peak of each head ellipsoid (in units of LEVEL): sharp enough that the parts blend
only near their joins, so the outline keeps the published dimensions."""

S2_RADIUS = 1.0
"""Myosin tail (S2 coiled coil) radius, nm."""

RESOURCE = Path(__file__).resolve().parent.parent / "resources" / "actin_ellipsoids.npz"


@dataclass
class Ellipsoids:
    """Gaussian ellipsoids (the arguments of :func:`~.blobby.blobby_surface`) with a part id each."""

    centers: np.ndarray  # (n, 3) nm
    rotations: np.ndarray  # (n, 3, 3) columns: principal axes
    sigmas: np.ndarray  # (n, 3) nm
    weights: np.ndarray  # (n,)
    part: np.ndarray = field(default=None)  # (n,) int

    def __post_init__(self):
        self.centers = np.asarray(self.centers, np.float64).reshape(-1, 3)
        n = len(self.centers)
        self.rotations = np.asarray(self.rotations, np.float64).reshape(n, 3, 3)
        self.sigmas = np.asarray(self.sigmas, np.float64).reshape(n, 3)
        self.weights = np.asarray(self.weights, np.float64).reshape(n)
        self.part = np.zeros(n, np.int32) if self.part is None else np.asarray(self.part, np.int32).reshape(n)

    def __len__(self):
        return len(self.centers)

    @property
    def args(self):
        """``(centers, rotations, sigmas, weights)`` for :func:`~.blobby.blobby_surface`."""
        return self.centers, self.rotations, self.sigmas, self.weights

    def moved(self, rotation, translation):
        """The ellipsoids turned by ``rotation`` (3, 3) about the origin, then shifted."""
        rot = np.asarray(rotation, np.float64)
        return Ellipsoids(self.centers @ rot.T + translation, rot @ self.rotations, self.sigmas, self.weights,
                          self.part)

    @staticmethod
    def concat(items):
        items = list(items)
        if not items:
            return Ellipsoids(np.zeros((0, 3)), np.zeros((0, 3, 3)), np.zeros((0, 3)), np.zeros(0))
        return Ellipsoids(*(np.concatenate([getattr(e, k) for e in items])
                            for k in ("centers", "rotations", "sigmas", "weights", "part")))

    def surface(self, spacing, **kw):
        """The blobby surface at :data:`LEVEL` (attribute ``"part"`` per vertex)."""
        return blobby_surface(*self.args, LEVEL, spacing, attributes={"part": self.part}, **kw)


@dataclass
class Atoms:
    """Atoms of a PQR file, nanometres."""

    xyz: np.ndarray  # (n, 3)
    radius: np.ndarray  # (n,)
    residue: np.ndarray  # (n,) residue number
    resname: np.ndarray  # (n,) str


def read_pqr(path):
    """Atoms of a PQR file (columns x y z charge radius after the residue number), in nm.

    Raises
    ------
    DataError
        Naming the file and line when a record cannot be read.
    """
    path = Path(path)
    xyz, rad, res, names = [], [], [], []
    try:
        text = path.read_bytes().decode("latin-1")  # any byte reads; a damaged record then fails on its line
    except OSError as err:
        raise DataError(f"cannot read: {err.strerror}", path=str(path)) from None
    for no, line in enumerate(text.splitlines(), 1):
        if not line.startswith(("ATOM", "HETATM")):
            continue
        cols = line[30:].split()
        try:
            x, y, z, _q, r = (float(v) for v in cols[:5])
            res.append(int(line[22:26]))
        except (ValueError, IndexError):
            raise DataError(f"line {no}: needs x y z charge radius", path=str(path)) from None
        if not (np.isfinite([x, y, z, r]).all() and r > 0):
            raise DataError(f"line {no}: bad coordinates or radius", path=str(path))
        xyz.append((x, y, z))
        rad.append(r)
        names.append(line[17:20].strip())
    if not xyz:
        raise DataError("no ATOM records", path=str(path))
    return Atoms(np.array(xyz) / 10, np.array(rad) / 10, np.array(res), np.array(names))


def atom_gaussians(atoms, blobbiness=BLOBBINESS):
    """The atoms' Gaussian molecular density: ``exp(B (1 - d^2 / r^2))`` per atom, surface at :data:`LEVEL`."""
    n = len(atoms.xyz)
    sig = atoms.radius / np.sqrt(2 * blobbiness)
    return Ellipsoids(atoms.xyz, np.repeat(np.eye(3)[None], n, 0), np.repeat(sig[:, None], 3, 1),
                      np.full(n, np.exp(blobbiness)))


def subdomain_of(atoms):
    """Actin subdomain (1-4) of every atom; ligands (ADP, Ca) join the nearest protein atom's."""
    sd = np.zeros(len(atoms.xyz), np.int32)
    protein = ~np.isin(atoms.resname, ("ADP", "ATP", "CA", "MG"))
    for k, spans in SUBDOMAINS.items():
        for lo, hi in spans:
            sd[protein & (atoms.residue >= lo) & (atoms.residue <= hi)] = k
    rest = np.flatnonzero(sd == 0)
    if len(rest):
        from scipy.spatial import cKDTree

        known = np.flatnonzero(sd > 0)
        sd[rest] = sd[known[cKDTree(atoms.xyz[known]).query(atoms.xyz[rest])[1]]]
    return sd


def _moments(xyz, mass, var):
    """One Gaussian with the mass, centre and covariance of a cluster of atom Gaussians."""
    m = mass.sum()
    c = (mass[:, None] * xyz).sum(0) / m
    d = xyz - c
    cov = (mass[:, None, None] * d[:, :, None] * d[:, None, :]).sum(0) / m + np.eye(3) * (mass * var).sum() / m
    ev, vec = np.linalg.eigh(cov)
    if np.linalg.det(vec) < 0:
        vec[:, 0] *= -1
    sig = np.sqrt(ev)
    return c, vec, sig, m / ((2 * np.pi) ** 1.5 * sig.prod())


def _rotvec(v):
    """Rotation matrices from rotation vectors (..., 3) (Rodrigues)."""
    th = np.linalg.norm(v, axis=-1)[..., None, None]
    k = v / np.maximum(th[..., 0], 1e-12)
    K = np.zeros(v.shape[:-1] + (3, 3))
    K[..., 0, 1], K[..., 0, 2], K[..., 1, 2] = -k[..., 2], k[..., 1], -k[..., 0]
    K = K - np.swapaxes(K, -1, -2)
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


@dataclass
class FitResult:
    """Fitted ellipsoids and their surface's distance to the atoms' surface (nm)."""

    ellipsoids: Ellipsoids
    rms: float  # symmetric RMS distance between the two surfaces
    max: float  # symmetric maximum (Hausdorff) distance
    spacing: float  # mesh spacing of the comparison


def surface_distance(a, b):
    """Symmetric RMS and maximum distance between two meshes, from each vertex to the
    nearest point of the other mesh's vertices and triangle centroids (an upper bound on
    the true distance by under half a triangle)."""
    from scipy.spatial import cKDTree

    def samples(m):
        return np.concatenate([m.vertices, m.vertices[m.faces].mean(axis=1)]).astype(np.float64)

    d_ab = cKDTree(samples(b)).query(a.vertices.astype(np.float64))[0]
    d_ba = cKDTree(samples(a)).query(b.vertices.astype(np.float64))[0]
    d = np.concatenate([d_ab, d_ba])
    return float(np.sqrt(np.mean(d * d))), float(d.max())


def fit_ellipsoids(atoms, k, *, groups=None, spacing=0.05, sample=1000, band=0.3, seed=0, target=None, max_nfev=30):
    """Fit ``k`` Gaussian ellipsoids to the atoms' Gaussian molecular surface.

    Parameters
    ----------
    atoms : Atoms
    k : int
        Number of ellipsoids (ignored when ``groups`` is given).
    groups : (n,) ints, optional
        A cluster label per atom (e.g. :func:`subdomain_of`); default k-means.
    spacing : float
        Mesh spacing (nm) of the atoms' surface and of the comparison.
    sample : int
        Surface points the least-squares fit uses (and as many on each side of
        the surface at ``band`` nm, so that no lobe grows away from it).
    seed : int
        k-means seed.
    target : Mesh, optional
        The atoms' surface, if already meshed at ``spacing``.
    max_nfev : int
        Least-squares iterations (each costs 10 k + 1 field evaluations).

    Returns
    -------
    FitResult

    References
    ----------
    .. [1] J. A. Grant and B. T. Pickup, J. Phys. Chem. 99, 3503 (1995).
    """
    from scipy.cluster.vq import kmeans2
    from scipy.optimize import least_squares

    dens = atom_gaussians(atoms)
    if target is None:
        target = dens.surface(spacing)
    var = dens.sigmas[:, 0] ** 2
    mass = dens.weights * dens.sigmas[:, 0] ** 3
    if groups is None:
        k = int(k)
        if k < 1:
            raise DataError(f"needs at least one ellipsoid, got {k}", field="k")
        if k == 1:
            groups = np.zeros(len(mass), np.int64)
        else:
            _, groups = kmeans2(atoms.xyz, k, seed=np.random.default_rng(seed), minit="++")
    labels = np.unique(groups)
    init = [_moments(atoms.xyz[groups == g], mass[groups == g], var[groups == g]) for g in labels]
    c0 = np.array([m[0] for m in init])
    r0 = np.array([m[1] for m in init])
    p0 = np.concatenate([c0, np.zeros_like(c0), np.log([m[2] for m in init]), np.log([[m[3]] for m in init])], axis=1)

    rng = np.random.default_rng(seed)
    pick = rng.choice(len(target.vertices), min(sample, len(target.vertices)), replace=False)
    p = target.vertices[pick].astype(np.float64)
    nrm = target.normals[pick].astype(np.float64)
    pts = np.concatenate([p, p + band * nrm, p - band * nrm])
    want = np.concatenate([np.zeros(len(p)), np.full(len(p), band), np.full(len(p), -band)])
    m = len(labels)

    def unpack(x):
        x = x.reshape(m, 10)
        return x[:, :3], _rotvec(x[:, 3:6]) @ r0, np.exp(x[:, 6:9]), np.exp(x[:, 9])

    def resid(x):
        f, g = blobby_field(pts, *unpack(x), gradient=True)
        # Signed distance outward, to first order in ln f (exact for a lone Gaussian's radius).
        lg = np.log(np.maximum(f, 1e-300)) - np.log(LEVEL)
        return -lg * f / np.maximum(np.linalg.norm(g, axis=1), 1e-300) - want

    # Bounds keep every ellipsoid a compact piece of the subunit (peak >= 1.5 level, sigma <= 3 nm):
    # no broad faint background that would leak into the neighbours' field.
    lo = np.concatenate([c0 - 2.0, np.full((m, 3), -np.pi), np.full((m, 3), np.log(0.2)),
                         np.full((m, 1), np.log(1.5 * LEVEL))], 1)
    hi = np.concatenate([c0 + 2.0, np.full((m, 3), np.pi), np.full((m, 3), np.log(3.0)),
                         np.full((m, 1), np.log(8 * LEVEL))], 1)
    x0 = np.clip(p0, lo + 1e-9, hi - 1e-9).reshape(-1)
    sol = least_squares(resid, x0, bounds=(lo.reshape(-1), hi.reshape(-1)), loss="soft_l1", f_scale=0.2,
                        x_scale=0.1, max_nfev=max_nfev)
    fitted = Ellipsoids(*unpack(sol.x), part=labels)
    rms, mx = surface_distance(fitted.surface(spacing), target)
    return FitResult(fitted, rms, mx, spacing)


def write_actin_resource(pqr, out=RESOURCE):
    """Fit 4 ellipsoids (the subdomains) to the actin subunit and write them as ``.npz``."""
    atoms = read_pqr(pqr)
    res = fit_ellipsoids(atoms, 4, groups=subdomain_of(atoms))
    e = res.ellipsoids
    out = Path(out)
    tmp = out.with_name(out.name + ".tmp.npz")
    np.savez_compressed(tmp, centers=e.centers, rotations=e.rotations, sigmas=e.sigmas, weights=e.weights,
                        part=e.part, rms=res.rms, max=res.max)
    tmp.replace(out)
    return res


def actin_subunit(path=RESOURCE):
    """The actin subunit, four ellipsoids (part = subdomain 1-4), in the filament frame.

    z is the filament axis (through the origin); subunit ``j`` of a filament is
    this one turned by ``j * ACTIN_TWIST`` degrees about z and raised by
    ``j * ACTIN_RISE`` nm.
    """
    try:
        with np.load(path, allow_pickle=False) as z:
            return Ellipsoids(z["centers"], z["rotations"], z["sigmas"], z["weights"], z["part"])
    except (OSError, KeyError, ValueError) as err:
        raise DataError(f"cannot read the actin ellipsoids: {err}", path=str(path)) from None


def _axis_ellipsoid(a, b, sigma_xyz, weight, up=(0, 0, 1)):
    """An ellipsoid from point a to point b: long axis along b - a, third axis near ``up``."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    x = (b - a) / np.linalg.norm(b - a)
    z = np.asarray(up, float) - np.dot(up, x) * x
    z /= np.linalg.norm(z)
    rot = np.stack([x, np.cross(z, x), z], axis=1)
    return (a + b) / 2, rot, np.asarray(sigma_xyz, float), float(weight)


def _radius_sigma(semi, weight=HEAD_WEIGHT):
    """Sigma whose lone Gaussian of ``weight`` has semi-axis ``semi`` at :data:`LEVEL`."""
    return np.asarray(semi, float) / np.sqrt(2 * np.log(weight / LEVEL))


MOTOR, LEVER = 1, 2
"""Part ids of the myosin head models."""


def lever_arm():
    """Lever arm ("neck": heavy-chain helix with essential and regulatory light chains).

    Frame: the head-rod junction (where S2 starts) at the origin, the lever along +x
    to the converter at (LEVER_LENGTH, 0, 0); the light chains on its +y side.
    """
    L = LEVER_LENGTH
    parts = [
        # heavy-chain helix
        _axis_ellipsoid((0.5, 0, 0), (L, 0, 0), _radius_sigma(((L - 0.5) / 2 + 0.3, 0.6, 0.6)), HEAD_WEIGHT),
        # RLC
        _axis_ellipsoid((0.8, 0.6, 0), (0.8 + 0.45 * L, 0.9, 0), _radius_sigma((0.25 * L, 1.35, 1.1)), HEAD_WEIGHT),
        # ELC
        _axis_ellipsoid((0.5 * L, 0.9, 0), (0.96 * L, 0.7, 0), _radius_sigma((0.27 * L, 1.45, 1.15)), HEAD_WEIGHT),
    ]
    return Ellipsoids(*map(np.array, zip(*parts)), part=np.full(3, LEVER))


def motor_domain():
    """Motor domain (N-terminal subdomain, upper and lower 50K with the actin-binding
    cleft at the tip, converter), in the lever's frame: it starts at the converter
    (LEVER_LENGTH, 0, 0) and reaches along +x to the actin-binding tip, so the whole
    S1 spans S1_LENGTH in x, S1_WIDTH in y and S1_DEPTH in z.
    """
    L, M = LEVER_LENGTH, S1_LENGTH - LEVER_LENGTH
    w, d = S1_WIDTH, S1_DEPTH
    parts = [
        # converter
        _axis_ellipsoid((L - 0.3, -0.2, 0), (L + 2.0, 0.4, 0), _radius_sigma((1.6, 1.6, 1.4)), HEAD_WEIGHT),
        _axis_ellipsoid((L + 0.8, 0.6, 0), (L + 0.55 * M, 1.4, 0), _radius_sigma((0.32 * M, 1.9, d / 2 - 0.25)),
                        HEAD_WEIGHT),  # N-terminal
        _axis_ellipsoid((L + 0.35 * M, 1.8, 0), (S1_LENGTH - 0.5, 1.1, 0),
                        _radius_sigma((0.36 * M, w / 2 - 1.6, d / 2 - 0.25)), HEAD_WEIGHT),  # upper 50K
        _axis_ellipsoid((L + 0.3 * M, -0.9, 0), (S1_LENGTH - 0.8, -1.9, 0),
                        _radius_sigma((0.34 * M, 1.5, d / 2 - 0.45)), HEAD_WEIGHT),  # lower 50K
    ]
    return Ellipsoids(*map(np.array, zip(*parts)), part=np.full(4, MOTOR))


def myosin_head():
    """Motor domain and lever arm in one frame (the lever's): the S1 at rest."""
    return Ellipsoids.concat([lever_arm(), motor_domain()])


@dataclass
class Cylinders:
    """Capped cylinders from ``starts`` to ``ends`` (nm)."""

    starts: np.ndarray  # (n, 3)
    ends: np.ndarray  # (n, 3)
    radii: np.ndarray  # (n,)
    part: np.ndarray = field(default=None)

    def __post_init__(self):
        self.starts = np.asarray(self.starts, np.float64).reshape(-1, 3)
        n = len(self.starts)
        self.ends = np.asarray(self.ends, np.float64).reshape(n, 3)
        self.radii = np.broadcast_to(np.asarray(self.radii, np.float64), (n,)).copy()
        self.part = np.zeros(n, np.int32) if self.part is None else np.asarray(self.part, np.int32).reshape(n)
        if n and not (np.all(self.radii > 0) and np.all(np.linalg.norm(self.ends - self.starts, axis=1) > 0)):
            raise DataError("cylinders need positive radii and lengths", field="cylinders")


def cylinder_mesh(cyl, segments=16):
    """Closed triangle mesh of capped cylinders (``segments`` around), attribute ``"part"``."""
    n = len(cyl.starts)
    if n == 0:
        return Mesh.empty(["part"])
    s = int(segments)
    ax = cyl.ends - cyl.starts
    length = np.linalg.norm(ax, axis=1)
    x = ax / length[:, None]
    ref = np.where(np.abs(x[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(x, ref)
    u /= np.linalg.norm(u, axis=1)[:, None]
    v = np.cross(x, u)
    th = 2 * np.pi * np.arange(s) / s
    ring = np.cos(th)[None, :, None] * u[:, None] + np.sin(th)[None, :, None] * v[:, None]  # (n, s, 3)
    rr = cyl.radii[:, None, None] * ring
    # Per cylinder: side ring 0 (s), side ring 1 (s), cap 0 ring (s), cap 1 ring (s), two centres.
    verts = np.concatenate([cyl.starts[:, None] + rr, cyl.ends[:, None] + rr, cyl.starts[:, None] + rr,
                            cyl.ends[:, None] + rr, cyl.starts[:, None], cyl.ends[:, None]], axis=1)
    norms = np.concatenate([ring, ring, np.repeat(-x[:, None], s, 1), np.repeat(x[:, None], s, 1), -x[:, None],
                            x[:, None]], axis=1)
    i = np.arange(s)
    j = (i + 1) % s
    side = np.concatenate([np.stack([i, j, s + j], 1), np.stack([i, s + j, s + i], 1)])
    cap0 = np.stack([np.full(s, 4 * s), 2 * s + j, 2 * s + i], 1)
    cap1 = np.stack([np.full(s, 4 * s + 1), 3 * s + i, 3 * s + j], 1)
    local = np.concatenate([side, cap0, cap1])
    nv = 4 * s + 2
    faces = (local[None] + (np.arange(n) * nv)[:, None, None]).reshape(-1, 3)
    return Mesh(verts.reshape(-1, 3), faces, norms.reshape(-1, 3), {"part": np.repeat(cyl.part, nv)})


if __name__ == "__main__":
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: python -m nephele.core.muscle.molecules MOL1.pqr [OUT.npz]")
    r = write_actin_resource(*sys.argv[1:])
    print(f"actin: 4 ellipsoids, surface distance rms {r.rms:.3f} nm, max {r.max:.3f} nm")
