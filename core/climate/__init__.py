"""Climate data: the globe grid, datasets and their readers (NetCDF, GrADS, GRIB, Zarr), the synthetic demo,
humidity and relief."""

from .columns import (  # noqa: F401
    ColumnLocator,
)
from .dataset import (  # noqa: F401
    ArrayDataset,
    Dataset,
    GlobeGrid,
    Variable,
    hourly,
)
from .grads import (  # noqa: F401
    GradsDataset,
    open_grads,
    parse_ctl,
    parse_time,
)
from .grib import (  # noqa: F401
    open_grib,
)
from .grid import (  # noqa: F401
    DEFAULT_EXAGGERATION,
    EARTH_RADIUS,
    globe_radius,
    height_from_radius,
    lonlat_to_xyz,
    rotated_pole_matrix,
    xyz_to_lonlat,
)
from .gridfile import (  # noqa: F401
    ALIASES,
    FileDataset,
    cf_times,
    cf_times_or_steps,
    plausible_units,
    standard_name,
    step_times,
    tidy_lonlat,
)
from .humidity import (  # noqa: F401
    EPSILON,
    RH_CRIT,
    mixing_ratio,
    relative_humidity,
    saturation_vapour_pressure,
    standard_height,
    standard_pressure,
    sundqvist_cloud,
    vapour_pressure,
)
from .netcdf import (  # noqa: F401
    NetCDFDataset,
    destagger,
    open_netcdf,
)
from .readers import (  # noqa: F401
    OVERRIDES,
    check_overrides,
    open_dataset,
    override_source,
    parse_var_map,
    split_source,
)
from .relief import (  # noqa: F401
    RELIEF_FILE,
    load_etopo,
    load_relief,
    sample_relief,
    write_relief,
)
from .synthetic import (  # noqa: F401
    DELTA,
    SIZES,
    TOP,
    SyntheticClimate,
    demo_dataset,
)
from .zarrstore import (  # noqa: F401
    open_zarr_store,
)
