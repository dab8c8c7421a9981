"""The side panel's tabs: the larger views of what is shown. Each tab owns its controls and
images (`build`), shows a snapshot (`show`) and clears them on Reset (`clear`); the debugger
calls every tab the same way. A new tab is one module here plus one line in `TABS`."""

from __future__ import annotations

from viewer.tabs.base import Shown, Tab, TabActions
from viewer.tabs.hessian import HessianTab
from viewer.tabs.keyframe import KeyframeTab
from viewer.tabs.plots import PlotsTab
from viewer.tabs.report import ReportTab
from viewer.tabs.sweep import SweepTab
from viewer.tabs.variants import VariantsTab

# In the order they appear.
TABS: tuple[type[Tab], ...] = (KeyframeTab, HessianTab, VariantsTab, PlotsTab, ReportTab, SweepTab)

__all__ = ["TABS", "HessianTab", "KeyframeTab", "PlotsTab", "ReportTab", "Shown", "SweepTab", "Tab", "TabActions", "VariantsTab"]
