"""The MJX step's solve over each world's rows in use (mjx_packed_solve) gives
the accelerations and forces of MJX's solve over every row, on the SIGGRAPH
letters in the peg board and piling into the slots, and a world the same bits
whatever else is in its batch."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import mwbx
from conftest import REPO
from mwbx.batch_sim import mjx_backend, mjx_collision, mjx_packed_solve
from mwbx.batch_sim.sampler import resolve_contact_budget
from mujoco.mjx._src import solver

from test_mjx_solver_limits import TIMES, _states

# Packed and full solves minimize one cost (MJX's, over every row) equally well:
# their costs agree to this share (float32's epsilon is 1.2e-7).
COST_TOLERANCE = 1e-6
# A world whose solve stopped with its gradient (rescaled as MJX's stopping test
# rescales it) below this is converged: there both solves' accelerations (and
# constraint forces) agree to QACC_TOLERANCE of the world's largest |qacc|
# (|efc_force|): the same problem, summed in another order in float32.
CONVERGED_GRADIENT = 1e-4
QACC_TOLERANCE = 1e-4
# A heaped world whose cost is flat along a valley stops on MJX's improvement
# test, and where along the valley depends on the summation order: measured on
# the pile at 2.0 s, one world's two solves 2.6e-4 of |qacc| apart at costs
# 1e-7 apart (on jax 0.12.0.1 with tolerance 0, on 0.12.1 with the model's),
# rescaled gradients up to 4.8e-4. Worlds not converged agree to this.
UNCONVERGED_TOLERANCE = 1e-3

# That order is the compiled code's: checked as users compile it (with XLA's
# optimizations mostly off, the pile's world 3 at 2.0 s stopped 5.2e-3 apart).
pytestmark = pytest.mark.usefixtures("xla_optimized")


def test_row_caps():
  assert mjx_packed_solve.row_caps(588, 0) == (80, 152, 296, 448, 588)
  assert mjx_packed_solve.row_caps(100, 10) == (26, 34, 58, 82, 100)
  assert mjx_packed_solve.row_caps(8, 0) == (8,)  # too few rows to pack


@pytest.fixture(scope="module")
def siggraph():
  config = mwbx.load_config(REPO / "configs" / "siggraph.yaml")
  scene = mwbx.Scene(config)
  backend = mjx_backend.backend_for(scene, "jax", resolve_contact_budget(scene, config.sim.mjx))
  return scene, backend


def test_packing_is_the_default(siggraph):
  scene, backend = siggraph
  assert backend.batched_step is mjx_collision.batched_step  # default: each world over its rows in use
  every_row = mjx_backend.backend_for(scene, "jax", backend.budget, pack_rows=False)
  assert every_row.batched_step is not mjx_collision.batched_step  # MJX's solve, world by world


def _world_errors(a, b) -> np.ndarray:
  """f[W]: each world's largest |a - b| as a share of its largest |b|."""
  a, b = np.asarray(a), np.asarray(b)
  return (np.abs(a - b) / np.maximum(np.abs(b).max(axis=-1, keepdims=True), 1e-6)).max(axis=-1)


@jax.jit
def _cost_and_gradient(mx, ready, qacc):
  """f[W] MJX's solver cost at ``qacc`` over every row of ``ready``, and its
  gradient's norm rescaled as MJX's stopping test rescales it."""
  def one(d, q):
    ctx = solver.Context.create(mx, d.replace(qacc=q))
    return ctx.cost, solver._rescale(mx, d, jnp.linalg.norm(ctx.grad))
  return jax.vmap(one)(ready, qacc)


def _assert_same_solution(mx, ready, solved, reference, label):
  """``solved`` minimizes the cost of ``ready`` as well as ``reference`` does,
  with the same accelerations and forces where both solves converged."""
  cost, gradient = map(np.asarray, _cost_and_gradient(mx, ready, solved.qacc))
  cost_ref, gradient_ref = map(np.asarray, _cost_and_gradient(mx, ready, reference.qacc))
  assert (np.abs(cost - cost_ref) <= COST_TOLERANCE * np.abs(cost_ref)).all(), (label, cost, cost_ref)
  converged = np.maximum(gradient, gradient_ref) <= CONVERGED_GRADIENT
  assert converged.mean() >= 0.5, (label, gradient, gradient_ref)  # the tight check is not vacuous
  for name in ("qacc", "efc_force"):
    pick = (lambda d: d.qacc) if name == "qacc" else (lambda d: d._impl.efc_force)
    errors = _world_errors(pick(solved), pick(reference))
    assert (errors[converged] <= QACC_TOLERANCE).all(), (label, name, errors, converged)
    assert (errors <= UNCONVERGED_TOLERANCE).all(), (label, name, errors, converged)


