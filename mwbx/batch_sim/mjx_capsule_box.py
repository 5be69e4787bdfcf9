"""Capsule-box contacts for MJX (impl ``jax``), agreeing with MuJoCo C.

MJX's capsule-convex function (``collision_convex._capsule_convex``, which
MJX uses for capsule-box pairs) returns no contact at all in two cases where
MuJoCo C's ``mjc_CapsuleBox`` returns one or two:

* **The closest edge is picked by distance alone.** When the capsule lies
  parallel to a box edge (SIGGRAPH's pegs and the letters' boxes), the
  closest points fall on a box corner, and every edge through that corner is
  as close; ``argmin`` takes the first, whose faces the capsule is not in
  front of, so the edge contact is dropped as "not shallow".
* **A face is preferred whenever the edge direction is along its normal**,
  even when the capsule lies past that face's rim, where the face gives no
  contact either.

And where a capsule lies along an edge it gives one contact, at one end of
their overlap, where MuJoCo C gives two, one at each end.

Measured on 168 stored SIGGRAPH states (8 worlds, 0.3 to 1.5 s): MuJoCo C
had 439 touching capsule-box pairs with 812 contacts; MJX's function missed
23 pairs (penetrating by 0.7 mm median, up to 3 mm) and gave 718 contacts,
this one misses none and gives 811. Pegs let into the letters' corners
changed where the letters fall: with MJX's function mjx:jax left letter_G1
right of where native does (z 4.1 with 512 worlds per engine), with this
one it agrees (docs/sampling.md, *Engine agreement*).

:func:`capsule_box_contacts` is MJX's function with these changed: the edge
is the closest among those whose faces the capsule is in front of (of edges
equally close, the one the capsule lies along); a face is preferred over an
edge only where the face has a contact; a capsule along the edge gets a
contact at each end of their overlap. The rest (the face clip, positions,
normals, the two contact rows) is MJX's, adapted from
``mujoco/mjx/_src/collision_convex.py`` (Copyright 2023 DeepMind
Technologies Limited, Apache License 2.0).
"""

from __future__ import annotations

import jax
from jax import numpy as jp
from mujoco.mjx._src import collision_convex, math
from mujoco.mjx._src.collision_types import ConvexInfo, GeomInfo

# |cos| between the capsule's axis and a box edge above which the capsule lies
# along the edge (two contacts, at the ends of their overlap).
PARALLEL_COS = 0.99
# Edges whose distances to the capsule's axis differ by less than this are
# equally close (float32 rounding at the box's scale), m.
TIE_DISTANCE = 1e-6


