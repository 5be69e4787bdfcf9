"""A small stand-in for `mwbx.bank.Bank` used by the viewer tests and benchmark
(like MJX's ``test_util``: test support that scripts share, so it lives in the
package).

It has exactly the attributes of the bank contract and is filled by simulating
a tiny MJCF scene with `mujoco.mj_step` (no perturbations): a floor, a static
ramp and one free object per geom type plus a two-link articulated object.
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import mujoco
import numpy as np

from mwbx.bank import FLAG_FINISHED, FLAG_UNSTABLE, rows_of

METRIC_NAMES = (
  "angular_travel", "rest_time", "collisions", "orientation_error", "path_length", "max_height",
)

# Colours are chosen far from each other and from meshcat's background so the
# browser test can find them in a screenshot.
STANDIN_XML = """
<mujoco model="viewer_standin">
  <option timestep="0.004166666666666667"/>
  <asset>
    <material name="floor_mat" rgba="0.85 0.85 0.8 1"/>
    <material name="yellow" rgba="1 0.85 0 1" shininess="0.2"/>
    <mesh name="tetra" vertex="0 0 0  0.12 0 0  0 0.12 0  0 0 0.12"/>
  </asset>
  <worldbody>
    <camera name="overview" pos="1.6 -1.6 1.3" xyaxes="0.707 0.707 0 -0.35 0.35 0.87"/>
    <geom name="floor" type="plane" size="1.2 1.2 0.05" material="floor_mat"/>
    <geom name="ramp" type="box" size="0.3 0.15 0.02" pos="-0.4 0 0.15" euler="0 20 0" rgba="0.5 0.3 0.1 1"/>
    <geom name="hidden_collider" type="sphere" size="0.05" pos="0 0 1" group="3"/>
    <body name="box" pos="-0.4 0 0.5">
      <freejoint/>
      <geom type="box" size="0.07 0.07 0.07" rgba="0.9 0.1 0.1 1"/>
    </body>
    <body name="ball" pos="0 0.3 0.4">
      <freejoint/>
      <geom type="sphere" size="0.07" rgba="0.1 0.2 0.95 1"/>
    </body>
    <body name="pill" pos="0.3 -0.3 0.3">
      <freejoint/>
      <geom type="capsule" size="0.04 0.08" rgba="0.95 0.5 0.1 1"/>
    </body>
    <body name="can" pos="0.3 0.3 0.3">
      <freejoint/>
      <geom type="cylinder" size="0.05 0.08" material="yellow"/>
    </body>
    <body name="egg" pos="-0.3 -0.4 0.35">
      <freejoint/>
      <geom type="ellipsoid" size="0.05 0.08 0.05" rgba="0.8 0.1 0.8 1"/>
    </body>
    <body name="tetra" pos="0 -0.1 0.6">
      <freejoint/>
      <geom type="mesh" mesh="tetra" rgba="0.1 0.8 0.8 1"/>
    </body>
    <body name="arm_base" pos="0.5 0 0.45">
      <freejoint/>
      <geom type="box" size="0.06 0.03 0.03" rgba="0.3 0.3 0.3 1"/>
      <body name="arm_tip" pos="0.1 0 0">
        <joint name="elbow" type="hinge" axis="0 1 0"/>
        <geom type="capsule" fromto="0 0 0 0.12 0 0" size="0.025" rgba="0.3 0.3 0.3 1"/>
      </body>
    </body>
  </worldbody>
