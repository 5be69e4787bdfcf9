"""The MJX backend's solver limits (mjx_backend.SOLVER_ITERATIONS and
LS_ITERATIONS) give the answer of the model's own limits on contact-rich
states: the SIGGRAPH letters in the peg board and piling into the slots."""

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

import mwbx
from conftest import REPO
from mwbx.batch_sim import mjx_backend, mjx_collision
from mwbx.batch_sim.sampler import resolve_contact_budget

# Accelerations of the capped and the full solve agree to this share of the
# world's largest |qacc| (float32; measured: identical on these states).
QACC_TOLERANCE = 1e-5
WORLDS = 8
TIMES = (0.6, 2.0)  # s: in the peg board; piling into the slots


def _states(model: mujoco.MjModel, seconds: float) -> tuple[np.ndarray, np.ndarray]:
  """qpos, qvel f64[WORLDS, ...] after ``seconds`` of MuJoCo C from the initial
  state with small random velocities (a different fall per world)."""
  rng = np.random.default_rng(0)
  data = mujoco.MjData(model)
  qpos, qvel = [], []
  for _ in range(WORLDS):
    mujoco.mj_resetData(model, data)
    data.qvel[:] = rng.normal(0.0, 0.05, model.nv)
    for _ in range(round(seconds / model.opt.timestep)):
      mujoco.mj_step(model, data)
    qpos.append(data.qpos.copy())
    qvel.append(data.qvel.copy())
  return np.array(qpos), np.array(qvel)


def test_capped_solver_matches_the_models_own_limits_in_contact():
  config = mwbx.load_config(REPO / "configs" / "siggraph.yaml")
  scene = mwbx.Scene(config)
  backend = mjx_backend.backend_for(scene, "jax", resolve_contact_budget(scene, config.sim.mjx))
  capped = backend.mx
  assert (capped.opt.iterations, capped.opt.ls_iterations) == (mjx_backend.SOLVER_ITERATIONS,
                                                                mjx_backend.LS_ITERATIONS)
  full = capped.tree_replace({"opt.iterations": int(scene.model.opt.iterations),
                              "opt.ls_iterations": int(scene.model.opt.ls_iterations)})
  assert full.opt.iterations > capped.opt.iterations and full.opt.ls_iterations > capped.opt.ls_iterations

  def forward(mx):
    def one(d):
      d = mjx_collision.forward(mx, d)
      return d.qacc, (d._impl.contact.dist < 0).sum()  # pylint: disable=protected-access
    return jax.jit(jax.vmap(one))
  for seconds in TIMES:
    qpos, qvel = _states(scene.model, seconds)
    d = backend.make_data(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
    d = d.replace(xfrc_applied=jnp.zeros_like(d.xfrc_applied))
    qacc_capped = np.asarray(forward(capped)(d)[0])
    qacc_full, touching = (np.asarray(x) for x in forward(full)(d))
    assert np.isfinite(qacc_full).all()
    assert touching.min() >= 4, (seconds, touching)  # every world is in contact: the solver has work
    scale = np.abs(qacc_full).max(axis=1, keepdims=True)
    error = (np.abs(qacc_capped - qacc_full) / np.maximum(scale, 1e-6)).max()
    assert error <= QACC_TOLERANCE, (seconds, error)
