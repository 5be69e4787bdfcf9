"""Banks of moving shapes with known qpos, and slow obvious references for
whole-geometry and orientation queries: MuJoCo's own kinematics at every
stored frame and dense points on every geom's surface."""

from __future__ import annotations

import dataclasses

import mujoco
import numpy as np

from mwbx import queries as mq
from mwbx.qpos_store import RawQposStore
from queries_bank import FLAG_FINISHED, METRIC_NAMES, StandInBank

SHAPES_XML = """
<mujoco>
  <asset><mesh name="gem" vertex="0.06 0 0  -0.06 0 0  0 0.04 0  0 -0.04 0  0 0 0.08  0 0 -0.05  0.03 0.03 0.03"/></asset>
  <worldbody>
    <camera name="front" pos="0 -4 1" xyaxes="1 0 0 0 0 1" fovy="45"/>
    <geom type="plane" size="5 5 0.1"/>
    <body name="crate" pos="0 0 1"><freejoint/>
      <geom type="box" size="0.12 0.05 0.03" pos="0.05 0 0" euler="0 0 20" mass="0.3"/>
      <geom type="cylinder" size="0.03 0.05" pos="-0.08 0.02 0" euler="90 0 0" mass="0.1"/>
    </body>
    <body name="pill" pos="0.5 0 1"><freejoint/>
      <geom type="capsule" fromto="-0.1 0 0 0.1 0.02 0" size="0.025" mass="0.1"/>
      <geom type="sphere" size="0.04" pos="0 0 0.06" mass="0.05"/>
    </body>
    <body name="gem" pos="-0.5 0 1"><freejoint/><geom type="mesh" mesh="gem" mass="0.1"/></body>
    <body name="upper" pos="0 0.8 1.2"><joint type="ball"/>
      <geom type="capsule" fromto="0 0 0 0 0 -0.2" size="0.02" mass="0.1"/>
      <body name="lower" pos="0 0 -0.2"><joint type="hinge" axis="0 1 0"/>
        <geom type="box" size="0.02 0.02 0.1" pos="0 0 -0.1" mass="0.1"/></body>
    </body>
  </worldbody>
</mujoco>
"""
BODIES = ("crate", "pill", "gem", "upper", "lower")


def _quat_exp(v):
  angle = np.linalg.norm(v, axis=-1, keepdims=True)
  safe = np.where(angle > 1e-12, angle, 1.0)
  return np.concatenate([np.cos(angle / 2), np.sin(angle / 2) * v / safe], axis=-1)


def _qmul(a, b):
  aw, ax, ay, az = np.moveaxis(a, -1, 0)
  bw, bx, by, bz = np.moveaxis(b, -1, 0)
  return np.stack([aw * bw - ax * bx - ay * by - az * bz, aw * bx + ax * bw + ay * bz - az * by,
                   aw * by - ax * bz + ay * bw + az * bx, aw * bz + ax * by - ay * bx + az * bw], -1)


@dataclasses.dataclass
class ShapesBank(StandInBank):
  """A StandInBank over SHAPES_XML whose qpos frames are stored (raw)."""

  qpos_store: object = None
  frames_stored: np.ndarray | None = None

  def __post_init__(self):
    self._xml = SHAPES_XML
    model = self.model
    self.body_names = BODIES
    self.body_ids = np.array([model.body(n).id for n in BODIES], np.int32)
    self.objects = {"crate": ("crate",), "pill": ("pill",), "gem": ("gem",), "arm": ("upper", "lower")}
    self.groups = {"free": ("crate", "pill", "gem")}
    self.world_ids = np.arange(self.com.shape[0], dtype=np.int64) + 100
    self.keys = np.zeros((self.com.shape[0], 2), np.uint32)
    self.frame_count = np.asarray(self.frames_stored, np.int32)