</mujoco>
"""

OBJECTS = {
  "box": ("box",), "ball": ("ball",), "pill": ("pill",), "can": ("can",),
  "egg": ("egg",), "tetra": ("tetra",), "arm": ("arm_base", "arm_tip"),
}
GROUPS = {"round": ("ball", "pill", "egg"), "all": tuple(OBJECTS)}


class StandinError(ValueError):
  pass


@dataclasses.dataclass
class StandinBank:
  """Same attribute names and shapes as the bank contract (host numpy arrays)."""

  n_worlds: int
  world_ids: np.ndarray  # i64[W]
  keys: np.ndarray  # u32[W, 2]
  flags: np.ndarray  # u8[W]
  record_fps: float
  frame_count: np.ndarray  # i32[W]
  qpos: np.ndarray  # f32[W, T, nq], stand-in for the compressed streams
  query_fps: float
  com: np.ndarray  # f32[W, P, B, 3]
  com_count: np.ndarray  # i32[W]
  metrics: np.ndarray  # f32[W, B, M]
  metric_names: tuple
  body_names: tuple
  body_ids: np.ndarray  # i32[B]
  objects: dict
  groups: dict
  config: dict
  timestep: float
  xml: str

  @property
  def valid(self) -> np.ndarray:
    return (self.flags & FLAG_UNSTABLE) == 0

  def row_of(self, ids):
    return rows_of(self.world_ids, ids)

  def qpos_frames(self, world: int) -> np.ndarray:
    row = self.row_of(world)
    return self.qpos[row, : self.frame_count[row]]

  @property
  def model(self) -> mujoco.MjModel:
    return mujoco.MjModel.from_xml_string(self.xml)

  def select_bodies(self, names: str | Sequence[str]) -> np.ndarray:
    if isinstance(names, str):
      names = [names]
    picked: list[str] = []
    for name in names:
      if name in self.body_names:
        picked.append(name)
      elif name in self.objects:
        picked.extend(self.objects[name])
      elif name in self.groups:
        for obj in self.groups[name]:
          picked.extend(self.objects[obj])
      else:
        raise StandinError(f"unknown body, object or group name {name!r}")
    return np.asarray(sorted({self.body_names.index(n) for n in picked}), np.int32)


def make_standin_bank(n_worlds: int = 6, seconds: float = 1.5, seed: int = 0,
                      unstable: Sequence[int] = ()) -> StandinBank:
  """Simulates `n_worlds` variations (random initial velocities) of STANDIN_XML."""
  model = mujoco.MjModel.from_xml_string(STANDIN_XML)
  data = mujoco.MjData(model)
  body_names = tuple(n for obj in OBJECTS.values() for n in obj)
  body_ids = np.asarray([model.body(n).id for n in body_names], np.int32)
  record_fps, query_fps = 120.0, 30.0
  n_steps = int(round(seconds / model.opt.timestep))
  rec_every = int(round(1.0 / (record_fps * model.opt.timestep)))
  com_every = int(round(1.0 / (query_fps * model.opt.timestep)))
  n_frames = n_steps // rec_every + 1
  n_points = n_steps // com_every + 1
  rng = np.random.default_rng(seed)
  qpos = np.zeros((n_worlds, n_frames, model.nq), np.float32)
  com = np.zeros((n_worlds, n_points, len(body_names), 3), np.float32)
  for w in range(n_worlds):
    mujoco.mj_resetData(model, data)
    data.qvel[:] = rng.normal(0.0, 1.0, model.nv)
    for step in range(n_steps + 1):
      if step:
        mujoco.mj_step(model, data)
      if step % rec_every == 0:
        qpos[w, step // rec_every] = data.qpos
      if step % com_every == 0:
        mujoco.mj_kinematics(model, data)
        mujoco.mj_comPos(model, data)
        com[w, step // com_every] = data.xipos[body_ids]
  frame_count = np.full(n_worlds, n_frames, np.int32)
  com_count = np.full(n_worlds, n_points, np.int32)
  # Shorter recordings for some worlds: tails repeat the last valid sample.
  for w in range(1, n_worlds, 3):
    frame_count[w] = n_frames * 2 // 3
    com_count[w] = n_points * 2 // 3
    com[w, com_count[w]:] = com[w, com_count[w] - 1]
    qpos[w, frame_count[w]:] = qpos[w, frame_count[w] - 1]
  flags = np.full(n_worlds, FLAG_FINISHED, np.uint8)
  for w in unstable:
    flags[w] |= FLAG_UNSTABLE
    com[w, 3:] = np.nan
  seg = np.linalg.norm(np.diff(com, axis=1), axis=-1)
  metrics = np.zeros((n_worlds, len(body_names), len(METRIC_NAMES)), np.float32)
  metrics[..., METRIC_NAMES.index("path_length")] = np.nansum(seg, axis=1)
  metrics[..., METRIC_NAMES.index("max_height")] = np.nanmax(com[..., 2], axis=1)
  return StandinBank(
    n_worlds=n_worlds,
    world_ids=np.arange(n_worlds, dtype=np.int64),
    keys=rng.integers(0, 2**32, (n_worlds, 2), dtype=np.uint32),
    flags=flags,
    record_fps=record_fps,
    frame_count=frame_count,
    qpos=qpos,
    query_fps=query_fps,
    com=com,
    com_count=com_count,
    metrics=metrics,
    metric_names=METRIC_NAMES,
    body_names=body_names,
    body_ids=body_ids,
    objects=dict(OBJECTS),
    groups=dict(GROUPS),
    config={"scene": {"mjcf": "viewer_standin"}},
    timestep=float(model.opt.timestep),
    xml=STANDIN_XML,
  )
