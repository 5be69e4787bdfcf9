"""Browsing many worlds in the browser (paper §4, §6): draw boxes, see the
answer at once, sort, play back, refine."""

from mwbx.browser.app import Browser
from mwbx.browser.app import browse
from mwbx.browser.session import Counts
from mwbx.browser.session import Session
from mwbx.browser.session import SorterRow
