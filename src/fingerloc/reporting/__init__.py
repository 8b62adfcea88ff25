"""Report folders of a user's own data: plain HTML pages with PNG figures beside them.

Every report is a folder holding ``index.html`` (no JavaScript, readable
offline; open it in any browser), its PNG figures (each with alt text) and
``report.json`` (the numbers, with full place names). The writers take plain
data (numpy arrays, names, :class:`FeatureView`), so that any command or
script can call them:

- :func:`write_map_report`: the places over the run (centres, radius, graph
  edges, trajectory, scan end points) and per place its views and one view's
  features and fingerprint;
- :func:`write_localize_report`: accuracy, per-place top-1, the confusion
  matrix (the most confused places when there are many), the worst queries
  with their posterior and features against the true place's and the answer's;
- :func:`write_track_report`: the trajectory coloured by right / wrong, the
  true place's filtered and single-shot probability and the entropy over
  time, kidnappings and recoveries;
- :func:`write_panorama_report`: a panorama with its vertical edges and colour
  patches, and the heading estimate against a reference view;
- :func:`write_photo_answers`: the photos behind a panorama model's answers
  (the query above the answered view, the verified keypoint matches, the
  heading and where it comes from, the evidence of each weighted term); the
  localize report links it for models with the keypoint term.

matplotlib is imported only when a report is written.
"""

from __future__ import annotations

from .html import Page, check_report_dir, ellipsize_middle, markdown_to_html, write_markdown_page
from .pages import (
    alignment_rows,
    detect_jumps,
    most_confused,
    recoveries_after,
    scan_end_points,
    write_localize_report,
    write_map_report,
    write_panorama_report,
    write_track_report,
)
from .photos import write_photo_answers
from .views import FeatureView, draw_view_thumbnail

__all__ = [
    "FeatureView",
    "Page",
    "alignment_rows",
    "check_report_dir",
    "detect_jumps",
    "draw_view_thumbnail",
    "ellipsize_middle",
    "markdown_to_html",
    "most_confused",
    "recoveries_after",
    "scan_end_points",
    "write_localize_report",
    "write_map_report",
    "write_markdown_page",
    "write_panorama_report",
    "write_photo_answers",
    "write_track_report",
]
