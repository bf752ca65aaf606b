"""The muscle film (Fig. 7): blobby molecules, the filament lattice and its cross-bridges."""

from .blobby import blobby_field, blobby_surface, level_distance
from .brownian import CrossBridges, Params
from .lattice import CELL_LENGTH, Lattice, actin_subunits, myosin_heads, unit_cell
from .molecules import Cylinders, Ellipsoids, actin_subunit, cylinder_mesh, myosin_head

__all__ = ["CELL_LENGTH", "CrossBridges", "Cylinders", "Ellipsoids", "Lattice", "Params", "actin_subunit",
           "actin_subunits", "blobby_field", "blobby_surface", "cylinder_mesh", "level_distance", "myosin_head",
           "myosin_heads", "unit_cell"]
