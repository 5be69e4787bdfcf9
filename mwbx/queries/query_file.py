"""Query sets from YAML files.

```yaml
camera: {mjcf: front}          # default camera: an MJCF camera of the scene,
#   or {eye: [x, y, z], target: [x, y, z], up: [0, 0, 1], fovy: 45,
#       aspect: 1.333, orthographic: false}
queries:
  - name: ends_in_left_bin
    box: [0.05, 0.75, 0.3, 0.95]   # screen box [u0, v0, u1, v1], origin top-left
    near: 0.5                      # optional, metres along the view axis
    far: 10
    sign: include                  # include | exclude
    bodies: [ball]                 # body, object or group names (default: all)
    mode: any                      # any | all
    window: [2.0, null]            # seconds, null = open end (default: whole path)
    radius: auto                   # metres or auto (default 0: the COM point)
    shape: com                     # com | geometry (any point of the bodies' geoms; radius 0)
  - name: never_on_ramp
    region: {min: [-1, -0.3, 0.9], max: [0, 0.3, 1.3]}   # a world box instead
    sign: exclude
  - name: bucket_tips_forward
    joint: bucket_hinge            # a hinge/slide joint's change over the window
    turn: [0.5, null]              # radians (metres): at least +0.5 (null: open)
    of: max                        # change (t1 vs t0, default) | max | min over the window
    window: [0.0, null]
  - name: ball_ends_upright
    bodies: [ball]
    upright: z                     # a body axis that points up (world +z), or
    #   {axis: z, up: [0, 0, 1]} (axis and up: x, y, z, -x, ... or [x, y, z])
    within_deg: 15                 # degrees
    window: [4.0, null]            # optional: at every frame in it (default: the last frame)
  - name: ball_as_placed
    bodies: [ball]
    orientation: initial           # or a quaternion [w, x, y, z]
    within_deg: 10
rank:                              # optional default ranking
  - {metric: angular_travel, bodies: [ball], reduce: sum, weight: 1.0}
  - {metric: orientation_error, query: ball_ends_upright}   # an orientation query's error
order: desc                        # desc | asc
top: 10
```
"""

from __future__ import annotations

import os
from typing import Literal, NamedTuple, Union

import pydantic
import yaml

from mwbx import yaml_input
from mwbx.errors import MwbxError
from mwbx.files import write_atomic
from mwbx.queries.camera import Camera
from mwbx.queries.camera import ScreenBox
from mwbx.queries.metrics import Term
from mwbx.queries.metrics import parse_term
from mwbx.queries.joint import JointQuery
from mwbx.queries.joint import joint_column
from mwbx.queries.orientation import OrientationQuery
from mwbx.queries.query import Query

_STRICT = pydantic.ConfigDict(extra="forbid")
Vec3 = tuple[float, float, float]


class _MjcfCamera(pydantic.BaseModel):
  model_config = _STRICT
  mjcf: str
  aspect: float | None = None


class _LookAtCamera(pydantic.BaseModel):
  model_config = _STRICT
  eye: Vec3
  target: Vec3
  up: Vec3 = (0.0, 0.0, 1.0)
  fovy: float = 45.0
  aspect: float = 4.0 / 3.0
  orthographic: bool = False


_CameraSpec = Union[_MjcfCamera, _LookAtCamera]


class _Region(pydantic.BaseModel):
  model_config = pydantic.ConfigDict(extra="forbid", populate_by_name=True)
  lo: Vec3 = pydantic.Field(alias="min")
  hi: Vec3 = pydantic.Field(alias="max")


class _Upright(pydantic.BaseModel):
  model_config = _STRICT
  axis: str | Vec3
  up: str | Vec3 = "z"


class _QuerySpec(pydantic.BaseModel):
  model_config = _STRICT
  name: str = ""
  box: tuple[float, float, float, float] | None = None
  region: _Region | None = None
  camera: _CameraSpec | None = None
  near: float | None = None
  far: float | None = None
  sign: Literal["include", "exclude"] = "include"
  bodies: str | list[str] | None = None
  mode: Literal["any", "all"] = "any"
  window: tuple[float | None, float | None] | None = None
  radius: float | Literal["auto"] = 0.0
  joint: str | None = None
  turn: tuple[float | None, float | None] | None = None
  of: Literal["change", "max", "min"] | None = None
  shape: Literal["com", "geometry"] = "com"
  upright: str | Vec3 | _Upright | None = None
  orientation: Literal["initial"] | tuple[float, float, float, float] | None = None
  within_deg: float | None = None


