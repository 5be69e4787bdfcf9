"""YAML scene configs -> validated, frozen config objects.

A config names an MJCF file, which of its objects to randomize and how, and the
sampling, rest, perturbation and codec parameters. Every field has a default
except ``scene.mjcf``. Unknown keys and wrong types are rejected with a message
naming the file and the field path (``perturb.alpha``).

Example::

  scene:
    mjcf: quickstart.xml          # relative to this file, else a packaged asset
    groups: {balls: [ball_a, ball_b]}
  randomize:
    balls:
      position: {dist: uniform, scale: [0.05, 0.05, 0.0]}
  sim: {end_time: 4.0, backend: auto}
"""

from __future__ import annotations

import hashlib
import json
import math
import pathlib
import typing
from typing import Literal

import numpy as np
import pydantic

from mwbx import yaml_input
from mwbx.codec import polyline
from mwbx.codec.layout import CodecBounds
from mwbx.errors import MwbxError

ASSET_DIR = pathlib.Path(__file__).parent / "assets"

Vec3 = tuple[float, float, float]


class _Strict(pydantic.BaseModel):
  # NaN and infinities are refused in every float field (a scale of .nan made
  # every world unstable; an end_time of .inf overflowed the frame count).
  model_config = pydantic.ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

  @pydantic.field_validator("*", mode="before")
  @classmethod
  def _no_booleans_as_numbers(cls, value, info):
    # Lax pydantic reads `end_time: true` as 1.0 s; YAML's true/false are never numbers here.
    if _holds_bool(value) and not _admits_bool(cls.model_fields[info.field_name].annotation):
      raise ValueError("expected a number (true/false are not numbers)")
    return value


def _holds_bool(value) -> bool:
  """A YAML boolean, alone or in a list of values."""
  if isinstance(value, (list, tuple)):
    return any(isinstance(v, bool) for v in value)
  return isinstance(value, bool)


def _admits_bool(annotation) -> bool:
  """Whether a field's type (or a member of its union) is ``bool``."""
  return annotation is bool or any(_admits_bool(a) for a in typing.get_args(annotation))


class Distribution(_Strict):
  """A random offset about ``mean`` (default 0).

  ``uniform``: each component uniform in ``[mean - scale, mean + scale]``;
  ``normal``: each component normal with standard deviation ``scale``.
  ``scale`` and ``mean`` are a scalar (all components) or one value per
  component (e.g. a push: ``linear_velocity: {mean: [0, 1, 0], scale: 0.2}``).
  """

  dist: Literal["uniform", "normal"] = "uniform"
  scale: float | tuple[float, ...] = 0.0
  mean: float | tuple[float, ...] = 0.0


class Randomization(_Strict):
  """Initial-condition noise for one object (or every object of a group).
  For a flex, position and linear velocity move all of its vertices alike,
  rotation and angular velocity turn them about their mean (world frame);
  joint_noise is refused.

  Attributes:
    position: offset of the root position, metres (3 components).
    rotation: axis-angle rotation of the root orientation, radians (3).
    linear_velocity: root linear velocity added, m/s (3).
    angular_velocity: root angular velocity added, rad/s (3).
    joint_noise: offset added to every hinge/slide/ball joint of the object,
      radians or metres (1 component, or one per hinge/slide joint).
  """

  position: Distribution | None = None
  rotation: Distribution | None = None
  linear_velocity: Distribution | None = None
  angular_velocity: Distribution | None = None
  joint_noise: Distribution | None = None


class SceneSection(_Strict):
  """Which MJCF, which objects, which bodies are tracked.

  Attributes:
    mjcf: path of the MJCF file, relative to the config file; if no such file
      exists, the packaged asset of that name (``mwbx/assets``).
    objects: root bodies (children of the world body) and flexes (by their
      MJCF name) to treat as objects; default every non-static tree and flex.
    track: bodies tracked for queries and metrics; default every body of
      every object.
    groups: named sets of objects (or other groups); a member with ``*``, ``?``
      or ``[`` is a shell-style pattern over object names (``block_*``).
  """

  mjcf: str
  objects: tuple[str, ...] | None = None
  track: tuple[str, ...] | None = None
  groups: dict[str, tuple[str, ...]] = {}