def shapes_bank(n_worlds: int = 12, n_frames: int = 41, seed: int = 0, spin: float = 3.0,
                store=None) -> ShapesBank:
  """Worlds where each body drifts and tumbles smoothly (random speeds), some
  worlds shorter than others; qpos f32 stored raw (or in `store`)."""
  model = mujoco.MjModel.from_xml_string(SHAPES_XML)
  rng = np.random.default_rng(seed)
  t = np.arange(n_frames) / 120.0
  qpos = np.zeros((n_worlds, n_frames, model.nq))
  for name in ("crate", "pill", "gem"):
    adr = model.jnt_qposadr[model.body(name).jntadr[0]]
    p0 = model.body(name).pos + rng.uniform(-0.3, 0.3, (n_worlds, 3))
    v = rng.normal(0, 1.0, (n_worlds, 3))
    qpos[:, :, adr:adr + 3] = p0[:, None] + v[:, None] * t[None, :, None]
    q0 = _quat_exp(rng.normal(0, 1.0, (n_worlds, 3)))
    w = rng.normal(0, spin, (n_worlds, 3))
    qpos[:, :, adr + 3:adr + 7] = _qmul(_quat_exp(w[:, None] * t[None, :, None]), q0[:, None])
  ball = model.jnt_qposadr[model.body("upper").jntadr[0]]
  w = rng.normal(0, spin, (n_worlds, 3))
  qpos[:, :, ball:ball + 4] = _quat_exp(w[:, None] * t[None, :, None])
  hinge = model.jnt_qposadr[model.body("lower").jntadr[0]]
  qpos[:, :, hinge] = rng.uniform(-1, 1, (n_worlds, 1)) * np.sin(spin * t)[None]
  counts = np.full(n_worlds, n_frames, np.int32)
  counts[::3] = max(1, n_frames - 9)  # some worlds end early (the last frame holds)
  return bank_from_qpos(qpos, counts, store)


def bank_from_qpos(qpos, counts=None, store=None, seed: int = 0) -> ShapesBank:
  """A ShapesBank storing qpos f[W, T, nq] (frames past each world's count
  are replaced by its last one), its COM paths at 30 fps from MuJoCo."""
  model = mujoco.MjModel.from_xml_string(SHAPES_XML)
  qpos = np.array(qpos, np.float32)
  n_worlds, n_frames = qpos.shape[:2]
  counts = np.full(n_worlds, n_frames, np.int32) if counts is None else np.asarray(counts, np.int32)
  for w_, c in enumerate(counts):
    qpos[w_, c:] = qpos[w_, c - 1]
  if store is None:
    store = RawQposStore(model.nq)
  store.append(qpos, counts)
  com_rate = 4
  n_points = (n_frames - 1) // com_rate + 1
  com = np.zeros((n_worlds, n_points, len(BODIES), 3), np.float32)
  data = mujoco.MjData(model)
  ids = [model.body(n).id for n in BODIES]
  for w_ in range(n_worlds):
    for k in range(n_points):
      data.qpos[:] = qpos[w_, min(k * com_rate, counts[w_] - 1)]
      mujoco.mj_kinematics(model, data)
      com[w_, k] = data.xipos[ids]
  flags = np.full(n_worlds, FLAG_FINISHED, np.uint8)
  rng = np.random.default_rng(seed)
  metrics = rng.uniform(0, 5, (n_worlds, len(BODIES), len(METRIC_NAMES))).astype(np.float32)
  return ShapesBank(com, flags, metrics, np.full(n_worlds, n_points, np.int32), query_fps=30.0,
                    record_fps=120.0, qpos_store=store, frames_stored=counts)


# ---------------------------------------------------------------------------
# Dense surface points


