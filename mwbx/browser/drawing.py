"""The page's paths and query volumes (viser line segments).

Paths: the selected bodies' COM polylines of every valid world, faint grey,
in the body's own colour where every query holds, red where an exclude query
rejects the world. Volumes: the frustum of every enabled box query.
"""

from __future__ import annotations

import numpy as np

# Each group of paths (faint, matching, excluded) draws at most this many
# segments: an evenly spaced subset of its worlds beyond it, with a count shown.
MAX_PATH_SEGMENTS = 60_000
FAINT_RGB = (185, 185, 185)
EXCLUDE_RGB = (220, 40, 40)
QUERY_RGB = {"include": (40, 200, 60), "exclude": (220, 40, 40)}
EDGES = [(0, 1), (1, 2), (2, 3), (3, 0), (4, 5), (5, 6), (6, 7), (7, 4), (0, 4), (1, 5), (2, 6), (3, 7)]


def draw_paths(server, handles: dict, bank, body_rgb: np.ndarray, bodies: np.ndarray, match: np.ndarray,
               exclude: np.ndarray, only_matches: bool = False) -> dict:
  """Draws the paths of tracked bodies ``bodies`` (i64[k]) for the worlds in
  ``match`` / ``exclude`` (bool[W]) and the other valid ones (faint, unless
  ``only_matches``); ``handles`` keeps what was drawn (replaced next time).
  Each group draws at most MAX_PATH_SEGMENTS segments; returns {group: worlds left out}."""
  com, count = np.asarray(bank.com), np.asarray(bank.com_count)
  valid = np.asarray(bank.valid, bool)
  groups = {"faint": valid & ~match & ~exclude, "match": valid & match, "exclude": valid & exclude}
  if only_matches:
    groups["faint"] = groups["exclude"] = np.zeros_like(valid)
  per_world = max(1, (com.shape[1] - 1) * bodies.size)
  cap = max(1, MAX_PATH_SEGMENTS // per_world)
  left_out = {}
  for name, mask in groups.items():
    rows = np.flatnonzero(mask)
    left_out[name] = max(0, rows.size - cap)
    if left_out[name]:
      rows = rows[np.linspace(0, rows.size - 1, cap).astype(np.int64)]
    old = handles.pop(f"paths/{name}", None)
    if old is not None:
      old.remove()
    if not rows.size or com.shape[1] < 2:
      continue
    pts = com[rows][:, :, bodies]  # [n, P, k, 3]
    seg = np.stack([pts[:, :-1], pts[:, 1:]], axis=-2)  # [n, P-1, k, 2, 3]
    keep = np.arange(com.shape[1] - 1)[None, :] < (count[rows] - 1)[:, None]  # recorded segments only
    seg = seg[keep]  # [m, k, 2, 3]
    if name == "match":
      rgb = np.broadcast_to(body_rgb[bodies][None, :, None, :], seg.shape)
    else:
      rgb = np.broadcast_to(np.asarray(FAINT_RGB if name == "faint" else EXCLUDE_RGB, np.uint8), seg.shape)
    if seg.size:
      handles[f"paths/{name}"] = server.scene.add_line_segments(
          f"/paths/{name}", seg.reshape(-1, 2, 3).astype(np.float32),
          np.ascontiguousarray(rgb, np.uint8).reshape(-1, 2, 3),
          thickness=2.0 if name != "faint" else 1.0, thickness_units="screen")
  return left_out


def draw_frustums(server, handles: dict, entries) -> None:
  """Draws the frustum of every enabled query that has one (green include,
  red exclude); orientation and joint queries draw nothing."""
  for key in [k for k in handles if k.startswith("queries/")]:
    handles.pop(key).remove()
  for i, entry in enumerate(entries):
    q = entry.query
    corners = None if q.frustum is None else q.frustum.corners
    if corners is None or not entry.enabled:
      continue
    seg = np.array([[corners[a], corners[b]] for a, b in EDGES], np.float32)
    colours = np.broadcast_to(np.asarray(QUERY_RGB[q.sign], np.uint8), seg.shape).copy()
    handles[f"queries/q{i}"] = server.scene.add_line_segments(f"/queries/q{i}", seg, colours, thickness=2.0,
                                                              thickness_units="screen")