class MjxSection(_Strict):
  """Contact budgets of the batched engines (``backend: mjx``); see
  :mod:`mwbx.batch_sim.contact_budget`. A value left out is sized by a short
  native pilot run: ``headroom`` × the most that any pilot frame needed.
  Also MuJoCo Warp's solver settings (``solver``, ``tolerance``,
  ``iterations``; :mod:`mwbx.batch_sim.warp_solver`).

  Attributes:
    max_contact_points: impl jax: contacts kept per condim group per world.
    max_geom_pairs: impl jax: geom pairs kept per collision-function group.
    nconmax: impl warp: contacts per world.
    njmax: impl warp: constraint rows per world.
    headroom: budget over the pilot's peak (at least 1).
    pilot_worlds: worlds the pilot runs on the native backend.
    pack_rows: impl jax: solve each world over its own constraint rows in
      use (:mod:`mwbx.batch_sim.mjx_packed_solve`), 2-3.5x as fast as over
      every budget row on SIGGRAPH on a CPU; false: MJX's solve over every
      row (the same accelerations to float32 rounding); null (default): on
      where MJX runs on CPU devices, off on GPUs (not measured there). No
      effect on impl warp.
    solver: impl warp: MuJoCo Warp's constraint solver. ``auto`` (default):
      CG above ``warp_solver.NEWTON_MAX_NV`` degrees of freedom (Newton keeps
      a dense nv x nv Hessian per world), Newton at or below it;
      ``newton`` or ``cg`` forces one (:mod:`mwbx.batch_sim.warp_solver`).
      No effect on impl jax.
    tolerance: impl warp: the solver's tolerance (positive, below 1). Null
      (default): the model's ``opt.tolerance``, raised to 1e-6 where it is
      smaller (float32 does not reach MuJoCo's default 1e-8: the solver
      would run every iteration of every step). No effect on impl jax.
    iterations: impl warp: the solver's iteration limit per step. Null
      (default): the model's ``opt.iterations``. No effect on impl jax.
  """

  max_contact_points: int | None = pydantic.Field(None, gt=0)
  max_geom_pairs: int | None = pydantic.Field(None, gt=0)
  nconmax: int | None = pydantic.Field(None, gt=0)
  njmax: int | None = pydantic.Field(None, gt=0)
  headroom: float = pydantic.Field(1.5, ge=1.0)
  pilot_worlds: int = pydantic.Field(8, gt=0)
  pack_rows: bool | None = None
  solver: Literal["auto", "newton", "cg"] = "auto"
  tolerance: float | None = pydantic.Field(None, gt=0, lt=1)
  iterations: int | None = pydantic.Field(None, gt=0, le=100_000)


