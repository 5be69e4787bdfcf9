"""A flex's surface for the viewers: its triangles from MuJoCo's flex data,
its vertices placed by its vertex bodies' poses.

A cloth (``dim=2``) shows its elements, a soft solid (``dim=3``) its shell
(boundary faces), a rope (``dim=1``) three crossed ribbons along its
segments, each as wide as the rope (its radius either side of its vertices
along a world axis, both faces), so that every renderer that draws triangles
draws it, from any side. A flex whose
vertices are interpolated from node bodies (``dof="trilinear"``) is placed by
its nodes: MuJoCo's ``mj_flex`` puts each vertex at a fixed weighted sum of
the nodes' positions, and those weights are read off ``mj_flex`` itself
(:func:`interpolation_weights`).

Example::

  surfaces = flex_surfaces(model)
  vertices = surfaces[0].vertices(pos, quat)   # pos f64[N, 3], quat f64[N, 4] of surfaces[0].bodies
"""

from __future__ import annotations

from typing import NamedTuple

import mujoco
import numpy as np

from mwbx.queries.poses import quat_rotate
from mwbx.scene import flex_bodies


class FlexSurface(NamedTuple):
  """One flex's surface.

  Attributes:
    name: the flex's (and its object's) name.
    faces: i32[F, 3] triangles over its vertices.
    bodies: i64[V] each drawn vertex's body id (an interpolated flex: i64[N] its
      node bodies).
    offsets: f64[V, 3] each vertex in its body's frame, m (zero when centred;
      an interpolated flex: the constant term of its vertices' positions).
    rgba: f64[4] its colour.
    weights: f64[V, N] an interpolated flex's vertices as weighted sums of its
      nodes' positions; None otherwise.
  """

  name: str
  faces: np.ndarray
  bodies: np.ndarray
  offsets: np.ndarray
  rgba: np.ndarray
  weights: np.ndarray | None = None

  def vertices(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    """f32[V, 3] the vertices in the world, from their bodies' pos f64[V, 3]
    and quat f64[V, 4] (w, x, y, z) (an interpolated flex: its nodes')."""
    pos = np.asarray(pos, np.float64)
    if self.weights is not None:
      return (self.weights @ pos + self.offsets).astype(np.float32)
    return (pos + quat_rotate(np.asarray(quat, np.float64), self.offsets)).astype(np.float32)


def interpolation_weights(model: mujoco.MjModel, f: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """(node body ids i64[N], weights f64[V, N], constant f64[V, 3]) of flex
  ``f``'s interpolated vertices: ``mj_flex`` places vertex v at
  ``weights[v] @ xpos[nodes] + constant[v]``, a linear map of the node bodies'
  positions, measured here by moving each node by a metre."""
  adr, n = int(model.flex_vertadr[f]), int(model.flex_vertnum[f])
  nodes = np.asarray(model.flex_nodebodyid[model.flex_nodeadr[f]:model.flex_nodeadr[f] + model.flex_nodenum[f]],
                     np.int64)
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  mujoco.mj_flex(model, data)
  base = data.flexvert_xpos[adr:adr + n].copy()
  weights = np.zeros((n, len(nodes)))
  for j, body in enumerate(nodes):
    mujoco.mj_kinematics(model, data)
    data.xpos[body, 0] += 1.0
    mujoco.mj_flex(model, data)
    weights[:, j] = data.flexvert_xpos[adr:adr + n, 0] - base[:, 0]
  mujoco.mj_kinematics(model, data)
  return nodes, weights, base - weights @ data.xpos[nodes]


def rope_ribbons(segments: np.ndarray, n_vertices: int, radius: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
  """(faces i32[12 E, 3], copy_of i64[6 V], offsets f64[6 V, 3] m) of a rope's
  ribbons: vertex v copied six times (copy 2k + s at ``(2 s - 1) * radius``
  along world axis k), and for each segment (a, b) i32[E, 2] and axis a quad
  from a's two copies to b's, as two triangles each way round."""
  copy_of = np.repeat(np.arange(n_vertices, dtype=np.int64), 6)
  offsets = np.zeros((n_vertices, 6, 3))
  for k in range(3):
    offsets[:, 2 * k, k], offsets[:, 2 * k + 1, k] = -radius, radius
  a, b = (6 * np.asarray(segments, np.int64)[:, i:i + 1] for i in (0, 1))
  faces = []
  for k in range(3):
    a_lo, a_hi, b_lo, b_hi = a + 2 * k, a + 2 * k + 1, b + 2 * k, b + 2 * k + 1
    faces += [np.hstack([a_lo, a_hi, b_hi]), np.hstack([a_lo, b_hi, b_lo]),   # one side
              np.hstack([a_lo, b_hi, a_hi]), np.hstack([a_lo, b_lo, b_hi])]   # the other
  return np.concatenate(faces).astype(np.int32), copy_of, offsets.reshape(-1, 3)


def flex_surfaces(model: mujoco.MjModel) -> list[FlexSurface]:
  """The drawable surfaces of a model's flexes (see the module)."""
  out = []
  for f in range(model.nflex):
    dim = int(model.flex_dim[f])
    adr, n = int(model.flex_vertadr[f]), int(model.flex_vertnum[f])
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_FLEX, f) or f"flex{f}"
    if dim == 1:
      start, count = int(model.flex_elemdataadr[f]), int(model.flex_elemnum[f])
      faces, copy_of, ribbon = rope_ribbons(model.flex_elem[start:start + 2 * count].reshape(count, 2), n,
                                            float(model.flex_radius[f]))
      bodies = np.asarray(model.flex_vertbodyid[adr:adr + n], np.int64)[copy_of]
      offsets = ribbon + (0.0 if bool(model.flex_centered[f]) else np.asarray(model.flex_vert[adr:adr + n])[copy_of])
      out.append(FlexSurface(name, faces, bodies, offsets, np.asarray(model.flex_rgba[f])))
      continue
    if dim == 2:
      start, count = int(model.flex_elemdataadr[f]), int(model.flex_elemnum[f])
      faces = model.flex_elem[start:start + 3 * count].reshape(count, 3)
    else:
      start, count = int(model.flex_shelldataadr[f]), int(model.flex_shellnum[f])
      faces = model.flex_shell[start:start + 3 * count].reshape(count, 3)
    weights = None
    if int(model.flex_interp[f]):  # vertices interpolated from node bodies
      bodies, weights, offsets = interpolation_weights(model, f)
    else:
      bodies = np.asarray(model.flex_vertbodyid[adr:adr + n], np.int64)
      offsets = (np.zeros((n, 3)) if bool(model.flex_centered[f])
                 else np.asarray(model.flex_vert[adr:adr + n], np.float64))
    out.append(FlexSurface(name, np.asarray(faces, np.int32), bodies, offsets, np.asarray(model.flex_rgba[f]),
                           weights))
  return out


def path_bodies(bank) -> np.ndarray:
  """i64[k] the tracked bodies whose COM paths a viewer draws by default (all, in
  a scene without flexes):
  every tracked body but a flex's vertices, and for each flex one path, its
  centre vertex's (the vertex nearest the mean of its vertices at the
  model's initial configuration), not one per vertex."""
  model = bank.model
  if not model.nflex:
    return np.arange(len(bank.body_names), dtype=np.int64)
  tracked = {int(b): i for i, b in enumerate(np.asarray(bank.body_ids))}
  keep = np.ones(len(tracked), bool)
  centres = []
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  own = flex_bodies(model)
  for surface in flex_surfaces(model):
    bodies = np.asarray(own.get(surface.name, ()), np.int64)  # not the world or a body it is pinned to
    rows = [tracked[int(b)] for b in bodies if int(b) in tracked]
    if not rows:
      continue
    keep[rows] = False
    points = data.xpos[bodies]
    centre = int(bodies[np.argmin(np.linalg.norm(points - points.mean(axis=0), axis=1))])
    if centre in tracked:
      centres.append(tracked[centre])
  return np.sort(np.concatenate([np.flatnonzero(keep), np.asarray(centres, np.int64)])).astype(np.int64)

