"""The error report (host side): a page of sections, its figures, and the layout of results handed in by callers."""

from ._layout import compare as compare, pareto_flags as pareto_flags, report as report
from ._page import Page as Page, figure_png as figure_png, new_figure as new_figure, rgb_png as rgb_png
from ._plots import heatmap as heatmap, trade_figure as trade_figure
from ._results import FrameImages as FrameImages, ReportData as ReportData, TechniqueRun as TechniqueRun