class SimSection(_Strict):
  """Time stepping, recording and batching.

  Attributes:
    timestep: physics step, seconds. Default: the MJCF's own
      ``<option timestep>`` (the physics as its author wrote it).
    end_time: a world stops recording at this time if not at rest, seconds.
    record_fps: rate of the stored ``qpos`` frames, Hz; a frame is a whole
      number of physics steps. Unset (or null): chosen from the timestep,
      nearest to 120 (:mod:`mwbx.rates`; the 120 here is what a timestep
      dividing 1/120 s gets).
    query_fps: rate of the COM polylines used by queries; a whole number of
      frames apart. Unset (or null): chosen nearest to 30.
    backend: ``auto`` (mjx on GPU/TPU, native on CPU), ``mjx`` or ``native``.
    mjx_impl: ``jax``, ``warp`` or ``auto`` (warp when importable on a GPU).
    chunk_size: worlds simulated per batch, then compressed together and
      written as one shard. Native: the threads pull the chunk's worlds one by
      one. MJX: worlds per device, in lockstep (rounded up to whole lanes of
      8; a run needing fewer simulates fewer).
    threads: native backend threads (0: one per CPU core).
    max_speed: a body faster than this (m/s) marks its world unstable.
    sleep: MuJoCo 4's island sleep in the native engine: resting islands
      sleep (no contacts computed inside them, no perturbation), contact
      wakes them, a world whose every island sleeps is at rest and stops.
      ``auto`` (default): on where it is measured to agree with sleep off
      (:mod:`mwbx.batch_sim.sleep`); ``true``/``on`` or ``false``/``off``.
    sleep_tolerance: velocity below which a tree may sleep (MuJoCo's
      ``opt.sleep_tolerance``, m/s or rad/s scaled by ``dof_length``).
      Unset: the MJCF's own (MuJoCo's default 1e-3).
    mjx: contact budgets of the MJX backend (:class:`MjxSection`).
  """

  timestep: float | None = pydantic.Field(None, gt=0)
  end_time: float = pydantic.Field(4.0, gt=0)
  record_fps: float | None = pydantic.Field(120.0, gt=0)
  query_fps: float | None = pydantic.Field(30.0, gt=0)
  backend: Literal["auto", "mjx", "native"] = "auto"
  mjx_impl: Literal["auto", "jax", "warp"] = "auto"
  chunk_size: int = pydantic.Field(256, gt=0, le=1 << 24)
  threads: int = pydantic.Field(0, ge=0, le=4096)
  max_speed: float = pydantic.Field(100.0, gt=0)
  sleep: bool | Literal["auto"] = "auto"
  sleep_tolerance: float | None = pydantic.Field(None, gt=0, lt=1)
  mjx: MjxSection = MjxSection()

  @pydantic.field_validator("sleep", mode="before")
  @classmethod
  def _sleep_words(cls, value):
    # YAML 1.1 reads on/off/yes/no as booleans; the same words quoted mean the same.
    words = {"on": True, "yes": True, "true": True, "off": False, "no": False, "false": False}
    if isinstance(value, str) and value.strip().lower() in words:
      return words[value.strip().lower()]
    if not isinstance(value, bool) and value != "auto":
      raise ValueError("expected auto, true (on) or false (off)")
    return value


class RestSection(_Strict):
  """A world is at rest once every tracked body is slower than both speeds
  for ``duration`` seconds."""

  linear_speed: float = pydantic.Field(0.02, ge=0)
  angular_speed: float = pydantic.Field(0.1, ge=0)
  duration: float = pydantic.Field(0.25, ge=0)


class PerturbSection(_Strict):
  """Plausible impulse perturbations (paper §2).

  Attributes:
    enabled: off gives the plain deterministic simulation (plus randomized
      initial conditions).
    alpha: perturbation magnitude is uniform in ``±alpha·‖Δv‖``.
    lobe_exponent: n of the Phong lobe ``cosⁿθ`` about ``Δv`` for the direction.
    linear_threshold: ``C_v``, m/s²: ``‖Δv‖/dt`` above it is an impact.
    angular_threshold: ``C_ω``, rad/s².
    collision_gap: impacts of a body closer than this (s) count as one
      collision in the metrics (MuJoCo's soft contacts spread an impact over
      several steps and a sliding body chatters).
    exclude: objects, groups or bodies never perturbed.
  """

  enabled: bool = True
  alpha: float = pydantic.Field(0.1, ge=0, le=1)
  lobe_exponent: float = pydantic.Field(20.0, ge=0)
  linear_threshold: float = pydantic.Field(100.0, ge=0)
  angular_threshold: float = pydantic.Field(2000.0, ge=0)
  collision_gap: float = pydantic.Field(0.05, ge=0)
  exclude: tuple[str, ...] = ()


# The codec's rotation bound must stay below 0.5 rad (mwbx.codec.CodecBounds).
MAX_ROTATION_BOUND_DEG = 0.5 * 180.0 / math.pi


