"""Annotations of a film: the model date and time in the dataset's calendar, legends of the transfer
functions in use, a frame's annotation layer and the title cards of a reel.  NumPy only; text comes
from a rasteriser passed in (Blender's font engine through :func:`nephele.fileio.text_mask`)."""

from .canvas import box_text, over_rgb, srgb_decode, srgb_encode  # noqa: F401
from .layout import FIGURES, REFERENCE, font_size, heading, overlay, title_card  # noqa: F401
from .legend import ColorBar, OpacityBar, Swatch, bar_pixels, bar_values, legend_image  # noqa: F401
from .modeltime import calendar_note, dataset_calendar, model_datetime, time_label  # noqa: F401
