"""Channel layout, error bounds and the codec's error type.

A *channel* is one independently coded piece of ``qpos``:

- ``pos``: the 3 translation coordinates of a free joint (metres), fitted with
  piecewise-linear segments plus one global vertical quadratic term (gravity)
  switched on or off per segment;
- ``rot``: one quaternion ``(w, x, y, z)`` of a free or ball joint, fitted
  piecewise-linearly in the log map;
- ``scalar``: one hinge (radians) or slide (metres) coordinate, fitted
  piecewise-linearly.

The layout only needs MuJoCo's joint arrays (``m.jnt_type``, ``m.jnt_qposadr``,
``m.nq``); the codec never imports a model.
"""

from __future__ import annotations

import dataclasses
import math
from typing import Sequence

import numpy as np

from mwbx.errors import MwbxError
from mwbx.joints import JNT_BALL, JNT_FREE, JNT_HINGE, JNT_SLIDE  # noqa: F401 (re-exported)


class CodecError(MwbxError):
  """A stream that cannot be decoded, or codec input a user got wrong."""


@dataclasses.dataclass(frozen=True)
class CodecBounds:
  """Largest decoded error allowed, per frame and per channel.

  Attributes:
    e_pos: metres, l-infinity per coordinate of a free-joint translation.
    e_rot: radians, rotation angle between decoded and true orientation.
    e_scalar: joint units (radians for hinges, metres for slides).
  """

  e_pos: float = 1e-3
  e_rot: float = float(np.deg2rad(0.5))
  e_scalar: float = 1e-3

  def __post_init__(self):
    for name in ("e_pos", "e_rot", "e_scalar"):
      value = getattr(self, name)
      if not (isinstance(value, (int, float, np.floating)) and math.isfinite(value)
              and value > 0):
        raise CodecError(f"codec bound {name} must be a finite number > 0, got {value!r}")
    if self.e_rot >= 0.5:
      raise CodecError(f"codec bound e_rot must be < 0.5 rad, got {self.e_rot!r}")

  def to_json(self) -> dict:
    return {"e_pos": float(self.e_pos), "e_rot": float(self.e_rot),
            "e_scalar": float(self.e_scalar)}

  @classmethod
  def from_json(cls, d: dict) -> "CodecBounds":
    return cls(e_pos=float(d["e_pos"]), e_rot=float(d["e_rot"]),
               e_scalar=float(d["e_scalar"]))


@dataclasses.dataclass(frozen=True)
class ChannelLayout:
  """Where each coded channel lives in ``qpos``.

  Attributes:
    nq: number of generalized coordinates.
    pos_adr: qpos address of each free-joint translation (3 coordinates).
    rot_adr: qpos address of each quaternion (4 coordinates, w first).
    scalar_adr: qpos address of each hinge/slide coordinate.
  """

  nq: int
  pos_adr: tuple[int, ...] = ()
  rot_adr: tuple[int, ...] = ()
  scalar_adr: tuple[int, ...] = ()

  def __post_init__(self):
    covered = np.zeros(max(self.nq, 0), np.int64)
    if self.nq < 0 or self.nq > 65535:
      raise CodecError(f"layout nq must be in [0, 65535], got {self.nq}")
    for name, width in (("pos_adr", 3), ("rot_adr", 4), ("scalar_adr", 1)):
      for adr in getattr(self, name):
        if adr < 0 or adr + width > self.nq:
          raise CodecError(f"layout {name} entry {adr} (width {width}) is outside qpos of "
                           f"size {self.nq}")
        covered[adr:adr + width] += 1
    if np.any(covered != 1):
      bad = int(np.flatnonzero(covered != 1)[0])
      raise CodecError(f"layout must cover every qpos coordinate exactly once; coordinate "
                       f"{bad} is covered {int(covered[bad])} times")

  @classmethod
  def from_joints(cls, jnt_type: Sequence[int], jnt_qposadr: Sequence[int],
                  nq: int) -> "ChannelLayout":
    """Layout from MuJoCo joint arrays (``m.jnt_type``, ``m.jnt_qposadr``, ``m.nq``)."""
    jnt_type = np.asarray(jnt_type, np.int64).reshape(-1)
    jnt_qposadr = np.asarray(jnt_qposadr, np.int64).reshape(-1)
    if jnt_type.shape != jnt_qposadr.shape:
      raise CodecError(f"jnt_type has {jnt_type.size} joints but jnt_qposadr has "
                       f"{jnt_qposadr.size}")
    pos, rot, scalar = [], [], []
    for jtype, adr in zip(jnt_type.tolist(), jnt_qposadr.tolist()):
      if jtype == JNT_FREE:
        pos.append(adr)
        rot.append(adr + 3)
      elif jtype == JNT_BALL:
        rot.append(adr)
      elif jtype in (JNT_SLIDE, JNT_HINGE):
        scalar.append(adr)
      else:
        raise CodecError(f"unknown MuJoCo joint type {jtype} at qpos address {adr}")
    return cls(nq=int(nq), pos_adr=tuple(pos), rot_adr=tuple(rot), scalar_adr=tuple(scalar))

  @property
  def n_channels(self) -> int:
    return len(self.pos_adr) + len(self.rot_adr) + len(self.scalar_adr)

  def channels_for(self, columns: Sequence[int]) -> np.ndarray:
    """bool[C]: the channels (translations, rotations, scalars) holding any of
    the qpos ``columns``."""
    wanted = np.zeros(self.nq, bool)
    columns = np.asarray(columns, np.int64).reshape(-1)
    if columns.size and (columns.min() < 0 or columns.max() >= self.nq):
      raise CodecError(f"qpos columns must be in [0, {self.nq}), got {columns.tolist()}")
    wanted[columns] = True
    return np.array([wanted[a:a + w].any() for adrs, w in ((self.pos_adr, 3), (self.rot_adr, 4),
                                                            (self.scalar_adr, 1)) for a in adrs],
                    bool)

  def to_json(self) -> dict:
    return {"nq": self.nq, "pos_adr": list(self.pos_adr), "rot_adr": list(self.rot_adr),
            "scalar_adr": list(self.scalar_adr)}

  @classmethod
  def from_json(cls, d: dict) -> "ChannelLayout":
    return cls(nq=int(d["nq"]), pos_adr=tuple(int(a) for a in d["pos_adr"]),
               rot_adr=tuple(int(a) for a in d["rot_adr"]),
               scalar_adr=tuple(int(a) for a in d["scalar_adr"]))