@pytest.mark.parametrize("seconds", TIMES)
def test_packed_step_matches_the_full_step(siggraph, seconds):
  scene, backend = siggraph
  mx = backend.mx
  qpos, qvel = _states(scene.model, seconds)
  d = backend.make_data(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
  d = d.replace(xfrc_applied=jnp.zeros_like(d.xfrc_applied))
  ready = jax.jit(jax.vmap(mjx_collision.before_solve, in_axes=(None, 0)))(mx, d)
  n_rows = ready._impl.efc_J.shape[-2]
  used = np.asarray(jax.vmap(mjx_packed_solve.rows_in_use)(ready))
  caps = mjx_packed_solve.row_caps(n_rows, 0)
  assert 0 < used.max() <= caps[-2], (used, caps)  # a smaller cap is used: the packed path runs
  assert seconds > TIMES[0] or used.max() <= caps[1]  # in the peg board: a quarter of the rows or fewer
  full = jax.jit(jax.vmap(solver.solve, in_axes=(None, 0)))(mx, ready)
  packed = jax.jit(mjx_packed_solve.solve_batch)(mx, ready)
  _assert_same_solution(mx, ready, packed, full, "packed")
  assert packed._impl.efc_J.shape == full._impl.efc_J.shape  # every row kept in the data
  # The smallest cap that holds the rows in use and the largest (every row)
  # give the same answer (each cap is a compile of its own: the ones between
  # add minutes, not coverage). The whole step, packed against every row, is
  # compared in the sampler (test_mjx.py::test_every_row_from_the_config).
  holding = [cap for cap in caps if cap >= used.max()]
  for cap in sorted({holding[0], holding[-1]}):
    solve = jax.vmap(mjx_packed_solve.solve_rows, in_axes=(None, 0, None))
    one = jax.jit(solve, static_argnums=2)(mx, ready, cap)
    _assert_same_solution(mx, ready, one, full, f"cap {cap}")


def test_a_too_small_cap_is_not_chosen(siggraph):
  """A world with more rows in use than a cap takes a larger one (here: a
  world made to use every row by a Jacobian of ones), the others their own."""
  scene, backend = siggraph
  mx = backend.mx
  qpos, qvel = _states(scene.model, TIMES[0])
  d = backend.make_data(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
  ready = jax.jit(jax.vmap(mjx_collision.before_solve, in_axes=(None, 0)))(mx, d)
  dense = ready._impl.efc_J.at[0].set(1e-3)  # world 0: every row non-zero
  ready = ready.replace(_impl=ready._impl.replace(efc_J=dense))
  assert int(jax.vmap(mjx_packed_solve.rows_in_use)(ready).max()) == dense.shape[-2]
  full = jax.jit(jax.vmap(solver.solve, in_axes=(None, 0)))(mx, ready)
  packed = jax.jit(mjx_packed_solve.solve_batch)(mx, ready)
  _assert_same_solution(mx, ready, packed, full, "packed")


def test_a_world_is_the_same_bits_in_any_batch(siggraph):
  """Each world's cap is its own and worlds are solved WORLDS_PER_SOLVE at a
  time, so its solve does not depend on its companions: the batch's worlds
  solved in another order, among copies of one crowded world, or alone
  (a batch of one) give the same accelerations and forces bit for bit."""
  scene, backend = siggraph
  mx = backend.mx
  qpos, qvel = _states(scene.model, TIMES[-1])
  d = backend.make_data(jnp.asarray(qpos, jnp.float32), jnp.asarray(qvel, jnp.float32))
  ready = jax.jit(jax.vmap(mjx_collision.before_solve, in_axes=(None, 0)))(mx, d)
  n_worlds = ready.qacc.shape[0]
  used = np.asarray(jax.vmap(mjx_packed_solve.rows_in_use)(ready))
  caps = mjx_packed_solve.row_caps(ready._impl.efc_J.shape[-2], 0)
  assert len(set(np.searchsorted(caps, used))) > 1  # worlds of several caps: the groups differ
  solve = jax.jit(mjx_packed_solve.solve_batch)
  reference = solve(mx, ready)
  crowded = int(used.argmax())
  for order in (np.arange(n_worlds)[::-1], np.array([crowded] * 9 + list(range(n_worlds))), np.array([1])):
    out = solve(mx, jax.tree_util.tree_map(lambda x, order=order: x[order], ready))
    np.testing.assert_array_equal(np.asarray(out.qacc), np.asarray(reference.qacc)[order])
    np.testing.assert_array_equal(np.asarray(out._impl.efc_force), np.asarray(reference._impl.efc_force)[order])
