"""Backends, the lockstep sampling loop, recording and rest detection."""

from mwbx.batch_sim.backend import ChunkResult
from mwbx.batch_sim.backend import resolve_backend
from mwbx.batch_sim.sampler import SampleStats
from mwbx.batch_sim.sampler import Sampler
from mwbx.batch_sim.sampler import sample
from mwbx.batch_sim.world import METRIC_NAMES
from mwbx.batch_sim.sampling_run import Hosts
from mwbx.batch_sim.sampling_run import RunInterrupted
from mwbx.batch_sim.sampling_run import SamplingRun
from mwbx.batch_sim.sampling_run import sample_run
