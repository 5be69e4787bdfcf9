"""Refinement (paper §5): resample chosen objects of one world from a time on.

Stored-state restarts, active/inactive/ghost sets, the interaction test and
stored-motion playback. It calls the sampler's backends and the codec; it
never writes the codec's format itself (``QposStore.refined`` does).
"""

from mwbx.refinement.refine import DEFAULT_MARGIN
from mwbx.refinement.refine import RefineStats
from mwbx.refinement.refine import refine
from mwbx.refinement.refine import RefinePlan
from mwbx.refinement.refine import RefineRequest
from mwbx.refinement.refine import Refinement
from mwbx.refinement.refine import plan_refinement
from mwbx.refinement.refine import run_refinement
from mwbx.refinement.refine import sampler_for
from mwbx.refinement.exact_activation import exact_active
