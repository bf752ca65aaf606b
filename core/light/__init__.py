"""Light: multiple scattering in clouds and the phase functions."""

from .phase import (  # noqa: F401
    FACES,
    N_PER_FACE,
    NBINS,
    bin_of,
    bin_phase_toward,
    bins,
    direct_directions,
    direct_fractions,
    hg,
    mean_directions,
    phase_matrix,
    sub_phase_matrix,
    sub_sub_phase_matrix,
)
from .scatter import (  # noqa: F401
    NB,
    Camera,
    Progress,
    Solution,
    load_solution,
    orbit_camera,
    render,
    save_solution,
    slab_reflectance,
    solution_arrays,
    solution_from_arrays,
    solve,
    solve_steps,
    view_source,
)
from .scatter_task import (  # noqa: F401
    plan_solve,
    solve_task,
    task_params,
)
from .sky import (  # noqa: F401
    luminance,
    panorama_radiance,
    panorama_solid_angles,
)
