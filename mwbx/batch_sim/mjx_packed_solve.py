"""MJX's constraint solve (impl ``jax``) over each world's rows in use only.

A contact budget gives every world the rows of its most crowded moment (588
on SIGGRAPH: 147 contact slots, four pyramidal rows each), and MJX's Newton
solver builds its Hessian from all of them every iteration. A slot without a
contact has a zero Jacobian row: it adds a constant to the cost and nothing
to the Hessian, the gradient or the acceleration. Early in a SIGGRAPH run 51
of 588 rows per world are in use (at most 124 in a world of 64).

:func:`solve_batch` therefore solves each world over its rows packed first
(:func:`solve_rows`: equality, friction and limit rows kept in place, then
the contact rows with a non-zero Jacobian, then zero rows up to the cap), at
the smallest cap of :func:`row_caps` that holds that world's rows in use.
Worlds of one cap are solved a few at a time (``WORLDS_PER_SOLVE``), so
neither the cap nor the shapes a world is solved at depend on the other
worlds of its batch: a world is the same bits in any batch. A cap that holds
every row in use solves the same problem, so the accelerations are MJX's
solve over every row up to float32 rounding
(``tests/batch_sim/test_mjx_packed_solve.py``, against ``solver.solve`` on
all rows); the forces of the rows left out are what the full solve gives a
zero row. Only pyramidal cones are packed (an elliptic cone's rows are
addressed per contact); other models take MJX's solve unchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from mujoco.mjx._src import solver
from mujoco.mjx._src.types import ConeType

# The caps tried, as shares of the budget's rows (the last cap is every row:
# MJX's own solve). A cap is rounded up to whole groups of ROW_GROUP rows.
ROW_CAP_SHARES = (0.125, 0.25, 0.5, 0.75)
ROW_GROUP = 8
# Worlds solved together at one cap. Measured on SIGGRAPH, 64 worlds, 2-core
# x86_64: 4, 8 and 16 took 29, 29 and 36 ms a batched solve with the letters
# heaped (t = 3.0 s), 8 and 16 took 16 and 21 ms in the peg board (0.6 s);
# MJX's solve over every row took 60 and 58.
WORLDS_PER_SOLVE = 8


def _fixed_rows(d) -> int:
  """Rows before the contacts (equality, friction, limits): never packed."""
  impl = d._impl  # pylint: disable=protected-access
  return int(impl.ne + impl.nf + impl.nl)


def row_caps(n_rows: int, n_fixed: int) -> tuple[int, ...]:
  """The caps (rows solved per world) for a budget of ``n_rows`` rows whose
  first ``n_fixed`` are not contacts: increasing, the last ``n_rows``."""
  caps = set()
  for share in ROW_CAP_SHARES:
    contact_rows = -(-int(share * (n_rows - n_fixed)) // ROW_GROUP) * ROW_GROUP
    if 0 < n_fixed + contact_rows < n_rows:
      caps.add(n_fixed + contact_rows)
  return tuple(sorted(caps)) + (n_rows,)


def contact_rows_in_use(d) -> jax.Array:
  """bool[rows - fixed]: one world's contact rows with a non-zero Jacobian."""
  impl = d._impl  # pylint: disable=protected-access
  return jnp.any(impl.efc_J[_fixed_rows(d):] != 0, axis=-1)


def rows_in_use(d) -> jax.Array:
  """i32[]: one world's rows the solve needs: the fixed rows and every
  contact row with a non-zero Jacobian."""
  return _fixed_rows(d) + contact_rows_in_use(d).sum(dtype=jnp.int32)


