"""A stand-in bank for the query tests: the bank contract's attributes over
given arrays, with a small MJCF of free bodies (and one two-link object)."""

from __future__ import annotations

import dataclasses
from typing import Sequence

import mujoco
import numpy as np

from mwbx.bank import rows_of
from mwbx.errors import MwbxError

FLAG_FINISHED = 1
FLAG_AT_REST = 2
FLAG_UNSTABLE = 4
METRIC_NAMES = ("angular_travel", "rest_time", "collisions", "orientation_error",
                "path_length", "max_height")


def scene_xml(n_bodies: int) -> str:
  """Free bodies b0.. (spheres and boxes at offsets from their COM); the last
  two, when n_bodies >= 3, are a two-link arm object hanging off the world."""
  free = n_bodies - 2 if n_bodies >= 3 else n_bodies
  parts = []
  for i in range(free):
    if i % 2 == 0:
      geom = f'<geom type="sphere" size="{0.03 + 0.01 * i}" mass="0.1"/>'
    else:
      geom = ('<geom type="box" size="0.04 0.02 0.01" pos="0.05 0 0" mass="0.1"/>'
              '<geom type="sphere" size="0.02" pos="-0.05 0 0" mass="0.1"/>')
    parts.append(f'<body name="b{i}" pos="{0.3 * i} 0 1"><freejoint/>{geom}</body>')
  if n_bodies >= 3:
    parts.append(
        f'<body name="b{free}" pos="0 1 1"><joint type="ball"/>'
        f'<geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02" mass="0.1"/>'
        f'<body name="b{free + 1}" pos="0 0 -0.2"><joint type="hinge" axis="0 1 0"/>'
        f'<geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02" mass="0.1"/></body></body>')
  return ('<mujoco><worldbody><camera name="front" pos="0 -4 1" xyaxes="1 0 0 0 0 1" fovy="45"/>'
          '<geom type="plane" size="5 5 0.1"/>' + "".join(parts) + "</worldbody></mujoco>")


@dataclasses.dataclass
class StandInBank:
  """The attributes of mwbx.bank.Bank that queries use, over plain arrays."""

  com: np.ndarray  # f32[W, P, B, 3]
  flags: np.ndarray  # u8[W]
  metrics: np.ndarray  # f32[W, B, M]
  com_count: np.ndarray  # i32[W]
  query_fps: float = 30.0
  record_fps: float = 120.0
  timestep: float = 0.002
  metric_names: tuple[str, ...] = METRIC_NAMES
  config: dict = dataclasses.field(default_factory=dict)

  def __post_init__(self):
    n_bodies = self.com.shape[2]
    self._xml = scene_xml(n_bodies)
    model = self.model
    self.body_names = tuple(f"b{i}" for i in range(n_bodies))
    self.body_ids = np.array([model.body(n).id for n in self.body_names], np.int32)
    free = n_bodies - 2 if n_bodies >= 3 else n_bodies
    self.objects = {f"b{i}": (f"b{i}",) for i in range(free)}
    if n_bodies >= 3:
      self.objects["arm"] = (f"b{free}", f"b{free + 1}")
    names = list(self.objects)
    self.groups = {"even": tuple(names[0::2]), "everything": tuple(names)}
    self.world_ids = np.arange(self.com.shape[0], dtype=np.int64) + 100
    self.keys = np.zeros((self.com.shape[0], 2), np.uint32)
    self.frame_count = self.com_count * 4

  def flex_body_mask(self) -> np.ndarray:
    return np.zeros(len(self.body_names), bool)  # no flexes here

  @property
  def n_worlds(self) -> int:
    return self.com.shape[0]

  def row_of(self, ids):
    return rows_of(self.world_ids, ids)

  @property
  def valid(self) -> np.ndarray:
    return (self.flags & FLAG_UNSTABLE) == 0

  @property
  def model(self) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(self._xml)

  def select_bodies(self, names: str | Sequence[str]) -> np.ndarray:
    if isinstance(names, str):
      names = [names]
    out = []
    for name in names:
      if name in self.body_names:
        bodies = [name]
      elif name in self.objects:
        bodies = list(self.objects[name])
      elif name in self.groups:
        bodies = [b for o in self.groups[name] for b in self.objects[o]]
      else:
        raise MwbxError(f"select: unknown body, object or group {name!r}")
      out.extend(self.body_names.index(b) for b in bodies)
    return np.unique(np.asarray(out, np.int32))


def make_bank(com, flags=None, metrics=None, com_count=None, fps: float = 30.0,
              seed: int = 0) -> StandInBank:
  """A StandInBank over com f32[W, P, B, 3]; random metrics by default."""
  com = np.asarray(com, np.float32)
  w, p, b, _ = com.shape
  rng = np.random.default_rng(seed)
  if flags is None:
    flags = np.full(w, FLAG_FINISHED, np.uint8)
  if metrics is None:
    metrics = rng.uniform(0, 5, size=(w, b, len(METRIC_NAMES))).astype(np.float32)
  if com_count is None:
    com_count = np.full(w, p, np.int32)
  return StandInBank(com, np.asarray(flags, np.uint8), np.asarray(metrics, np.float32),
                     np.asarray(com_count, np.int32), query_fps=fps)


def ballistic_paths(n_worlds: int, n_points: int, n_bodies: int, seed: int = 0,
                    fps: float = 30.0) -> np.ndarray:
  """f32[W, P, B, 3] plausible paths: thrown from around (0, 0, 1.5), falling
  under gravity and bouncing on the floor z = 0 with some damping."""
  rng = np.random.default_rng(seed)
  t = np.arange(n_points) / fps
  p0 = rng.uniform([-1, -1, 1], [1, 1, 2], size=(n_worlds, 1, n_bodies, 3))
  v = rng.normal(0, 1, size=(n_worlds, 1, n_bodies, 3))
  pos = p0 + v * t[None, :, None, None]
  z = p0[..., 2] + v[..., 2] * t[None, :, None] - 4.905 * t[None, :, None] ** 2
  pos[..., 2] = np.abs(z) * np.exp(-0.3 * t)[None, :, None]
  return pos.astype(np.float32)