class CodecSection(_Strict):
  """Error bounds of the stored trajectories.

  Attributes:
    e_pos: free-joint translations, metres.
    e_rot_deg: rotation angle, degrees (below 0.5 rad = 28.6 degrees).
    e_scalar: hinge (radians) and slide (metres) joints.
    e_com: the COM polylines queries test, metres: stored on a grid of step
      2·e_com (every point within e_com of the simulation; queries are exact
      on the stored points); null keeps them as float32.
  """

  e_pos: float = pydantic.Field(1e-3, gt=0)
  e_rot_deg: float = pydantic.Field(0.5, gt=0, lt=MAX_ROTATION_BOUND_DEG)
  e_scalar: float = pydantic.Field(1e-3, gt=0)
  e_com: float | None = pydantic.Field(5e-4, gt=0)

  def bounds(self) -> CodecBounds:
    """The qpos bounds in the codec's units: ``e_pos`` m, ``e_rot`` rad (from
    ``e_rot_deg``), ``e_scalar`` rad or m; what the compressed store codes
    under and what refinement's ghosts are padded by."""
    return CodecBounds(e_pos=self.e_pos, e_rot=float(np.deg2rad(self.e_rot_deg)), e_scalar=self.e_scalar)

  def com_step(self) -> float | None:
    """The grid step of the stored COM polylines, m (``2·e_com``; None: float32
    paths): sampled and refined worlds alike are rounded to it."""
    return polyline.grid_step(self.e_com)


class ControlSchedule(_Strict):
  """An actuator's control over time: knots ``(times[i], values[i])``.

  Attributes:
    times: knot times, seconds, strictly increasing.
    values: control at each knot (a position actuator's target: radians or
      metres; a motor's force or torque).
    interpolation: ``linear`` between knots, or ``step`` (each value held
      until the next knot). Before the first knot the first value holds, after
      the last the last.
  """

  times: tuple[float, ...] = pydantic.Field(min_length=1)
  values: tuple[float, ...] = pydantic.Field(min_length=1)
  interpolation: Literal["linear", "step"] = "linear"

  @pydantic.model_validator(mode="before")
  @classmethod
  def _fixed(cls, data):
    """A plain number is a control held from time 0."""
    if isinstance(data, (int, float)) and not isinstance(data, bool):
      return {"times": [0.0], "values": [float(data)]}
    return data

  @pydantic.model_validator(mode="after")
  def _knots(self):
    if len(self.times) != len(self.values):
      raise ValueError(f"times has {len(self.times)} knots but values has {len(self.values)}")
    if any(b <= a for a, b in zip(self.times, self.times[1:])):
      raise ValueError(f"times must increase strictly, got {list(self.times)}")
    if not all(math.isfinite(x) for x in self.times + self.values):
      raise ValueError("times and values must be finite")
    return self


class Config(_Strict):
  """A whole sampling config. ``source`` is the YAML file it came from.

  ``controls`` maps actuator names of the MJCF to a :class:`ControlSchedule`
  or a fixed control (a number: held from time 0); actuators not named keep control 0 (MuJoCo's
  default). Both backends, and refinement, apply the same control at every
  physics step (the schedule's value at the step's start time).
  """

  scene: SceneSection
  randomize: dict[str, Randomization] = {}
  controls: dict[str, ControlSchedule] = {}
  sim: SimSection = SimSection()
  rest: RestSection = RestSection()
  perturb: PerturbSection = PerturbSection()
  codec: CodecSection = CodecSection()
  source: str | None = None

  def resolved(self) -> dict:
    """The full config with every default filled in, JSON-able."""
    return self.model_dump(mode="json")

  def mjcf_path(self) -> pathlib.Path:
    """Where the MJCF lives: next to the config, else a packaged asset."""
    base = pathlib.Path(self.source).parent if self.source else pathlib.Path.cwd()
    path = base / self.scene.mjcf
    if path.exists():
      return path
    asset = ASSET_DIR / self.scene.mjcf
    if asset.exists():
      return asset
    raise MwbxError(
        f"{self.source or '<config>'}: scene.mjcf: no file {str(path)!r}"
        f" and no packaged asset {self.scene.mjcf!r}"
    )

  def with_overrides(self, **sim_fields) -> "Config":
    """A copy with some ``sim`` fields replaced (None values are ignored)."""
    fields = {k: v for k, v in sim_fields.items() if v is not None}
    if not fields:
      return self
    return self.model_copy(update={"sim": self.sim.model_copy(update=fields)})

  def digest(self, mjcf_text: str, includes: dict[str, str] | None = None) -> str:
    """sha256 of the resolved config (minus its file name), the MJCF and the
    files it includes."""
    resolved = self.resolved()
    resolved.pop("source", None)
    if resolved["sim"].get("mjx") == MjxSection().model_dump(mode="json"):
      resolved["sim"].pop("mjx")  # banks from before the section keep their digest
    for name, default in (("sleep", "auto"), ("sleep_tolerance", None)):  # likewise for sleep's fields
      if resolved["sim"].get(name, default) == default:
        resolved["sim"].pop(name, None)
    blob = json.dumps(resolved, sort_keys=True) + "\0" + mjcf_text
    for name in sorted(includes or {}):
      blob += "\0" + name + "\0" + includes[name]
    return hashlib.sha256(blob.encode()).hexdigest()