def capsule_box_contacts(cap: GeomInfo, box: ConvexInfo):
  """Up to two contacts of one capsule with one box (``box`` as
  ``mesh.box`` makes it: faces, vertices, edges and their face normals).

  Returns (dist f32[2] m, negative where penetrating, 1 where unused; pos
  f32[2, 3] m, world frame; normal f32[2, 3], from the capsule to the box).
  """
  faces, normals = box.face, box.face_normal
  # The capsule's segment in the box's frame.
  cap_pos = box.mat.T @ (cap.pos - box.pos)
  axis = box.mat.T @ cap.mat[:, 2]
  seg = axis * cap.size[1]
  cap_pts = jp.array([cap_pos - seg, cap_pos + seg])
  radius = cap.size[0]

  # Face contact: the face of least penetration, the segment clipped to it.
  def face_support(face, normal):
    pts = cap_pts - normal * radius
    return jax.vmap(lambda x: jp.dot(x - face[0], normal))(pts).min()

  support = jax.vmap(face_support)(faces, normals)
  has_support = jp.all(support < 0)
  best = support.argmax()
  face, normal = faces[best], normals[best]
  edge_p0 = jp.roll(face, 1, axis=0)
  side_planes = jax.vmap(jp.cross, in_axes=[0, None])(face - edge_p0, normal)
  clipped, mask = collision_convex._clip_edge_to_planes(cap_pts[0], cap_pts[1], edge_p0, side_planes)  # pylint: disable=protected-access
  clipped = clipped - normal * radius
  face_pts = jax.vmap(collision_convex._project_pt_onto_plane, in_axes=[0, None, None])(clipped, face[0], normal)  # pylint: disable=protected-access
  pos = (clipped + face_pts) * 0.5
  contact_normal = -jp.stack([normal] * 2, 0)
  face_penetration = jp.where(mask & has_support, jp.dot(face_pts - clipped, normal), -1)

  # Edge contact: the closest edge among those the capsule is in front of.
  def edge_axis_of(edge):
    edge_pt, cap_pt = math.closest_segment_to_segment_points(edge[0], edge[1], cap_pts[0], cap_pts[1])
    edge_dir = edge_pt - cap_pt
    degenerate = jp.sum(jp.square(edge_dir)) < 1e-6
    edge_axis, edge_dist = math.normalize_with_norm(edge_dir)
    return edge_dist, edge_axis, degenerate, edge_pt, cap_pt

  edges = jp.take(box.vert, box.edge, axis=0).reshape(-1, 2, 3)
  edge_dist, edge_axis, degenerate, edge_pt, cap_pt = jax.vmap(edge_axis_of)(edges)
  in_front = (jp.einsum("eij,ej->ei", box.edge_face_normal, edge_axis) < 0).all(axis=-1)
  shallow = in_front & ~degenerate
  # Of the edges as close as the closest (all edges through a corner, where the
  # closest points fall when the capsule lies along one of them), the one the
  # capsule lies along most.
  closeness = jp.where(shallow, jp.abs(edge_dist), jp.inf)
  tied = closeness <= closeness.min() + TIE_DISTANCE
  edge_dirs = jax.vmap(math.normalize)(edges[:, 1] - edges[:, 0])
  e = jp.where(tied, jp.abs(edge_dirs @ axis), -1.0).argmax()
  edge_dist, edge_axis, degenerate, edge_pt, cap_pt, shallow = (
      x[e] for x in (edge_dist, edge_axis, degenerate, edge_pt, cap_pt, shallow))
  edge_penetration = jp.where(shallow, radius - edge_dist, -1)
  edge_pos = (edge_pt + (cap_pt + edge_axis * radius)) * 0.5
  along_face_normal = (jp.abs(edge_axis.dot(normal)) > 0.99) & ~degenerate
  face_has_contact = (face_penetration > 0).any()
  min_face_penetration = face_penetration.min()
  has_edge_contact = (
      (edge_penetration > 0)
      # the edge where it is shallower than the face contact
      & jp.where(min_face_penetration > 0, edge_penetration < min_face_penetration, True)
      # the face where the edge points along its normal and the face has a contact
      & ~(along_face_normal & face_has_contact)
      & shallow)

  # A capsule along the edge touches it over an interval: a contact at each
  # end of it, as MuJoCo C gives (one at the closest points would put the
  # whole push at one end, a torque the capsule does not give).
  e0, e1 = edges[e]
  edge_dir, edge_len = math.normalize_with_norm(e1 - e0)
  along_edge = jp.abs(edge_dir.dot(axis)) > PARALLEL_COS
  s = jp.clip(jp.sort((cap_pts - e0) @ edge_dir), 0, edge_len)
  ends = e0 + s[:, None] * edge_dir
  on_axis = jax.vmap(math.closest_segment_point, in_axes=[None, None, 0])(cap_pts[0], cap_pts[1], ends)
  end_axis, end_dist = jax.vmap(math.normalize_with_norm)(ends - on_axis)
  end_pos = (ends + on_axis + end_axis * radius) * 0.5
  end_penetration = radius - end_dist
  two_ends = has_edge_contact & along_edge & (s[1] - s[0] > 1e-6)

  edge_pos2 = jp.where(two_ends, end_pos, pos.at[0].set(edge_pos))
  edge_n2 = jp.where(two_ends, end_axis, contact_normal.at[0].set(edge_axis))
  edge_pen2 = jp.where(two_ends, end_penetration, jp.array([edge_penetration, -1]))
  pos = jp.where(has_edge_contact, edge_pos2, pos)
  n = jp.where(has_edge_contact, edge_n2, contact_normal)
  pos = box.pos + pos @ box.mat.T
  n = n @ box.mat.T
  dist = -jp.where(has_edge_contact, edge_pen2, face_penetration)
  return dist, pos, n


@collision_convex.collider(ncon=2)
def capsule_box(cap: GeomInfo, box: ConvexInfo):
  """MJX collision function for (capsule, box) pairs: :func:`capsule_box_contacts`
  with each contact's frame (MJX's ``collision_driver`` signature)."""
  dist, pos, n = capsule_box_contacts(cap, box)
  return dist, pos, jax.vmap(math.make_frame)(n)
