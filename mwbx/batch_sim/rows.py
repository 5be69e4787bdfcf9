"""One road from chunk results to bank rows, for sampling and refinement.

A backend's loop (:mod:`mwbx.batch_sim.native_backend`,
:mod:`mwbx.batch_sim.mjx_backend`, the refinement loops) returns a
:class:`~mwbx.batch_sim.backend.ChunkResult`; :func:`rows_from_chunks` turns
one or more of them into the per-world columns a :class:`mwbx.Bank` stores:
flags from the run status (:data:`STATUS_FLAGS`), the COM polylines at the
query rate on the codec's COM grid with their point counts
(:func:`com_count`), and finite metrics. A refinement also keeps part of its
parent's row (:class:`ParentRow`).
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import numpy as np

from mwbx import bank as bank_lib
from mwbx.batch_sim import world
from mwbx.batch_sim.backend import ChunkResult, fill_tail
from mwbx.codec import polyline

# The flag a world's final run status adds to FLAG_FINISHED (RUNNING and
# END_TIME add none). SIM_ERROR: MuJoCo stopped the world (trapped by the loop).
STATUS_FLAGS = ((world.AT_REST, bank_lib.FLAG_AT_REST),
                (world.UNSTABLE, bank_lib.FLAG_UNSTABLE),
                (world.SIM_ERROR, bank_lib.FLAG_SIM_ERROR))


class ChunkRows(NamedTuple):
  """Bank columns of W worlds (see :class:`mwbx.Bank` for each)."""

  flags: np.ndarray  # u8[W]
  frame_count: np.ndarray  # i32[W]
  com: np.ndarray  # f32[W, P, B, 3], m
  com_count: np.ndarray  # i32[W]
  metrics: np.ndarray  # f32[W, B, M]
  perturbations: np.ndarray  # i32[W]
  steps: np.ndarray  # i32[W]


class ParentRow(NamedTuple):
  """What refined worlds keep of their parent's bank row.

  Attributes:
    com: f32[P, B, 3] the parent's stored COM polylines (every point before
      the first refined frame is the parent's, for every body).
    metrics: f32[B, M] the parent's metrics.
    com_kept: bool[W, B] bodies whose whole polyline is the parent's.
    metrics_kept: bool[W, B] bodies whose metrics are the parent's.
  """

  com: np.ndarray
  metrics: np.ndarray
  com_kept: np.ndarray
  metrics_kept: np.ndarray


def status_flags(status: np.ndarray, contact_overflow: np.ndarray | None = None) -> np.ndarray:
  """u8[W] bank flags of worlds that ended with ``status`` (i32[W]);
  ``contact_overflow`` bool[W] (MJX; None: the backend has no budget) adds
  FLAG_CONTACT_OVERFLOW."""
  status = np.asarray(status)
  flags = np.full(status.shape, bank_lib.FLAG_FINISHED, np.uint8)
  for code, flag in STATUS_FLAGS:
    flags[status == code] |= flag
  if contact_overflow is not None:
    flags[np.asarray(contact_overflow, bool)] |= bank_lib.FLAG_CONTACT_OVERFLOW
  return flags


def com_count(frame_count: np.ndarray, query_stride: int) -> np.ndarray:
  """i32[W] polyline points of worlds of ``frame_count`` recorded frames: the
  frames 0, stride, 2·stride, … below frame_count (0 frames: 0 points)."""
  frame_count = np.asarray(frame_count)
  return np.where(frame_count > 0, (frame_count - 1) // query_stride + 1, 0).astype(np.int32)


def rows_from_chunks(results: Sequence[ChunkResult], query_stride: int, com_step: float | None, *,
                     first_frame: int = 0, frame_count: np.ndarray | None = None,
                     parent: ParentRow | None = None) -> ChunkRows:
  """The bank columns of the worlds of ``results``, in order.

  Args:
    results: chunk results (their ``qpos`` is not read); frame 0 of their
      ``com`` is the world's frame ``first_frame``.
    query_stride: record frames per polyline point.
    com_step: the stored COM grid step, m (``CodecSection.com_step()``: the
      polylines go on it, so that queries see exactly what is stored); None:
      no grid.
    first_frame: the frame the results start at (a refinement's f0).
    frame_count: i32[W] recorded frames from frame 0 (default: first_frame
      plus the results' own counts).
    parent: a refinement's parent row (points before ``first_frame`` and
      kept bodies come from it); needed when ``first_frame`` > 0.

  Returns:
    the columns; polyline points past ``com_count`` repeat the last one.
  """
  cat = lambda name: np.concatenate([getattr(r, name) for r in results])
  if frame_count is None:
    frame_count = first_frame + cat("frame_count")
  frame_count = np.asarray(frame_count).astype(np.int32)
  counts = com_count(frame_count, query_stride)
  com = cat("com")
  if first_frame:
    com = np.concatenate([np.zeros((len(com), first_frame) + com.shape[2:], np.float32), com], axis=1)
  com = com[:, ::query_stride]
  if parent is not None:
    n_points = parent.com.shape[0]
    com = com[:, :n_points]
    com = np.concatenate([com, np.repeat(com[:, -1:], n_points - com.shape[1], axis=1)], axis=1)
    before = np.arange(n_points) * query_stride < first_frame
    com[:, before] = parent.com[before]
    com = np.where(parent.com_kept[:, None, :, None], parent.com[None], com)
  com = fill_tail(np.ascontiguousarray(com), counts)  # the tail repeats the last polyline point
  com = np.nan_to_num(com)
  com = polyline.round_to_grid(com, com_step)
  metrics = np.nan_to_num(cat("metrics"), nan=0.0, posinf=0.0, neginf=0.0)
  if parent is not None:
    metrics = np.where(parent.metrics_kept[:, :, None], parent.metrics[None], metrics)
  overflow = [r.contact_overflow for r in results]
  flags = status_flags(cat("status"),
                       np.concatenate(overflow) if all(o is not None for o in overflow) else None)
  return ChunkRows(flags=flags, frame_count=frame_count, com=com.astype(np.float32), com_count=counts,
                   metrics=metrics.astype(np.float32), perturbations=cat("perturbations").astype(np.int32),
                   steps=cat("steps").astype(np.int32))
