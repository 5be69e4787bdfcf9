"""Backends, the lockstep sampling loop, recording and rest detection."""

from mwbx.batch_sim.backend import ChunkResult
from mwbx.batch_sim.backend import resolve_backend
from mwbx.batch_sim.sampler import SampleStats
from mwbx.batch_sim.sampler import Sampler
from mwbx.batch_sim.sampler import sample
from mwbx.batch_sim.world import METRIC_NAMES