class _TermSpec(pydantic.BaseModel):
  model_config = _STRICT
  metric: str
  bodies: str | list[str] | None = None
  reduce: Literal["sum", "max"] = "sum"
  weight: float = 1.0
  query: str | None = None


class _FileSpec(pydantic.BaseModel):
  model_config = _STRICT
  camera: _CameraSpec | None = None
  queries: list[_QuerySpec] = []
  rank: list[str | _TermSpec] | str | None = None
  order: Literal["desc", "asc"] = "desc"
  top: int | None = pydantic.Field(default=None, ge=0)


class QuerySet(NamedTuple):
  """A loaded query file.

  queries: the constraints (their conjunction). rank: the default ranking
  terms, () if none. descending: order of the ranking. top: default number
  of worlds to list, or None. path: the file.

  Example::

    qs = QuerySet((Query.screen(camera, [0.1, 0.2, 0.3, 0.4], bodies="ball"),))
    qs.save("out/my_queries.yaml")        # mwbx query BANK out/my_queries.yaml
  """

  queries: tuple[Query, ...]
  rank: tuple[Term, ...] = ()
  descending: bool = True
  top: int | None = None
  path: str = ""

  def to_dict(self) -> dict:
    """The query file's contents (see this module's docstring)."""
    out: dict = {"queries": [_query_dict(q, i) for i, q in enumerate(self.queries)]}
    if self.rank:
      out["rank"] = [{"metric": t.metric, "bodies": None if t.bodies is None else list(t.bodies),
                      "reduce": t.reduce, "weight": float(t.weight)}
                     | ({} if t.query is None else {"query": t.query.name}) for t in self.rank]
    out["order"] = "desc" if self.descending else "asc"
    if self.top is not None:
      out["top"] = int(self.top)
    return out

  def save(self, path: str | os.PathLike) -> str:
    """Writes the set as a query file that :func:`load_queries` (and ``mwbx
    query``) read back to the same queries; returns the path."""
    path = os.fspath(path)
    text = "# mwbx query file (QuerySet.save)\n" + yaml.safe_dump(self.to_dict(), sort_keys=False,
                                                                  default_flow_style=None)
    write_atomic(os.path.abspath(path), text, "query file")  # a reader never sees half a file
    return path


def _camera_dict(camera: Camera) -> dict:
  """An MJCF camera by name; any other as look-at (its own axes, exactly)."""
  if camera.name:
    return {"mjcf": camera.name, "aspect": float(camera.aspect)}
  return {"eye": [float(x) for x in camera.eye], "target": [float(x) for x in camera.eye + camera.forward],
          "up": [float(x) for x in camera.up], "fovy": float(camera.fovy), "aspect": float(camera.aspect),
          "orthographic": bool(camera.orthographic)}


def _query_dict(q: Query, index: int) -> dict:
  out: dict = {"name": q.name or f"q{index}"}  # the name load_queries gives an unnamed one
  if isinstance(q, OrientationQuery):
    return q.to_dict() | out
  if isinstance(q, JointQuery):
    out.update(joint=q.joint, turn=list(q.turn), of=q.of)
    if q.window is not None:
      out["window"] = list(q.window)
    return out
  if q.box is not None and q.camera is not None:
    out["box"] = [float(q.box.u0), float(q.box.v0), float(q.box.u1), float(q.box.v1)]
    out["camera"] = _camera_dict(q.camera)
    if q.near is not None:
      out["near"] = float(q.near)
    if q.far is not None:
      out["far"] = float(q.far)
  elif q.world_box is not None:
    out["region"] = {"min": list(q.world_box[0]), "max": list(q.world_box[1])}
  else:
    raise MwbxError(f"queries[{index}]: a query built from raw planes cannot be saved "
                    f"(build it with Query.screen or Query.region)")
  out["sign"] = q.sign
  if q.bodies is not None:
    out["bodies"] = list(q.bodies)
  out["mode"] = q.mode
  if q.window is not None:
    out["window"] = list(q.window)
  out["radius"] = q.radius
  if q.shape != "com":
    out["shape"] = q.shape
  return out


