"""Figures of the report (not part of the method): turntable strips of a hairstyle, scalp
coverage maps and metrics tables. Each ``write_*`` function loads pipeline files, draws one
figure and writes it atomically; the other functions work on in-memory values.

>>> from vid2haircut.report import TurntableStyle
>>> TurntableStyle().views[0]
('front', 0.0)
"""

from vid2haircut.report.coverage import CoverageMap, coverage_figure, scalp_coverage, write_coverage
from vid2haircut.report.metrics_table import metrics_table_image, metrics_table_rst, write_metrics_table
from vid2haircut.report.turntable import TurntableStyle, render_views, turntable_strip, write_turntable

__all__ = ["CoverageMap", "TurntableStyle", "coverage_figure", "metrics_table_image", "metrics_table_rst",
           "render_views", "scalp_coverage", "turntable_strip", "write_coverage", "write_metrics_table",
           "write_turntable"]