# Validation errors a message lists at most (a long list of bad items would
# otherwise make a message of a line per item).
MAX_ERROR_LINES = 10


def _is_union_branch(part) -> bool:
  """Whether a pydantic error location part names a branch of a union
  (``float``, ``tuple[float, ...]``) rather than a key or index of the input."""
  return isinstance(part, str) and (part in ("float", "int", "str", "bool", "none") or "[" in part)


def _deepest_branches(errors: list[dict]) -> list[dict]:
  """One error per union: pydantic reports every branch a value failed; the
  branch that got deepest into the value says best what is wrong with it
  (``scale: [.nan, 0, 0]`` fails ``float`` at the list and the tuple branch at
  its first item: the second is the useful line)."""
  best: dict[tuple, dict] = {}
  out = []
  for e in errors:
    loc = tuple(e["loc"])
    cut = next((i for i, part in enumerate(loc) if _is_union_branch(part)), None)
    if cut is None:
      out.append(e)
      continue
    key = loc[:cut]
    if key not in best:
      out.append(key)  # placeholder: the union's place in the order
      best[key] = e
    elif len(loc) > len(best[key]["loc"]):
      best[key] = e
  return [best[e] if isinstance(e, tuple) else e for e in out]


def _format_error(source: str, err: pydantic.ValidationError) -> str:
  """One line per error (at most :data:`MAX_ERROR_LINES`): the file, the
  field and what is wrong, never the value found there."""
  lines = []
  errors = _deepest_branches(err.errors())
  for e in errors[:MAX_ERROR_LINES]:
    field = ".".join(str(p) for p in e["loc"] if not _is_union_branch(p)) or "<top>"
    if e["type"] == "extra_forbidden":
      lines.append(f"{source}: {field}: unknown key")
    else:
      # The field, never the value: any file may be named (a secret read as a
      # scene config must not be shown, the page shows errors to everyone).
      lines.append(f"{source}: {field}: {e['msg']}")
  if len(errors) > MAX_ERROR_LINES:
    lines.append(f"{source}: … and {len(errors) - MAX_ERROR_LINES} more errors")
  return "\n".join(lines)


def config_from_dict(data: dict, source: str = "<config>") -> Config:
  """Validates a plain dict (e.g. parsed YAML) into a :class:`Config`."""
  if not isinstance(data, dict):
    raise MwbxError(f"{source}: expected a mapping at the top level, got {type(data).__name__}")
  try:
    return Config.model_validate({**data, "source": source})
  except pydantic.ValidationError as err:
    raise MwbxError(_format_error(source, err)) from None


def load_config(path: str | pathlib.Path) -> Config:
  """Reads and validates a YAML config.

  Args:
    path: the YAML file; a bare name like ``"quickstart"`` also finds the
      packaged config ``mwbx/assets/quickstart.yaml``.

  Returns:
    the validated :class:`Config` (MJCF paths resolve relative to ``path``).

  Raises:
    MwbxError: unreadable file, malformed YAML, unknown key or wrong type; the
      message names the file and the field.
  """
  path = pathlib.Path(path)
  if not path.exists() and (ASSET_DIR / f"{path.name}.yaml").exists():
    path = ASSET_DIR / f"{path.name}.yaml"
  try:
    text = path.read_text()
  except OSError as err:
    raise MwbxError(f"{path}: cannot read config: {err.strerror}") from None
  except UnicodeDecodeError as err:
    raise MwbxError(f"{path}: cannot read config: not a text file ({err.reason})") from None
  data = yaml_input.load(text, str(path))
  return config_from_dict(data if data is not None else {}, source=str(path))
