"""The compiled kept-pose pass of the geometry index against the numpy
forward kinematics (`poses.body_poses`) and `geometry.sweep_margins`."""

import mujoco
import numpy as np
import pytest

from mwbx.queries import geometry as geometry_lib
from mwbx.queries import kept_poses
from mwbx.queries import poses as poses_lib

import geometry_reference as ref

SLIDE_XML = """
<mujoco>
  <worldbody>
    <body name="cart" pos="0.1 0.2 0.3" quat="0.9 0.1 0.3 0.2"><joint type="slide" axis="1 1 0"/>
      <geom type="box" size="0.1 0.05 0.02"/>
      <body name="pole" pos="0 0 0.1"><joint type="hinge" axis="0 1 0" pos="0 0 -0.05"/>
        <joint type="slide" axis="0 0 1"/>
        <geom type="capsule" fromto="0 0 0 0 0 0.4" size="0.02"/></body>
    </body>
    <body name="marker" mocap="true" pos="0 1 1" quat="2 0 0 1"><geom type="sphere" size="0.05"/></body>
  </worldbody>
</mujoco>
"""


def _reference(model, qpos, body_ids, reach, stride):
  w, t, _ = qpos.shape
  xpos, xquat = poses_lib.body_poses(model, qpos.reshape(w * t, -1), body_ids)
  ipos = np.asarray(model.body_ipos[body_ids], np.float64)
  n = len(body_ids)
  xquat = xquat.reshape(w, t, n, 4)
  com = (xpos + poses_lib.quat_rotate(xquat.reshape(-1, n, 4), ipos)).reshape(w, t, n, 3)
  sweep = geometry_lib.sweep_margins(com, xquat, reach, stride)  # [w, k, B]
  return com[:, ::stride], xquat[:, ::stride], sweep


@pytest.mark.parametrize("xml,stride", [(ref.SHAPES_XML, 4), (SLIDE_XML, 3), (SLIDE_XML, 1)])
def test_kept_poses_match_numpy_kinematics_and_margins(xml, stride):
  model = mujoco.MjModel.from_xml_string(xml)
  rng = np.random.default_rng(stride)
  n_worlds, n_int = 5, 7
  t = n_int * stride + 1
  qpos = (model.qpos0 + np.cumsum(rng.normal(0, 0.05, (n_worlds, t, model.nq)), axis=1)).astype(np.float32)
  body_ids = np.arange(1, model.nbody)
  reach = rng.uniform(0.05, 0.3, len(body_ids))
  ipos = np.asarray(model.body_ipos[body_ids], np.float64)
  com = np.zeros((len(body_ids), n_worlds, n_int + 1, 3), np.float32)
  quat = np.zeros((len(body_ids), n_worlds, n_int + 1, 4), np.float32)
  sweep = np.zeros((len(body_ids), n_worlds, n_int), np.float32)
  kept_poses.kept_poses(qpos, kept_poses.tree(model, body_ids), body_ids, ipos, reach, stride, com, quat, sweep)
  want_com, want_quat, want_sweep = _reference(model, qpos, body_ids, reach, stride)
  np.testing.assert_allclose(com, np.moveaxis(want_com, 2, 0), rtol=1e-6, atol=1e-6)
  np.testing.assert_allclose(quat, np.moveaxis(want_quat, 2, 0), rtol=1e-6, atol=1e-6)
  np.testing.assert_allclose(sweep, np.moveaxis(want_sweep, 2, 0), rtol=1e-5, atol=1e-6)
  assert (sweep > 0).mean() > 0.6  # the motion is not trivial (a mocap body holds still)
  # A world whose poses are not finite gets no finite margin.
  qpos[1, 2] = np.nan
  kept_poses.kept_poses(qpos, kept_poses.tree(model, body_ids), body_ids, ipos, reach, stride, com, quat, sweep)
  assert np.isinf(sweep[0, 1]).any() and np.isfinite(sweep[:, 0]).all()