def random_frustums(rng, n: int, corner=(0.2, 0.7), size=(0.02, 0.2), box_side=(0.05, 0.4)) -> list:
  """``n`` volumes around the shapes bank, in turn: a camera frustum with an
  open far end (clipped to the bank's box), one with near and far planes, and
  an axis-aligned box. Screen boxes start at ``corner`` (u and v each in the
  range) and are ``size`` wide and high; boxes have sides in ``box_side``, m."""
  cam = mq.Camera.look_at((0.3, -3.0, 1.5), (0.0, 0.0, 1.0), fovy=40)
  out = []
  for k in range(n):
    u0, v0 = rng.uniform(*corner, 2)
    box = mq.ScreenBox(u0, v0, u0 + rng.uniform(*size), v0 + rng.uniform(*size))
    if k % 3 == 0:
      out.append(cam.frustum(box))
    elif k % 3 == 1:
      out.append(cam.frustum(box, 2.6 + rng.uniform(0, 0.4), 3.3 + rng.uniform(0, 0.5)))
    else:
      lo = rng.uniform([-0.8, -0.5, 0.6], [0.6, 0.6, 1.2])
      out.append(mq.Frustum.box(lo, lo + rng.uniform(*box_side, 3)))
  return out


def _sphere_points(n: int) -> np.ndarray:
  i = np.arange(n) + 0.5
  phi = np.arccos(1 - 2 * i / n)
  theta = np.pi * (1 + 5 ** 0.5) * i
  return np.stack([np.cos(theta) * np.sin(phi), np.sin(theta) * np.sin(phi), np.cos(phi)], axis=1)


def _grid(n: int) -> np.ndarray:
  return np.linspace(-1.0, 1.0, n)


def _box_points(half, spacing) -> np.ndarray:
  pts = []
  for axis in range(3):
    a, b = [i for i in range(3) if i != axis]
    ua = _grid(max(2, int(np.ceil(2 * half[a] / spacing)) + 1)) * half[a]
    ub = _grid(max(2, int(np.ceil(2 * half[b] / spacing)) + 1)) * half[b]
    A, B = np.meshgrid(ua, ub, indexing="ij")
    for sign in (-1, 1):
      p = np.zeros(A.shape + (3,))
      p[..., axis] = sign * half[axis]
      p[..., a], p[..., b] = A, B
      pts.append(p.reshape(-1, 3))
  return np.concatenate(pts)


def _triangle_points(a, b, c, spacing) -> np.ndarray:
  n = max(1, int(np.ceil(max(np.linalg.norm(b - a), np.linalg.norm(c - a), np.linalg.norm(c - b)) / spacing)))
  out = []
  for i in range(n + 1):
    for j in range(n + 1 - i):
      out.append(a + (b - a) * i / n + (c - a) * j / n)
  return np.array(out)


def surface_points(model, geom: int, spacing: float) -> np.ndarray:
  """f64[N, 3] points on a geom's surface, geom frame, at most `spacing` apart
  (every surface point within about `spacing` of one of them)."""
  kind = int(model.geom_type[geom])
  size = model.geom_size[geom]
  if kind == 2:  # sphere
    r = size[0]
    return r * _sphere_points(max(12, int(4 * np.pi * r * r / spacing ** 2) * 2))
  if kind == 3:  # capsule
    r, h = size[0], size[1]
    caps = r * _sphere_points(max(12, int(4 * np.pi * r * r / spacing ** 2) * 2))
    caps[:, 2] += np.where(caps[:, 2] >= 0, h, -h)
    k = max(8, int(np.ceil(2 * np.pi * r / spacing)))
    ring = np.stack([r * np.cos(2 * np.pi * np.arange(k) / k), r * np.sin(2 * np.pi * np.arange(k) / k)], 1)
    zs = _grid(max(2, int(np.ceil(2 * h / spacing)) + 1)) * h
    side = np.concatenate([np.c_[ring, np.full(k, z)] for z in zs])
    return np.concatenate([caps, side])
  if kind == 6:  # box
    return _box_points(size, spacing)
  if kind == 5:  # cylinder
    r, h = size[0], size[1]
    k = max(8, int(np.ceil(2 * np.pi * r / spacing)))
    ang = 2 * np.pi * np.arange(k) / k
    zs = _grid(max(2, int(np.ceil(2 * h / spacing)) + 1)) * h
    side = np.concatenate([np.c_[r * np.cos(ang), r * np.sin(ang), np.full(k, z)] for z in zs])
    rs = np.linspace(0, r, max(2, int(np.ceil(r / spacing)) + 1))
    disk = np.concatenate([np.c_[q * np.cos(ang), q * np.sin(ang)] for q in rs])
    caps = np.concatenate([np.c_[disk, np.full(len(disk), -h)], np.c_[disk, np.full(len(disk), h)]])
    return np.concatenate([side, caps])
  if kind == 7:  # mesh: its convex hull's surface
    from scipy.spatial import ConvexHull
    m = int(model.geom_dataid[geom])
    v = np.asarray(model.mesh_vert[model.mesh_vertadr[m]:model.mesh_vertadr[m] + model.mesh_vertnum[m]], float)
    hull = ConvexHull(v)
    return np.concatenate([_triangle_points(*v[s], spacing) for s in hull.simplices])
  raise ValueError(f"geom type {kind}")