def solve_rows(m, d, cap: int, in_use: jax.Array | None = None):
  """``solver.solve`` of one world over ``cap`` rows: the fixed rows, then its
  contact rows with a non-zero Jacobian first (``in_use``:
  :func:`contact_rows_in_use`, computed here when None). Exact when ``cap`` >=
  :func:`rows_in_use`; returns ``d`` with every row (forces scattered back)."""
  impl = d._impl  # pylint: disable=protected-access
  n_rows = impl.efc_J.shape[0]
  if cap >= n_rows:
    return solver.solve(m, d)
  fixed = _fixed_rows(d)
  in_use = contact_rows_in_use(d) if in_use is None else in_use
  order = jnp.concatenate([jnp.arange(fixed), fixed + jnp.argsort(~in_use, stable=True)[:cap - fixed]])
  fields = ("efc_J", "efc_D", "efc_aref", "efc_frictionloss", "efc_force")
  packed = d.replace(_impl=impl.replace(nefc=cap, **{f: getattr(impl, f)[order] for f in fields}))
  out = solver.solve(m, packed)
  # A contact row with a zero Jacobian has J qacc - aref = -aref: the full
  # solve's pyramidal force there is D * aref where that is active (< 0).
  left_out = jnp.where(impl.efc_aref > 0, impl.efc_D * impl.efc_aref, 0.0)
  force = left_out.at[order].set(out._impl.efc_force)  # pylint: disable=protected-access
  return out.replace(_impl=impl.replace(efc_force=force))


def solve_batch(m, d):
  """``jax.vmap(solver.solve)`` of a batch (``d``: batched ``mjx.Data``, W
  worlds), each world over the smallest cap of :func:`row_caps` that holds its
  own rows in use (:func:`solve_rows`).

  The worlds of one cap are solved ``WORLDS_PER_SOLVE`` at a time (a
  ``while_loop`` over the groups, a group short of worlds padded with copies
  whose results are dropped), so a world's cap and the shapes it is solved at
  depend on that world alone, never on its companions in the batch: its
  accelerations are the same bits in any batch (tested). Each group's Newton
  loop also stops at its own slowest world, not the batch's. Elliptic cones
  take MJX's solve unchanged.
  """
  impl = d._impl  # pylint: disable=protected-access
  n_worlds, n_rows = impl.efc_J.shape[0], impl.efc_J.shape[-2]
  if m.opt.cone != ConeType.PYRAMIDAL:
    return jax.vmap(solver.solve, in_axes=(None, 0))(m, d)
  fixed = _fixed_rows(d)
  caps = row_caps(n_rows, fixed)
  in_use = jax.vmap(contact_rows_in_use)(d)  # bool[W, rows - fixed]
  rows = fixed + in_use.sum(axis=-1, dtype=jnp.int32)  # i32[W]
  world_cap = jnp.minimum(jnp.searchsorted(jnp.asarray(caps, jnp.int32), rows), len(caps) - 1)  # the first cap >= rows
  group = jnp.arange(WORLDS_PER_SOLVE, dtype=jnp.int32)
  solved = (d.qacc, d.qfrc_constraint, impl.efc_force)  # what the solve writes (not the whole data)
  for k, cap in enumerate(caps):
    members = jnp.argsort(world_cap != k, stable=True).astype(jnp.int32)  # this cap's worlds first
    count = (world_cap == k).sum(dtype=jnp.int32)

    def solve_group(carry, cap=cap, members=members, count=count):
      start, (qacc, qfrc_constraint, efc_force) = carry
      slot = start + group
      real = slot < count
      ids = jnp.where(real, members[jnp.minimum(slot, n_worlds - 1)], members[start])
      out = jax.vmap(solve_rows, in_axes=(None, 0, None, 0))(
          m, jax.tree_util.tree_map(lambda x: x[ids], d), cap, in_use[ids])
      dest = jnp.where(real, ids, n_worlds)  # padding writes nowhere
      put = lambda a, b: a.at[dest].set(b, mode="drop")
      return start + WORLDS_PER_SOLVE, (put(qacc, out.qacc), put(qfrc_constraint, out.qfrc_constraint),
                                        put(efc_force, out._impl.efc_force))  # pylint: disable=protected-access

    _, solved = jax.lax.while_loop(lambda c, count=count: c[0] < count, solve_group, (jnp.int32(0), solved))
  qacc, qfrc_constraint, efc_force = solved
  return d.tree_replace({"qacc": qacc, "qfrc_constraint": qfrc_constraint, "_impl.efc_force": efc_force})
