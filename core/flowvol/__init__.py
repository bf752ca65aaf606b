"""Flow volumes (Fig. 5): smoke released through a generator polygon, as tetrahedra."""

from .climate import ClimateVelocity
from .unstructured import UnstructuredVelocity
from .volume import FlowVolume, flow_volume

__all__ = ["ClimateVelocity", "FlowVolume", "UnstructuredVelocity", "flow_volume"]