def _location(loc) -> str:
  out = ""
  for part in loc:
    if isinstance(part, int):
      out += f"[{part}]"
    elif part in ("_MjcfCamera", "_LookAtCamera", "_TermSpec", "_Upright", "str") or "[" in str(part):
      continue  # pydantic's union-member labels
    else:
      out += f".{part}" if out else str(part)
  return out or "(top level)"


def _camera(spec, where: str, path: str, model) -> Camera:
  try:
    if isinstance(spec, _MjcfCamera):
      if model is None:
        raise MwbxError(f"MJCF camera {spec.mjcf!r} needs the scene: pass the bank")
      return Camera.from_model(model, spec.mjcf, spec.aspect)
    return Camera.look_at(spec.eye, spec.target, spec.up, spec.fovy, spec.aspect,
                          spec.orthographic)
  except MwbxError as err:
    raise MwbxError(f"{path}: {where}: {err}") from None


def load_queries(path: str | os.PathLike, bank=None, model=None) -> QuerySet:
  """Reads a query file (format in this module's docstring).

  Args:
    path: the YAML file.
    bank: the bank the queries are for: supplies MJCF cameras and checks
      body, object and group names now rather than at evaluation.
    model: an MjModel for MJCF cameras when no bank is given.

  Returns:
    QuerySet. Errors name the file and the field (e.g. `queries[2].box`).
  """
  path = os.fspath(path)
  try:
    with open(path) as f:
      text = f.read()
  except OSError as err:
    raise MwbxError(f"{path}: cannot read query file ({err.strerror})") from None
  except UnicodeDecodeError as err:
    raise MwbxError(f"{path}: not a text file ({err.reason})") from None
  raw = yaml_input.load(text, path, malformed="not valid YAML")
  if raw is None:
    raw = {}
  if not isinstance(raw, dict):
    raise MwbxError(f"{path}: expected a mapping with 'queries', got {type(raw).__name__}")
  try:
    spec = _FileSpec.model_validate(raw)
  except pydantic.ValidationError as err:
    # With unions, the deepest error is the one about the intended member.
    first = max(err.errors(), key=lambda e: len(e["loc"]))
    raise MwbxError(f"{path}: {_location(first['loc'])}: {first['msg']}"
                    f" (got {yaml_input.short_repr(first.get('input'))})") from None
  if model is None and bank is not None:
    model = bank.model()
  default_camera = None if spec.camera is None else _camera(spec.camera, "camera", path, model)
  queries = []
  for i, q in enumerate(spec.queries):
    queries.append(_query(q, i, path, default_camera, model, bank))
  terms = _terms(spec.rank, path, bank, queries)
  return QuerySet(tuple(queries), terms, spec.order == "desc", spec.top, path)


def _query(q: _QuerySpec, i: int, path: str, default_camera, model, bank) -> Query:
  where = f"queries[{i}]"
  if q.joint is not None or q.turn is not None or q.of is not None:
    return _joint_query(q, where, path, model)
  if q.upright is not None or q.orientation is not None or q.within_deg is not None:
    return _orientation_query(q, where, path, bank)
  if (q.box is None) == (q.region is None):
    raise MwbxError(f"{path}: {where}: give exactly one of 'box' (screen) or 'region' (world)")
  fields = dict(bodies=q.bodies, sign=q.sign, mode=q.mode, window=q.window,
                radius=q.radius, name=q.name or f"q{i}", shape=q.shape)
  try:
    if q.box is not None:
      camera = default_camera if q.camera is None else _camera(q.camera, f"{where}.camera",
                                                               path, model)
      if camera is None:
        raise MwbxError("a screen box needs a camera (top-level 'camera' or the query's own)")
      query = Query.screen(camera, ScreenBox(*q.box), near=q.near, far=q.far, **fields)
    else:
      if q.near is not None or q.far is not None or q.camera is not None:
        raise MwbxError("'near', 'far' and 'camera' apply to screen boxes, not to a region")
      query = Query.region(q.region.lo, q.region.hi, **fields)
  except MwbxError as err:
    if str(err).startswith(path):
      raise
    raise MwbxError(f"{path}: {where}: {err}") from None
  if bank is not None and query.bodies:
    try:
      bank.select_bodies(list(query.bodies))
    except MwbxError as err:
      raise MwbxError(f"{path}: {where}.bodies: {err}") from None
  return query