def body_surface(model, body_id: int, spacing: float) -> list[tuple[int, np.ndarray]]:
  """(geom id, its surface points in the geom frame) for a body's geoms."""
  return [(int(g), surface_points(model, int(g), spacing)) for g in np.flatnonzero(model.geom_bodyid == body_id)]


def world_points(data, geom: int, local: np.ndarray) -> np.ndarray:
  return data.geom_xpos[geom] + local @ data.geom_xmat[geom].reshape(3, 3).T


def stored_frames(bank, row: int, window) -> list[int]:
  """Stored frames of a world at times in the window (its last frame holds
  for times past its end)."""
  n = int(bank.frame_count[row])
  fps = float(bank.record_fps)
  total = max(int(np.max(bank.frame_count)), 1)
  t0, t1 = (None, None) if window is None else window
  out = set()
  for j in range(total):
    t = j / fps
    if (t0 is None or t >= t0) and (t1 is None or t <= t1):
      out.add(min(j, n - 1))
  return sorted(out)


def brute_geometry_hits(bank, frustum, bodies_mask, window, spacing: float) -> np.ndarray:
  """bool[W, B]: some dense surface point of the body inside the volume at
  some stored frame in the window (MuJoCo kinematics, plain loops)."""
  model = bank.model
  data = mujoco.MjData(model)
  surf = {b: body_surface(model, int(bank.body_ids[b]), spacing) for b in np.flatnonzero(bodies_mask)}
  out = np.zeros((bank.n_worlds, len(bank.body_names)), bool)
  for row in range(bank.n_worlds):
    q = bank.qpos_store.row_frames(row)
    for j in stored_frames(bank, row, window):
      data.qpos[:] = q[j]
      mujoco.mj_kinematics(model, data)
      for b, geoms in surf.items():
        if not out[row, b] and any(frustum.contains(world_points(data, g, p)).any() for g, p in geoms):
          out[row, b] = True
  return out & np.asarray(bank.valid, bool)[:, None]


def bound_geometry_hits(bank, index, frustum, bodies_mask, window, spacing: float) -> np.ndarray:
  """bool[W, B]: at some kept frame the window reaches, a dense surface point
  lies in the volume grown by that frame's stated margin (sweep + codec) plus
  the point spacing: every hit the query reports must be here."""
  from mwbx.queries.geometry_query import frame_margins
  model = bank.model
  data = mujoco.MjData(model)
  relevant, margin = frame_margins(index, window)
  surf = {b: body_surface(model, int(bank.body_ids[b]), spacing) for b in np.flatnonzero(bodies_mask)}
  out = np.zeros((bank.n_worlds, len(bank.body_names)), bool)
  for row in range(bank.n_worlds):
    q = bank.qpos_store.row_frames(row)
    for k in np.flatnonzero(relevant):
      data.qpos[:] = q[min(int(index.frames[k]), len(q) - 1)]
      mujoco.mj_kinematics(model, data)
      for b, geoms in surf.items():
        grow = float(margin[b, row, k]) + float(index.codec[b]) + spacing + 1e-6
        if not out[row, b] and any(frustum.contains(world_points(data, g, p), radius=grow).any()
                                   for g, p in geoms):
          out[row, b] = True
  return out & np.asarray(bank.valid, bool)[:, None]
