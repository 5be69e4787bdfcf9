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
  - name: ball_hits_box
    touch: [ball, box_a]           # two sides touch (mwbx.queries.event): objects, groups or
    #   named static geoms; a side may be a list (any of them)
    sign: include                  # include | exclude (never touch)
    window: [0.0, 2.0]             # optional
    impulse: [0.5, null]           # optional: only touches this hard (N·s; or force: [lo, hi], N)
  - name: ball_then_floor
    then:                          # touches in order: each first happens after the one before
      - [ball, box_a]
      - [ball, floor]
rank:                              # optional default ranking
  - {metric: angular_travel, bodies: [ball], reduce: sum, weight: 1.0}
  - {metric: orientation_error, query: ball_ends_upright}   # an orientation query's error
  - {metric: hardest_hit, query: ball_hits_box}             # a touch's largest impulse, N·s
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
from mwbx.queries.event import OrderQuery
from mwbx.queries.event import TouchQuery
from mwbx.queries.query import Query
from mwbx.queries.metrics import Term
from mwbx.queries.metrics import parse_term
from mwbx.queries.joint import JointQuery
from mwbx.queries.orientation import OrientationQuery
from mwbx.queries.query import VolumeQuery

# The query types a file may hold, each claiming the entries with its keys; the
# first that claims an entry reads it (VolumeQuery claims what no other does).
QUERY_KINDS: tuple[type[Query], ...] = (TouchQuery, OrderQuery, JointQuery, OrientationQuery, VolumeQuery)

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
  touch: list[str | list[str]] | None = None  # two sides, checked by TouchQuery
  impulse: tuple[float | None, float | None] | None = None  # N·s, checked by TouchQuery
  force: tuple[float | None, float | None] | None = None  # N
  then: list[list[str | list[str]]] | None = None


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

    qs = QuerySet((mwbx.Query.screen(camera, [0.1, 0.2, 0.3, 0.4], bodies="ball"),))
    qs.save("out/my_queries.yaml")        # mwbx query BANK out/my_queries.yaml
  """

  queries: tuple[Query, ...]
  rank: tuple[Term, ...] = ()
  descending: bool = True
  top: int | None = None
  path: str = ""

  def to_dict(self) -> dict:
    """The query file's contents (see this module's docstring)."""
    out: dict = {"queries": [_entry(q, i) for i, q in enumerate(self.queries)]}
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


def _entry(query: Query, index: int) -> dict:
  """A query's file entry, named as load_queries names an unnamed one."""
  try:
    return query.to_dict() | {"name": query.name or f"q{index}"}
  except MwbxError as err:
    raise MwbxError(f"queries[{index}]: {err}") from None


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
    # With unions, the deepest error is the one about the intended member. The
    # message names the field, never the value: a file holding anything (a
    # secret) is refused without showing it (the page shows errors to everyone).
    first = max(err.errors(), key=lambda e: len(e["loc"]))
    raise MwbxError(f"{path}: {_location(first['loc'])}: {first['msg']}") from None
  if model is None and bank is not None:
    model = bank.model
  default_camera = None if spec.camera is None else _camera(spec.camera, "camera", path, model)
  context = FileContext(path, default_camera, model, bank)
  queries = [_query(entry, i, context) for i, entry in enumerate(spec.queries)]
  terms = _terms(spec.rank, path, bank, queries)
  return QuerySet(tuple(queries), terms, spec.order == "desc", spec.top, path)


class FileContext(NamedTuple):
  """What a query type needs to read its entries of one file (:meth:`Query.from_entry`).

  path: the file. default_camera: its top-level camera, or None. model: an
  MjModel for MJCF cameras and joint names, or None. bank: the bank the
  queries are for (checks body, object and group names now), or None.
  """

  path: str
  default_camera: Camera | None
  model: object
  bank: object

  def camera(self, spec, where: str) -> Camera:
    """The camera of a ``camera:`` entry (MwbxError naming the file and ``where``)."""
    return _camera(spec, where, self.path, self.model)

  def check_bodies(self, bodies, where: str, field: bool = True) -> None:
    """MwbxError naming ``where`` (``.bodies`` with ``field``) for a name the bank does not know."""
    if self.bank is None or not bodies:
      return
    try:
      self.bank.select_bodies(list(bodies))
    except MwbxError as err:
      raise MwbxError(f"{self.path}: {where}{'.bodies' if field else ''}: {err}") from None


# The keys that say which kind an entry is, and what each must hold: one set
# to null would otherwise read as absent, and the entry as some other kind.
KIND_KEYS = {
    "box": "a screen box [u0, v0, u1, v1]",
    "region": "a world box {min: [x, y, z], max: [x, y, z]}",
    "joint": "a joint name",
    "upright": "a body axis (x, y, z, -x, ...) or {axis, up}",
    "orientation": "'initial' or a quaternion [w, x, y, z]",
    "touch": "two sides [A, B]",
    "then": "a list of touches in order [[A, B], [C, D], ...]",
}


def _query(entry: _QuerySpec, index: int, context: FileContext) -> Query:
  for key in entry.model_fields_set & KIND_KEYS.keys():
    if getattr(entry, key) is None:
      raise MwbxError(f"{context.path}: queries[{index}].{key}: must be {KIND_KEYS[key]}, got null")
  kind = next(k for k in QUERY_KINDS if k.claims(entry))
  return kind.from_entry(entry, index, context)


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


def _named_orientation(term: _TermSpec, queries) -> Query | None:
  """The query whose error a rank term ranks by (an orientation query's for
  metric orientation_error, a touch query's for hardest_hit), or None."""
  if term.query is None:
    return None
  metrics = [k.error_metric for k in QUERY_KINDS if k.error_metric]
  if term.metric not in metrics:
    raise MwbxError(f"'query' names the query whose error is metric {' or '.join(metrics)}, not {term.metric!r}")
  ranking = [q for q in queries if q.error_metric == term.metric]
  named = [q for q in ranking if q.name == term.query]
  if not named:
    raise MwbxError(f"no {term.metric} query named {term.query!r} (those queries: "
                    f"{', '.join(q.name for q in ranking) or 'none'})")
  return named[0]
