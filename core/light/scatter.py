"""Multiple scattering in a cloud: the binned volume radiosity solve of Fig. 6.

Method
------
Each voxel keeps, for each of the ``nb = 6 n^2`` direction bins (:mod:`.phase`; ``n =
bins_per_face``, 4 by default: the paper's 96 bins, 6 gives 216), the
``received`` flux (power intercepted by its droplets), on request the ``total`` flux
passing through it, and the ``unshot`` scattered flux not yet propagated.

* The sun is a parallel beam swept through the grid first.  Its first
  scattering is *not* binned for rendering: at render time each voxel adds
  ``albedo * R_sun * p(sun . view) / V`` with the exact phase function, so the
  narrow forward lobe (silver lining) is sharp.  For further scattering the
  sun's received flux is distributed over the bins with exact integrals of the
  phase function about the true sun direction (:func:`.phase.direct_fractions`),
  on 4x4 sub-directions per bin.  That once-scattered flux, and the
  flux of the next three orders (``peaked_orders``), are still peaked inside their
  bins, so they are swept on weighted sub-directions, intercepted per sub-direction
  and scattered again from each sub-direction (:func:`.phase.sub_phase_matrix`)
  and, at render time, toward the viewer with the same weights.  In the second
  order the weakest bins, holding ``merge_tol`` (20%) of its power together, are
  swept on their four 2x2 quarters instead (each at its weighted mean direction,
  its catch shared out by the weights), from the third on all bins.  Not in the
  first: its weak bins are the back-scatter that a sunlit face shows (slab
  single-scattering R +0.57% -> +1.12%).
* Skylight (constant radiance from the upper hemisphere, or a radiance per bin from
  any direction: a rendered sky, :func:`.sky.panorama_radiance`) enters through the
  boundary as ``nb`` binned beams and is received like scattered flux.
* Shooting passes (Gauss-Seidel by groups of bins): all voxels shoot the unshot
  flux of a group of bins at once.  For each bin, 2x2 (``sub``) sub-directions
  carry the flux, each swept through the grid layer by layer along the
  dominant axis (a discrete-ordinates sweep): in each layer a beam loses
  ``1 - exp(-sigma l)`` (``l`` = path length across the layer) to ``received``,
  a voxel's own emission escapes its voxel with the exact mean transmission of its
  in-voxel profile (an exponential fitted to where the light was caught, plus, in
  optically thick voxels, a Legendre P2 term fitted to its second moment), and the
  beam moves sideways by its transverse
  offset with bilinear weights.  Sub-directions plus bilinear spreading spread
  a bin's flux over its solid angle, which reduces ray effects.  The received
  flux of the group is scattered at once by the nb x nb phase matrix into unshot,
  times the albedo.  Late passes (unshot under 10% of the entered power) shoot on one
  direction per bin: that light is smooth.  Passes repeat until the unshot power falls below
  ``tol`` times the power that entered the cloud, or ``max_passes``.  Late passes
  shrink geometrically (by ~0.71 per pass in the Fig. 6 cloud), so after each pass
  the tail of passes still to come is extrapolated from the last two (:class:`_Tail`)
  and the solve stops once that extrapolation is sure to ``tol``: 13 passes, not 20.

Cost: one pass shoots all N voxels in all nb bins with ``nb * sub^2`` sweeps of
O(N) work each, i.e. O(N) per pass for all O(N^2) voxel-to-voxel interactions
(Max 1994 amortises them to O(N log N)); the number of passes depends on the
optical thickness and albedo, not on N.  Memory: a few nb x N float arrays.
Only the box around the non-empty voxels is solved (sun and sky are uniform, so
empty space only translates beams), and each layer only on the rectangle around
its non-empty voxels.  A sweep moves whole planes of blocks of beams: transverse
shifts by plane slices, float32 ``exp``/``expm1``/``tanh`` (vectorised) and blends
instead of ``np.where``, blocks on threads (:mod:`..threads`).

Views: :func:`march_planes` (film speed) or :func:`render` (any step, the anchor).

Modules: this one is the public face; the work is in ``_escape`` (closed forms for sources
inside a voxel), ``_sweep`` (the sweeps), ``_passes`` (the passes' bookkeeping and tail),
``_solve`` (the solve's stages), ``_views`` (views and renders) and ``_solution`` (the
result, its arrays and files).

Rendering (:func:`view_source`, :func:`render`): the in-scattered radiance
toward a camera per unit length at each voxel is
``S = albedo / V * (R_sun p(sun . w) + sum_j R_j pbar_j(w))`` with ``w`` the
direction from the voxel to the camera and ``pbar_j`` the phase function
averaged over bin ``j``; an emission-absorption ray march of ``S`` and the
extinction gives the image.

Conventions: arrays ``(nz, ny, nx)``, voxel centres at ``(i+.5) dx`` in the box
``[0,Lx]x[0,Ly]x[0,Lz]``; ``sun_dir`` points *toward* the sun; the sun's
irradiance is per unit area perpendicular to its rays.

References
----------
N. Max, R. Crawfis, "Advances in Scientific Visualization" ("Cloud rendering").
N. Max, "Efficient light propagation for multiple anisotropic volume
scattering", Eurographics Rendering Workshop 1994.
M. F. Cohen et al., "A progressive refinement approach to fast radiosity
image generation", SIGGRAPH 1988.
P. Feda, W. Purgathofer, "Accelerating radiosity by overshooting", Eurographics
Rendering Workshop 1992.
K. D. Lathrop, "Ray effects in discrete ordinates equations", Nucl. Sci. Eng. 32 (1968).
"""

from ..splats.camera import Camera
from . import phase
from ._solution import (
    Progress,
    Solution,
    json_plain,
    load_solution,
    save_solution,
    slab_reflectance,
    solution_arrays,
    solution_from_arrays,
)
from ._solve import (
    LOW_SUN,
    MERGE_TOL,
    MERGE_TOL_FIRST,
    MERGE_TOL_LATER,
    PEAKED_ORDERS,
    SECOND_MOMENTS_TAU,
    solve,
    solve_steps,
)
from ._views import march_planes, orbit_camera, render, view_source

NB = phase.NBINS  # the default layout's bin count (96); a solve's own is ``len(sol.received)``

__all__ = ["Camera", "LOW_SUN", "MERGE_TOL", "MERGE_TOL_FIRST", "MERGE_TOL_LATER", "NB", "PEAKED_ORDERS", "Progress",
           "SECOND_MOMENTS_TAU", "Solution", "json_plain", "load_solution", "march_planes", "orbit_camera", "render",
           "save_solution", "slab_reflectance", "solution_arrays", "solution_from_arrays", "solve", "solve_steps",
           "view_source"]
