"""Volumes: sparse resampling of curvilinear fields, the exact-shading atlas, exact ray integration,
transfer functions and cloud densities."""

from .cloud_density import (  # noqa: F401
    CloudParams,
    Ellipsoid,
    voxel_centres,
)
from .curvilinear import (  # noqa: F401
    CurvilinearField,
    LevelTable,
)
from .exact_ray import (  # noqa: F401
    opacity,
    ray_samples,
    reference_optical_depth,
    segment_optical_depth,
    sphere_span,
    volume_optical_depth,
)
from .sparse import (  # noqa: F401
    ALTITUDE,
    DEFAULT_EXTINCTION,
    DEFAULT_VOXEL_SIZE,
    EXACT,
    VOXELS,
    SparseVolume,
    candidate_blocks,
    height_scale,
    resample,
)
from .transfer import (  # noqa: F401
    ALTITUDE_COLORS,
    TEMPERATURE_COLORS,
    ColorMap,
    TransferFunction,
)
from .volume_atlas import (  # noqa: F401
    DEFAULT_BELOW,
    DEFAULT_SUPPORT_SIZE,
    AtlasLayout,
    ExactVolume,
    atlas_layout,
    axis_runs,
    bilinear,
    exact_volume,
    support_voxels,
    tf_eval32,
    tf_ramps,
)
from .volume_task import (  # noqa: F401
    frame_params,
    plan_volume,
)
