"""Small MuJoCo scenes recorded at a fixed rate, for codec tests and benchmarks.

``boxes``: free boxes thrown onto a plane (flight, bounces, sliding, rest).
``chain``: an articulated chain (free root + ball and hinge joints) falling and
tumbling, the kind of motion a ragdoll produces.
"""

from __future__ import annotations

import mujoco
import numpy as np

from mwbx.joints import JNT_BALL, JNT_FREE

_BOXES = """
<mujoco>
  <option timestep="{dt}"/>
  <worldbody>
    <geom type="plane" size="20 20 0.1"/>
    {bodies}
  </worldbody>
</mujoco>
"""

_BOX = """<body name="box{i}" pos="{x} {y} {z}"><freejoint/>
  <geom type="box" size="{sx} {sy} {sz}" density="500"/></body>"""

_CHAIN = """
<mujoco>
  <option timestep="{dt}"/>
  <default><joint armature="0.01" damping="0.02"/></default>
  <worldbody>
    <geom type="plane" size="20 20 0.1"/>
    <body name="root" pos="0 0 1.5"><freejoint/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.05"/>
      <body name="l1" pos="0.3 0 0"><joint type="ball"/>
        <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.04"/>
        <body name="l2" pos="0.3 0 0"><joint type="hinge" axis="0 0 1" range="-2 2"/>
          <geom type="capsule" fromto="0 0 0 0.25 0 0" size="0.04"/>
          <body name="l3" pos="0.25 0 0"><joint type="hinge" axis="0 1 0"/>
            <joint type="slide" axis="1 0 0" range="-0.05 0.05"/>
            <geom type="capsule" fromto="0 0 0 0.2 0 0" size="0.03"/>
          </body>
        </body>
      </body>
    </body>
  </worldbody>
</mujoco>
"""


def boxes_model(n_boxes: int, seed: int = 0, dt: float = 1 / 480) -> mujoco.MjModel:
  rng = np.random.default_rng(seed)
  bodies = "\n".join(
      _BOX.format(i=i, x=rng.uniform(-2, 2), y=rng.uniform(-2, 2), z=rng.uniform(0.5, 3),
                  sx=rng.uniform(0.05, 0.2), sy=rng.uniform(0.05, 0.2), sz=rng.uniform(0.05, 0.2))
      for i in range(n_boxes))
  return mujoco.MjModel.from_xml_string(_BOXES.format(dt=dt, bodies=bodies))


def chain_model(dt: float = 1 / 480) -> mujoco.MjModel:
  return mujoco.MjModel.from_xml_string(_CHAIN.format(dt=dt))


def record(model: mujoco.MjModel, n_frames: int, fps: float = 120.0, seed: int = 0,
           speed: float = 3.0, spin: float = 8.0) -> np.ndarray:
  """Simulates from random initial velocities; returns qpos f32[n_frames, nq].

  Free joints get random linear (m/s) and angular (rad/s) velocities; every
  quaternion in the output has its sign flipped at random, as a codec must
  accept.
  """
  rng = np.random.default_rng(seed)
  data = mujoco.MjData(model)
  for j in range(model.njnt):
    adr = model.jnt_dofadr[j]
    if int(model.jnt_type[j]) == JNT_FREE:
      data.qvel[adr:adr + 3] = rng.normal(0, speed, 3) + np.array([0, 0, speed])
      data.qvel[adr + 3:adr + 6] = rng.normal(0, spin, 3)
    else:
      data.qvel[adr] = rng.normal(0, 1.0)
  substeps = max(1, int(round(1.0 / (fps * model.opt.timestep))))
  out = np.zeros((n_frames, model.nq), np.float32)
  for f in range(n_frames):
    out[f] = data.qpos
    for _ in range(substeps):
      mujoco.mj_step(model, data)
  quat_adr = [model.jnt_qposadr[j] + (3 if int(model.jnt_type[j]) == JNT_FREE else 0)
              for j in range(model.njnt) if int(model.jnt_type[j]) in (JNT_FREE, JNT_BALL)]
  for adr in quat_adr:
    flip = rng.random(n_frames) < 0.3
    out[flip, adr:adr + 4] *= -1
  return out


def record_batch(model: mujoco.MjModel, n_worlds: int, n_frames: int, fps: float = 120.0,
                 seed: int = 0) -> np.ndarray:
  """qpos f32[n_worlds, n_frames, nq], each world from its own random velocities."""
  return np.stack([record(model, n_frames, fps, seed=seed * 100003 + w) for w in range(n_worlds)])