def _joint_query(q: _QuerySpec, where: str, path: str, model) -> JointQuery:
  spatial = [name for name in ("box", "region", "camera", "near", "far", "bodies") if getattr(q, name) is not None]
  if spatial or q.sign != "include" or q.mode != "any" or q.radius != 0.0:
    extra = spatial + [n for n, bad in (("sign", q.sign != "include"), ("mode", q.mode != "any"),
                                        ("radius", q.radius != 0.0)) if bad]
    raise MwbxError(f"{path}: {where}: a joint query takes joint, turn, of, window and name, not "
                    f"{', '.join(extra)}")
  if q.joint is None or q.turn is None:
    raise MwbxError(f"{path}: {where}: a joint query needs both 'joint' and 'turn' ([lo, hi])")
  try:
    query = JointQuery(q.joint, q.turn, q.window, q.name or where, q.of or "change")
    if model is not None:
      joint_column(model, q.joint)
  except MwbxError as err:
    raise MwbxError(f"{path}: {where}: {err}") from None
  return query


def _orientation_query(q: _QuerySpec, where: str, path: str, bank) -> OrientationQuery:
  spatial = [name for name in ("box", "region", "camera", "near", "far") if getattr(q, name) is not None]
  if spatial or q.radius != 0.0 or q.shape != "com":
    extra = spatial + [n for n, bad in (("radius", q.radius != 0.0), ("shape", q.shape != "com")) if bad]
    raise MwbxError(f"{path}: {where}: an orientation query takes bodies, upright or orientation, "
                    f"within_deg, window, sign, mode and name, not {', '.join(extra)}")
  if (q.upright is None) == (q.orientation is None):
    raise MwbxError(f"{path}: {where}: an orientation query needs exactly one of 'upright' "
                    f"(a body axis) or 'orientation' (a quaternion or 'initial')")
  if q.within_deg is None:
    raise MwbxError(f"{path}: {where}: an orientation query needs 'within_deg' (degrees)")
  upright = _Upright(axis=q.upright) if isinstance(q.upright, (str, tuple)) else q.upright
  fields = dict(bodies=q.bodies, within_deg=q.within_deg, window=q.window, sign=q.sign, mode=q.mode,
                name=q.name or where)
  try:
    if upright is not None:
      query = OrientationQuery(axis=upright.axis, up=upright.up, **fields)
    else:
      query = OrientationQuery(target=q.orientation, **fields)
    if bank is not None and query.bodies:
      bank.select_bodies(list(query.bodies))
  except MwbxError as err:
    raise MwbxError(f"{path}: {where}: {err}") from None
  return query


def _terms(rank, path: str, bank, queries=()) -> tuple[Term, ...]:
  if rank is None:
    return ()
  if isinstance(rank, str):
    rank = [rank]
  terms = []
  for i, t in enumerate(rank):
    try:
      if isinstance(t, str):
        term = parse_term(t)
      else:
        bodies = (t.bodies,) if isinstance(t.bodies, str) else t.bodies
        term = Term(t.metric, None if bodies is None else tuple(bodies), t.reduce, t.weight,
                    _named_orientation(t, queries))
      if bank is not None and term.query is None:
        known = tuple(bank.metric_names) + ("constraints_satisfied",)
        if term.metric not in known:
          raise MwbxError(f"unknown metric {term.metric!r} (known: {', '.join(known)})")
        if term.bodies:
          bank.select_bodies(list(term.bodies))
    except MwbxError as err:
      raise MwbxError(f"{path}: rank[{i}]: {err}") from None
    terms.append(term)
  return tuple(terms)


def _named_orientation(term: _TermSpec, queries) -> OrientationQuery | None:
  """The orientation query a rank term names (its error is the metric), or None."""
  if term.query is None:
    return None
  if term.metric != "orientation_error":
    raise MwbxError(f"'query' names an orientation query for metric orientation_error, not {term.metric!r}")
  named = [q for q in queries if isinstance(q, OrientationQuery) and q.name == term.query]
  if not named:
    known = [q.name for q in queries if isinstance(q, OrientationQuery)]
    raise MwbxError(f"no orientation query named {term.query!r} (orientation queries: "
                    f"{', '.join(known) or 'none'})")
  return named[0]
