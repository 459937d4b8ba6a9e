"""The review report: an interactive HTML page of one solve (``[output] html``), and the index page
of a batch's reports. Blender-free; the contact sheet's renders come from ``facecap_addon.render.review``.

See ``docs/review.md`` for what the page shows and how to read it.
"""

from .index import TakeSummary, write_batch_index
from .page import MissingPlotlyError, build_page, plotly_js_source, shared_plotly_js, write_review_page
from .review import (
           ContactSheet,
           MarkerGeometry,
           Review,
           Tile,
           Truth,
           head_motion,
           marker_geometry,
           pick_frames,
           read_truth,
)

__all__ = ["ContactSheet", "MarkerGeometry", "MissingPlotlyError", "Review", "TakeSummary", "Tile", "Truth",
           "build_page", "head_motion", "marker_geometry", "pick_frames", "plotly_js_source", "read_truth",
           "shared_plotly_js", "write_batch_index", "write_review_page"]
