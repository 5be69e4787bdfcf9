"""The budgeted MJX step's broadphase (mwbx.batch_sim.mjx_collision): a pair
cap that holds the pairs really near each other drops nothing, even beside a
long wall whose bounding sphere covers the scene (as SIGGRAPH's walls do)."""

import jax
import mujoco
import numpy as np
from mujoco import mjx

from mwbx.batch_sim import contact_budget, mjx_collision

# Three stacks of two boxes in front of a 2 m wall: 3 box-box pairs touch;
# the wall's 6 pairs and the 12 between stacks do not, but the wall's
# bounding sphere (radius 1.1 m) ranks its pairs first by sphere distance.
STACKS = (-0.4, 0.0, 0.4)
_BOX = '<body pos="{x} -0.2 {z}"><freejoint/><geom type="box" size="0.05 0.05 0.05"/></body>'
MJCF = f"""<mujoco>
  <option timestep="0.002"/>
  <custom>
    <numeric name="max_geom_pairs" data="{{pairs}}"/>
    <numeric name="max_contact_points" data="64"/>
  </custom>
  <worldbody>
    <geom type="plane" size="2 2 0.1"/>
    <geom name="wall" type="box" size="1 0.01 0.5" pos="0 0 0.5"/>
    {"".join(_BOX.format(x=x, z=z) for x in STACKS for z in (0.05, 0.15))}
  </worldbody>
</mujoco>"""
STEPS = 150


def _top_heights(qpos: np.ndarray) -> np.ndarray:
  """f[..., 3] heights of the upper boxes (free joints 1, 3, 5), m."""
  return qpos[..., [7 * k + 2 for k in (1, 3, 5)]]


def _mjx_rollout(model, step):
  mx, d0 = mjx.put_model(model, impl="jax"), mjx.make_data(model, impl="jax")
  check = contact_budget.JaxOverflowCheck(model)

  def run(d):
    def one(d, _):
      d = step(mx, d)
      return d, (d.qpos, check(d))
    return jax.lax.scan(one, d, None, length=STEPS)[1]

  qpos, flagged = jax.jit(run)(d0)
  return np.asarray(qpos), np.asarray(flagged)


def test_box_broadphase_keeps_the_touching_pairs_beside_a_long_wall():
  model = mujoco.MjModel.from_xml_string(MJCF.format(pairs=3))
  data = mujoco.MjData(model)
  for _ in range(STEPS):
    mujoco.mj_step(model, data)
  reference = _top_heights(data.qpos)
  assert np.allclose(reference, 0.15, atol=2e-3)  # MuJoCo C: the stacks stand

  qpos, flagged = _mjx_rollout(model, mjx_collision.step)
  np.testing.assert_allclose(_top_heights(qpos[-1]), reference, atol=2e-3)
  assert not flagged.any()  # 3 overlapping pairs, cap 3: nothing dropped

  # MJX's own driver under the same cap keeps the wall's pairs and lets the
  # upper boxes sink into the lower ones (what mwbx ran before).
  qpos_mjx, _ = _mjx_rollout(model, mjx.step)
  assert (_top_heights(qpos_mjx[-1]) < 0.13).any()


def test_a_cap_below_the_touching_pairs_is_flagged():
  flagged = {}
  for pairs in (2, 3):
    model = mujoco.MjModel.from_xml_string(MJCF.format(pairs=pairs))
    d = jax.jit(mjx.kinematics)(mjx.put_model(model, impl="jax"), mjx.make_data(model, impl="jax"))
    flagged[pairs] = bool(contact_budget.JaxOverflowCheck(model)(d))  # (the pair cap needs poses only)
  assert flagged == {2: True, 3: False}  # 3 pairs' boxes overlap from the start
