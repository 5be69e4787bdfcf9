"""Scenes: the MJCF model, its objects, tracked bodies, groups and the
initial-condition randomization of each world.

An *object* is a kinematic tree hanging off the world body (a free box, a
ragdoll); its name is the name of its root body. A flex (``<flexcomp>``: cloth,
a rope, a soft solid) is one object named as in the MJCF, its bodies its
moving vertex bodies (:func:`find_objects`). *Tracked* bodies are the ones
whose centre-of-mass paths and metrics are recorded. *Groups* name sets of
objects. Every name a config uses is checked here, with a message naming the
config file and field.
"""

from __future__ import annotations

import dataclasses
import functools
import fnmatch
import pathlib
import posixpath
import re
import xml.etree.ElementTree
from typing import Callable, Mapping, Sequence

import jax
import jax.numpy as jnp
import mujoco
import numpy as np

from mwbx import controls
from mwbx import rates as rates_lib
from mwbx import rotations
from mwbx.config import Config, Distribution
from mwbx.errors import MwbxError
from mwbx.joints import JNT_FREE, JNT_HINGE, JNT_SLIDE

# Per tracked body the model gets these sensors, all on the body's inertial
# frame (its centre of mass), in this order. The acceleration sensors give the
# velocity change of the step just taken (MuJoCo integrates qvel += h·qacc), so
# impacts are detected without differencing states; the linear one reports the
# proper acceleration a - gravity (free fall reads zero). The native backend
# computes the same block from the states for free bodies and steps with
# sensors disabled (batch_sim.host_loops.observe_free_bodies).
SENSORS = (
    ("com_pos", mujoco.mjtSensor.mjSENS_FRAMEPOS, 3),
    ("quat", mujoco.mjtSensor.mjSENS_FRAMEQUAT, 4),
    ("lin_vel", mujoco.mjtSensor.mjSENS_FRAMELINVEL, 3),
    ("ang_vel", mujoco.mjtSensor.mjSENS_FRAMEANGVEL, 3),
    ("lin_acc", mujoco.mjtSensor.mjSENS_FRAMELINACC, 3),
    ("ang_acc", mujoco.mjtSensor.mjSENS_FRAMEANGACC, 3),
)
SENSOR_WIDTH = sum(width for _, _, width in SENSORS)  # floats per tracked body
# Offset of each sensor in a tracked body's block, derived from SENSORS: the
# numba twins index sensordata with these (plain ints, constants to numba).
SENSOR_OFFSET = {name: sum(w for _, _, w in SENSORS[:i]) for i, (name, _, _) in enumerate(SENSORS)}
COM_POS = SENSOR_OFFSET["com_pos"]
QUAT = SENSOR_OFFSET["quat"]
LIN_VEL = SENSOR_OFFSET["lin_vel"]
ANG_VEL = SENSOR_OFFSET["ang_vel"]
LIN_ACC = SENSOR_OFFSET["lin_acc"]
ANG_ACC = SENSOR_OFFSET["ang_acc"]


def find_includes(path: pathlib.Path) -> dict[str, str]:
  """Text of every MJCF file ``path`` includes (recursively), by the name its
  ``<include file=…>`` gives; MuJoCo resolves them against the main file's folder.

  Raises:
    MwbxError: naming an included file that cannot be read.
  """
  out: dict[str, str] = {}
  base = path.parent
  pending = [path.read_text()]
  while pending:
    try:
      root = xml.etree.ElementTree.fromstring(pending.pop())
    except xml.etree.ElementTree.ParseError:
      continue  # MuJoCo's own parser reports it, with the line
    for node in root.iter("include"):
      name = node.get("file")
      if name and name not in out:
        try:
          out[name] = (base / name).read_text()
        except OSError as err:
          raise MwbxError(f"{path}: <include file={name!r}>: cannot read {base / name}: {err.strerror}") from None
        pending.append(out[name])
  return out


def stored_includes_only(mjcf_text: str, includes: Mapping[str, str]) -> None:
  """MwbxError if the MJCF (or an included text) includes a file not among
  ``includes``: a model is built only from the texts given with it (a bank's
  own, stored in it), never from a file a (crafted) MJCF names on disk."""
  texts = [("the MJCF", mjcf_text)] + [(repr(k), v) for k, v in includes.items()]
  for where, text in texts:
    try:
      root = xml.etree.ElementTree.fromstring(text)
    except xml.etree.ElementTree.ParseError:
      continue  # named by mjcf_files
    for node in root.iter("include"):
      name = node.get("file")
      if name not in includes:
        raise MwbxError(f"MJCF: {where} includes {name!r}, which is not stored with it; {STORED_ONLY}")


# Elements whose files MuJoCo finds through the compiler's meshdir (height
# fields, skins and flexcomp meshes as meshes are), or through its texturedir;
# either falls back to assetdir. Other files (a <model>'s) are found from the
# folder of the MJCF naming them.
_MESHDIR_TAGS = frozenset({"mesh", "skin", "hfield", "flexcomp"})
_TEXTUREDIR_TAGS = frozenset({"texture"})
_FOLDERS = ("meshdir", "texturedir", "assetdir")
# Files MuJoCo reads while it parses the XML; the others when it compiles.
_PARSED_TAGS = frozenset({"include", "model", "flexcomp"})
STORED_ONLY = "a bank's model is built only from the MJCF text and files stored in it"


@dataclasses.dataclass(frozen=True)
class FileReference:
  """One file an MJCF names: a mesh, texture, height field, skin, ``<model>``, ...

  Attributes:
    tag, attribute, written: its element, the attribute (``file``,
      ``fileright``, ...) and the path as written.
    folder: the folder it is found in, as written: the MJCF's naming it (a
      ``<model>`` file's) and the compiler's ``meshdir``/``texturedir``/``assetdir``.
    name: its path from the main MJCF's folder, normalized
      (``assets/tet.obj``); None where it is absolute or leaves that folder.
  """

  tag: str
  attribute: str
  written: str
  folder: str
  name: str | None

  def __str__(self) -> str:
    where = f" (in folder {self.folder!r})" if self.folder else ""
    return f"<{self.tag} {self.attribute}={self.written!r}>{where}"


def _escapes(path: str) -> bool:
  """A written path that is absolute, or that could be on another system
  (a drive letter, a backslash, a NUL)."""
  return path.startswith("/") or "\\" in path or "\0" in path or re.match(r"[A-Za-z]:", path) is not None


def _resolve(base: str, folder: str, written: str) -> str | None:
  """The path from the main MJCF's folder of ``written`` found in ``folder``
  of an MJCF in folder ``base``; None where it is absolute or leaves that folder."""
  if _escapes(folder) or _escapes(written):
    return None
  name = posixpath.normpath(posixpath.join(base, folder, written))
  return None if name == ".." or name.startswith("../") else name


def _xml_root(text: str | bytes, where: str):
  try:
    return xml.etree.ElementTree.fromstring(text)
  except xml.etree.ElementTree.ParseError as err:
    raise MwbxError(f"MJCF failed to load: {where} is not well-formed XML ({err})") from None


def _references(text: str | bytes, base: str, includes: Mapping[str, str] | None,
                where: str) -> list[FileReference]:
  """The files one MJCF text names (every ``file*`` attribute of every
  element), with the texts of ``includes`` spliced in where it includes them
  (the main MJCF; a ``<model>`` file's ``<include>`` is a file it names)."""
  folders: dict[str, str] = {}
  found = []
  expanded = set()
  stack = [iter([_xml_root(text, where)])]
  while stack:  # document order, without recursion (kinematic trees nest deep)
    node = next(stack[-1], None)
    if node is None:
      stack.pop()
      continue
    if not isinstance(node.tag, str):
      continue
    if node.tag == "include" and includes is not None:
      name = node.get("file")
      if name in includes and name not in expanded:
        expanded.add(name)
        stack.append(iter([_xml_root(includes[name], repr(name))]))
      continue
    if node.tag == "compiler":  # the last one wins, as in MuJoCo
      folders.update({key: node.get(key) for key in _FOLDERS if node.get(key) is not None})
    found.extend((node.tag, key, value) for key, value in node.attrib.items()
                 if key.lower().startswith("file") and value)
    stack.append(iter(node))
  refs = []
  for tag, attribute, written in found:
    folder = ""
    if tag in _MESHDIR_TAGS:
      folder = folders.get("meshdir") or folders.get("assetdir") or ""
    elif tag in _TEXTUREDIR_TAGS:
      folder = folders.get("texturedir") or folders.get("assetdir") or ""
    shown = posixpath.join(base, folder) if base or folder else ""
    refs.append(FileReference(tag, attribute, written, shown, _resolve(base, folder, written)))
  return refs


def _walk_files(mjcf_text: str, includes: Mapping[str, str],
                fetch: Callable[[FileReference], bytes]) -> tuple[dict[str, bytes], set[str]]:
  """(:func:`mjcf_files`, the names of those MuJoCo reads while parsing)."""
  out: dict[str, bytes] = {}
  parsed: set[str] = set()
  pending = [(mjcf_text, "", includes, "the MJCF")]
  while pending:
    text, base, included, where = pending.pop()
    for ref in _references(text, base, included, where):
      if ref.name is None or ref.name not in out:
        out[ref.name] = fetch(ref)
        if ref.tag == "model":  # an MJCF of its own: its files are found from its folder
          pending.append((out[ref.name], posixpath.dirname(ref.name), None, repr(ref.name)))
      if ref.tag in _PARSED_TAGS:
        parsed.add(ref.name)
  return out, parsed


def mjcf_files(mjcf_text: str, includes: Mapping[str, str],
               fetch: Callable[[FileReference], bytes]) -> dict[str, bytes]:
  """Every file the MJCF and its included texts name, and the files the
  ``<model>`` files among them name in turn: name (:attr:`FileReference.name`)
  -> bytes, each given by ``fetch``.

  Raises:
    MwbxError: a reference ``fetch`` refuses (it must refuse those whose name
      is None), or a text that is not well-formed XML, naming it.
  """
  return _walk_files(mjcf_text, includes, fetch)[0]


def find_assets(path: pathlib.Path, mjcf_text: str, includes: Mapping[str, str]) -> dict[str, bytes]:
  """The bytes of every file the MJCF at ``path`` names (meshes, textures,
  height fields, skins, models), read from its folder: a bank stores them.

  Raises:
    MwbxError: a file that cannot be read, or one outside the MJCF's folder
      (an absolute path, or ``..`` past it), which a bank does not store.
  """
  base = path.parent

  def fetch(ref: FileReference) -> bytes:
    if ref.name is None:
      raise MwbxError(f"{ref}: outside the MJCF's folder; a bank stores the files an MJCF names from its"
                      f" folder and below only: move the file there")
    try:
      return (base / ref.name).read_bytes()
    except OSError as err:
      raise MwbxError(f"{ref}: cannot read {base / ref.name}: {err.strerror}") from None

  return mjcf_files(mjcf_text, includes, fetch)


def _stored(assets: Mapping[str, bytes]) -> Callable[[FileReference], bytes]:
  """A :func:`mjcf_files` fetch that finds files in ``assets`` alone."""

  def fetch(ref: FileReference) -> bytes:
    if ref.name is None:
      raise MwbxError(f"MJCF: {ref} names a file outside the bank (an absolute path, or one leaving its"
                      f" folder); {STORED_ONLY}")
    if ref.name not in assets:
      raise MwbxError(f"MJCF: {ref} names {ref.name!r}, which is not stored with it; {STORED_ONLY} (a bank"
                      f" saved before banks stored these files gets them when sampled into again from its config)")
    return assets[ref.name]

  return fetch


def _base_name(name: str) -> str:
  """The name MuJoCo's parser finds a file by: its base name, lower case."""
  return posixpath.basename(name.replace("\\", "/")).lower()


def one_line(err: BaseException) -> str:
  """MuJoCo's multi-line compiler text as one line ("XML Error: …; Element 'geom', line 3")."""
  return "; ".join(line.strip() for line in str(err).splitlines() if line.strip())


def parse_mjcf(mjcf_text: str, base_dir: str | None = None, includes: Mapping[str, str] | None = None,
               assets: Mapping[str, bytes] | None = None) -> mujoco.MjSpec:
  """The MjSpec of MJCF text, built only from the texts and files given:
  nothing is read from disk.

  Args:
    mjcf_text: the MJCF.
    base_dir: the folder it was read from; nothing is read there (the files
      come from ``assets``), kept for the callers that name it.
    includes: file name -> text of every file it includes.
    assets: name (:attr:`FileReference.name`) -> bytes of every other file it
      names: meshes, textures, height fields, skins, ``<model>`` files
      (none by default: such a reference is then refused).

  Raises:
    MwbxError: a file it names that is not given (an include, an asset), or
      an absolute path or one leaving the MJCF's folder, naming it.
    ValueError: MuJoCo's parser error.
  """
  del base_dir
  includes = dict(includes or {})
  assets = {} if assets is None else assets
  stored_includes_only(mjcf_text, includes)
  files, parsed = _walk_files(mjcf_text, includes, _stored(assets))
  # MuJoCo finds the files it reads while parsing (includes, <model> and flexcomp files) by base name
  # alone, and looks on disk for any it does not find there (every file named is looked up while
  # parsing); those it reads when compiling it finds by path. Every file is given both ways.
  parse_vfs = {name: text.encode() for name, text in includes.items()}
  by_base = {_base_name(name): name for name in parse_vfs}
  for name in sorted(files, key=lambda n: (n not in parsed, n)):
    first = by_base.setdefault(_base_name(name), name)
    if first == name:
      parse_vfs[name] = files[name]
    elif name in parsed:
      raise MwbxError(f"MJCF: {first!r} and {name!r} have one file name, by which MuJoCo tells apart the files it"
                      f" reads while parsing; rename one")
  return mujoco.MjSpec.from_string(mjcf_text, include=parse_vfs or None, assets=files or None)


def build_model(mjcf_text: str, tracked: Sequence[str], base_dir: str | None = None,
                includes: Mapping[str, str] | None = None,
                assets: Mapping[str, bytes] | None = None) -> mujoco.MjModel:
  """Compiles the MJCF with the observation sensors of every tracked body,
  from the texts and files given alone (:func:`parse_mjcf`).

  Sensors already in the MJCF are removed so that ``sensordata`` is exactly
  ``f32[B, SENSOR_WIDTH]`` in :data:`SENSORS` order.
  """
  spec = parse_mjcf(mjcf_text, base_dir, includes, assets)
  for sensor in list(spec.sensors):
    spec.delete(sensor)
  for body in tracked:
    for name, sensor_type, _ in SENSORS:
      spec.add_sensor(
          name=f"mwbx_{name}_{body}",
          type=sensor_type,
          objtype=mujoco.mjtObj.mjOBJ_BODY,
          objname=body,
      )
  return spec.compile()


@dataclasses.dataclass(frozen=True)
class ObjectInit:
  """Static description of how one object's initial state is randomized.

  Attributes:
    name: the object.
    free_qpos: qpos address of the root free joint, or -1.
    free_dof: dof address of the root free joint, or -1.
    joint_qpos: i32[k] qpos addresses of its hinge/slide joints.
    position, rotation, linear_velocity, angular_velocity, joint_noise: the
      distributions (None: no noise).
    flex: a flex's :class:`FlexMotion` (its position and velocity fields move
      all of its vertices; rotation and angular velocity are about the mean of
      its vertices at ``qpos0``, in the world frame), else None.
  """

  name: str
  free_qpos: int
  free_dof: int
  joint_qpos: tuple[int, ...]
  position: Distribution | None
  rotation: Distribution | None
  linear_velocity: Distribution | None
  angular_velocity: Distribution | None
  joint_noise: Distribution | None
  flex: "FlexMotion | None" = None


# The randomized quantities of an object, in the order of their keys
# (``split(fold_in(world_key, object_index), 5)[k]`` draws field k).
RANDOMIZED_FIELDS = ("position", "rotation", "linear_velocity", "angular_velocity", "joint_noise")


@dataclasses.dataclass(frozen=True)
class NoiseSlot:
  """One randomized quantity's place in a world's unit noise vector.

  Attributes:
    object: the object's name. field: one of ``RANDOMIZED_FIELDS``.
    start, width: its components are ``unit[start:start + width]``.
    dist: its configured distribution (the quantity is ``mean + scale * unit``).
  """

  object: str
  field: str
  start: int
  width: int
  dist: Distribution


def flex_bodies(model: mujoco.MjModel) -> dict[str, tuple[int, ...]]:
  """Flex name -> ids (ascending) of the moving bodies that carry it: its
  vertex bodies, or the node bodies of an interpolated flex
  (``dof="trilinear"``/``"quadratic"``). Vertices pinned to the world or to a
  static body (no degrees of freedom) are left out, and so are vertices pinned
  to a moving body: MuJoCo gives a pinned vertex the flexcomp's parent body,
  which is not the flex's (it is the parent of the flex's own bodies, or has
  geoms of its own, which a flex's bodies never do). Unnamed flexes get no
  entry here (:func:`find_objects` refuses them)."""
  out: dict[str, tuple[int, ...]] = {}
  for f in range(model.nflex):
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_FLEX, f)
    if not name:
      continue
    verts = model.flex_vertbodyid[model.flex_vertadr[f]:model.flex_vertadr[f] + model.flex_vertnum[f]]
    nodes = model.flex_nodebodyid[model.flex_nodeadr[f]:model.flex_nodeadr[f] + model.flex_nodenum[f]]
    ids = {int(b) for b in np.concatenate([verts, nodes]) if b > 0 and model.body_dofnum[b] > 0}
    pinned_to = {int(model.body_parentid[b]) for b in ids} | {b for b in ids if model.body_geomnum[b] > 0}
    out[name] = tuple(sorted(ids - pinned_to))
  return out


def object_body_mask(model: mujoco.MjModel, names) -> np.ndarray:
  """bool[O, nbody] each named object's bodies (a root body's tree, or a
  flex's vertex bodies: :func:`find_objects`)."""
  objects = find_objects(model, "model")
  mask = np.zeros((len(names), model.nbody), bool)
  for o, name in enumerate(names):
    mask[o, objects[name]] = True
  return mask


def find_objects(model: mujoco.MjModel, source: str) -> dict[str, list[int]]:
  """Every candidate object -> its body ids (ascending), in object order.

  A rigid object is a moving root body (a child of the world body with
  degrees of freedom) and its kinematic tree, named after the root body. A
  flex (``<flexcomp>``) is one object named as in the MJCF, its bodies its
  moving vertex bodies (:func:`flex_bodies`) that do not already belong to a
  rigid object's tree (a flex inside a moving body stays part of that body's
  object); it takes the place its first vertex body would have had. A scene
  without flexes gets exactly the objects, in the order, it always had.

  Raises:
    MwbxError: an unnamed moving root body or flex, a flex named like a root
      body, or no moving bodies at all.
  """
  body_name = lambda i: mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, i)
  rigid_root = lambda i: model.body_parentid[i] == 0 and model.body_dofnum[i] > 0
  flexes = flex_bodies(model)
  unnamed_flex = [f for f in range(model.nflex) if not mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_FLEX, f)]
  if unnamed_flex:
    raise MwbxError(f"{source}: scene.mjcf: flexes need names (flex ids {unnamed_flex})")
  flex_of = {}  # body id -> the flex whose object takes it
  for name, ids in flexes.items():
    for b in ids:
      root = int(model.body_rootid[b])
      if root == b or not rigid_root(root):
        flex_of.setdefault(b, name)
  roots = [i for i in range(1, model.nbody) if rigid_root(i) and i not in flex_of]
  unnamed = [i for i in roots if not body_name(i)]
  if unnamed:
    raise MwbxError(f"{source}: scene.mjcf: moving root bodies need names (body ids {unnamed})")
  clash = sorted(set(flex_of.values()) & {body_name(i) for i in roots})
  if clash:
    raise MwbxError(f"{source}: scene.mjcf: flex {clash[0]!r} has the name of a moving root body; rename one")
  out: dict[str, list[int]] = {}
  for i in range(1, model.nbody):
    if i in flex_of:
      out.setdefault(flex_of[i], []).append(i)
    elif rigid_root(i):
      out[body_name(i)] = [j for j in range(1, model.nbody) if model.body_rootid[j] == i]
  if not out:
    raise MwbxError(f"{source}: scene.mjcf: no moving bodies (nothing hangs off the world body by a"
                    f" joint), so there is nothing to sample")
  return out


@dataclasses.dataclass(frozen=True, eq=False)
class FlexMotion:
  """How a flex moves as a whole: each of its n moving bodies (vertex or node
  bodies, :func:`flex_bodies`) has three slide joints.

  Attributes:
    qpos: i32[n, 3] qpos addresses of each body's slide joints.
    dof: i32[n, 3] their dof addresses.
    to_joints: f64[n, 3, 3] maps a world-frame displacement of a body to its
      slide joints' coordinates (the inverse of their world axes).
    arm: f64[n, 3] each body's position at ``qpos0`` less their mean (the
      centre a flex's ``rotation`` and ``angular_velocity`` turn about).
  """

  qpos: np.ndarray
  dof: np.ndarray
  to_joints: np.ndarray
  arm: np.ndarray


def flex_motion(model: mujoco.MjModel, bodies: Sequence[int]) -> FlexMotion | str:
  """The :class:`FlexMotion` of a flex's bodies, or why it has none (a body
  whose joints are not three independent slides, e.g. ``dof="radial"``)."""
  data = mujoco.MjData(model)
  mujoco.mj_kinematics(model, data)
  qpos, dof, to_joints = [], [], []
  for b in bodies:
    joints = list(range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]))
    axes = data.xaxis[joints].T if joints else np.zeros((3, 0))
    name = mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b)
    if (len(joints) != 3 or any(int(model.jnt_type[j]) != JNT_SLIDE for j in joints)
        or abs(np.linalg.det(axes)) < 1e-6 or model.body_dofnum[model.body_parentid[b]] > 0):
      return (f"its body {name!r} has {len(joints)} joint(s), not three independent slide joints"
              f" off a static parent, so the flex cannot be moved as a whole")
    qpos.append(model.jnt_qposadr[joints])
    dof.append(model.jnt_dofadr[joints])
    to_joints.append(np.linalg.inv(axes))
  pos = data.xpos[list(bodies)]
  return FlexMotion(np.array(qpos, np.int32), np.array(dof, np.int32), np.array(to_joints),
                    pos - pos.mean(axis=0))


class Scene:
  """A loaded scene: model, objects, tracked bodies, groups, randomization.

  Attributes:
    config: the validated config, its ``sim.record_fps``/``sim.query_fps``
      resolved (:mod:`mwbx.rates`).
    rates: the :class:`~mwbx.rates.Rates` it samples at.
    mjcf_text: the MJCF file's text, stored in every bank.
    mjcf_includes: file name -> text of every MJCF file it includes.
    mjcf_assets: name (:attr:`FileReference.name`) -> bytes of every other
      file it names (meshes, textures, ...), stored in every bank: the model
      is built from these, never from files on disk.
    mjcf_dir: the folder the MJCF was read from (None: given as text); its
      files are read once, when the scene is loaded from a config.
    digest: sha256 of the config, the MJCF and its includes.
    model: ``MjModel`` with the observation sensors added.
    object_names: names of the objects (root bodies and flexes).
    flex_objects: the object names that are flexes.
    objects: object name -> tracked body names.
    groups: group name -> object names (nested groups flattened).
    body_names: the B tracked bodies.
    body_ids: i32[B] MuJoCo body ids of the tracked bodies.
    perturbable: bool[B] false for bodies opted out of perturbations
      (``perturb.exclude``) and for every flex body.
    flex_weight: f32[F, B] each flex object's mass fractions over the
      tracked bodies (its vertex or node bodies; rows sum to 1): the flex's
      velocity change is their weighted mean (docs/sampling.md, "Flexes").
    flex_perturbable: bool[F] flexes perturbed as a whole (false where
      ``perturb.exclude`` names every tracked body of it).
  """

  def __init__(self, config: Config, mjcf_text: str | None = None, mjcf_dir: str | None = None,
               mjcf_includes: dict[str, str] | None = None, mjcf_assets: Mapping[str, bytes] | None = None):
    self.config = config
    source = config.source or "<config>"
    if mjcf_text is None:  # the user's own files: read from the MJCF's folder, once
      path = config.mjcf_path()
      self.mjcf_dir = str(path.parent)
      try:
        mjcf_text = path.read_text()
        mjcf_includes = find_includes(path)
      except OSError as err:
        raise MwbxError(f"{source}: scene.mjcf: cannot read {path}: {err.strerror}") from None
      try:
        mjcf_assets = find_assets(path, mjcf_text, mjcf_includes)
      except MwbxError as err:
        raise MwbxError(f"{source}: scene.mjcf: {err}") from None
    else:  # given (a bank's stored text and files): nothing is read from disk
      self.mjcf_dir = mjcf_dir
    self.mjcf_text = mjcf_text
    self.mjcf_includes = dict(mjcf_includes or {})
    self.mjcf_assets = dict(mjcf_assets or {})
    try:
      plain_model = parse_mjcf(mjcf_text, self.mjcf_dir, self.mjcf_includes, self.mjcf_assets).compile()
    except MwbxError as err:
      raise MwbxError(f"{source}: scene.mjcf: {err}") from None
    except Exception as err:  # MuJoCo raises ValueError with the parser's text.
      raise MwbxError(f"{source}: scene.mjcf: MJCF failed to load: {one_line(err)}") from None
    # The rates follow the physics step (never the reverse): the config from
    # here on states them, and so does its digest.
    timestep = config.sim.timestep if config.sim.timestep is not None else float(plain_model.opt.timestep)
    self.rates = rates_lib.resolve(config, timestep)
    self.config = config = rates_lib.with_rates(config, self.rates)
    self.digest = config.digest(mjcf_text, self.mjcf_includes)

    body_name = lambda i: mujoco.mj_id2name(plain_model, mujoco.mjtObj.mjOBJ_BODY, i)
    subtree = find_objects(plain_model, source)  # every candidate object -> its body ids
    object_names = config.scene.objects or tuple(subtree)
    for name in object_names:
      if name not in subtree:
        raise MwbxError(
            f"{source}: scene.objects: {name!r} is not a moving body hanging off the world body"
            f" nor a flex (have: {', '.join(subtree)})"
        )
    self.object_names = tuple(object_names)
    self.flex_objects = tuple(n for n in self.object_names if n in flex_bodies(plain_model))
    all_bodies = [body_name(i) for name in self.object_names for i in subtree[name]]
    if config.scene.track is None:
      tracked = all_bodies
    else:
      tracked = list(config.scene.track)
      for name in tracked:
        if name not in all_bodies:
          raise MwbxError(f"{source}: scene.track: unknown body {name!r} (have: {', '.join(all_bodies)})")
    self.body_names = tuple(tracked)
    self.objects = {
        name: tuple(body_name(i) for i in subtree[name] if body_name(i) in self.body_names)
        for name in self.object_names
    }
    self.groups = self._resolve_groups(source)

    self.model = build_model(mjcf_text, self.body_names, self.mjcf_dir, self.mjcf_includes, self.mjcf_assets)
    if config.sim.timestep is not None:  # the config's step, set once here (else the MJCF's own)
      self.model.opt.timestep = config.sim.timestep
    self.body_ids = np.array(
        [mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, b) for b in self.body_names], np.int32
    )
    excluded = self.select_bodies(config.perturb.exclude, field="perturb.exclude")
    self.perturbable = np.ones(len(self.body_names), bool)
    self.perturbable[excluded] = False
    # A flex is perturbed as a whole, never its vertex bodies one by one
    # (docs/sampling.md, "Flexes").
    flex_body_ids = [b for bodies in flex_bodies(plain_model).values() for b in bodies]
    self.perturbable[np.isin(self.body_ids, flex_body_ids)] = False
    self.flex_weight = np.zeros((len(self.flex_objects), len(self.body_names)), np.float32)
    self.flex_perturbable = np.zeros(len(self.flex_objects), bool)
    for f, name in enumerate(self.flex_objects):
      members = np.flatnonzero(np.isin(self.body_names, self.objects[name]))
      mass = self.model.body_mass[self.body_ids[members]]
      self.flex_weight[f, members] = mass / mass.sum() if mass.sum() > 0 else 1.0 / max(len(members), 1)
      self.flex_perturbable[f] = len(members) > 0 and not np.isin(members, excluded).all()
    self.object_inits = self._object_inits(source, subtree)
    controls.actuator_ids(self.model, config.controls, source)  # names each unknown actuator

  # -- names ------------------------------------------------------------------

  def _resolve_groups(self, source: str) -> dict[str, tuple[str, ...]]:
    raw = dict(self.config.scene.groups)
    for name in raw:
      if name in self.object_names or name in self.body_names:
        raise MwbxError(f"{source}: scene.groups.{name}: a group may not reuse an object or body name")

    def expand(name, stack):
      if name in self.object_names:
        return (name,)
      if name not in raw and any(c in name for c in "*?["):  # a pattern over object names
        matched = tuple(o for o in self.object_names if fnmatch.fnmatchcase(o, name))
        if not matched:
          raise MwbxError(f"{source}: scene.groups.{stack[0]}: pattern {name!r} matches no object")
        return matched
      if name not in raw:
        raise MwbxError(f"{source}: scene.groups.{stack[0]}: unknown object or group {name!r}")
      out = []
      for member in raw[name]:
        if member in stack:
          raise MwbxError(f"{source}: scene.groups.{stack[0]}: group {member!r} contains itself")
        out.extend(o for o in expand(member, stack + (member,)) if o not in out)
      return tuple(out)

    return {name: expand(name, (name,)) for name in raw}

  def select_bodies(self, names: str | Sequence[str], field: str = "selection") -> np.ndarray:
    """Indices into the tracked-body axis for body, object and group names."""
    return select_bodies(names, self.body_names, self.objects, self.groups, field,
                         self.config.source or "<config>")

  def objects_of(self, name: str, field: str) -> tuple[str, ...]:
    """Object names for an object or group name (``object:``/``group:`` allowed)."""
    return objects_of(name, self.object_names, self.groups, field, self.config.source or "<config>")

  # -- randomization ------------------------------------------------------------

  def _object_inits(self, source, subtree) -> tuple[ObjectInit, ...]:
    m = self.model
    per_object: dict[str, dict] = {}
    spelled: dict[tuple[str, str], str] = {}  # (object, field) -> the randomize key that set it (a group's name)
    for key, randomization in self.config.randomize.items():
      for obj in self.objects_of(key, f"randomize.{key}"):
        fields = randomization.model_dump(exclude_none=True)
        per_object.setdefault(obj, {}).update(fields)
        spelled.update({(obj, field): key for field in fields})
    at = lambda obj, field: f"randomize.{spelled.get((obj, field), obj)}.{field}"  # noqa: E731
    inits = []
    for obj, fields in per_object.items():
      flex = None
      if obj in self.flex_objects:
        free, scalar = [], []
        if "joint_noise" in fields:
          raise MwbxError(f"{source}: {at(obj, 'joint_noise')}: object {obj!r} is a flex; its vertices are"
                          f" not randomized one by one (position, rotation and the velocities move it whole)")
        flex = flex_motion(m, subtree[obj])
        if isinstance(flex, str):
          raise MwbxError(f"{source}: {at(obj, next(iter(fields)))}: flex {obj!r}: {flex}")
      else:
        root = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, obj)
        joints = [j for j in range(m.njnt) if m.body_rootid[m.jnt_bodyid[j]] == root]
        free = [j for j in joints if int(m.jnt_type[j]) == JNT_FREE and m.jnt_bodyid[j] == root]
        scalar = [j for j in joints if int(m.jnt_type[j]) in (JNT_HINGE, JNT_SLIDE)]
        for field in ("position", "rotation", "linear_velocity", "angular_velocity"):
          if field in fields and not free:
            raise MwbxError(f"{source}: {at(obj, field)}: object {obj!r} has no free joint at its root")
        if "joint_noise" in fields and not scalar:
          raise MwbxError(f"{source}: {at(obj, 'joint_noise')}: object {obj!r} has no hinge or slide joints")
      dist = {k: Distribution.model_validate(v) for k, v in fields.items()}
      for k, d in dist.items():
        width = len(scalar) if k == "joint_noise" else 3
        for field in ("scale", "mean"):
          size = np.atleast_1d(getattr(d, field)).size
          if size not in (1, width):
            raise MwbxError(
                f"{source}: {at(obj, k)}.{field}: expected 1 or {width} values, got {size}")
      inits.append(ObjectInit(
          name=obj,
          free_qpos=int(m.jnt_qposadr[free[0]]) if free else -1,
          free_dof=int(m.jnt_dofadr[free[0]]) if free else -1,
          joint_qpos=tuple(int(m.jnt_qposadr[j]) for j in scalar),
          position=dist.get("position"), rotation=dist.get("rotation"),
          linear_velocity=dist.get("linear_velocity"), angular_velocity=dist.get("angular_velocity"),
          joint_noise=dist.get("joint_noise"), flex=flex,
      ))
    return tuple(inits)

  @functools.cached_property
  def noise_slots(self) -> tuple[NoiseSlot, ...]:
    """Where each randomized quantity sits in a world's unit noise vector
    (:meth:`unit_noise`), in the order the draws are made; D = the last slot's
    ``start + width``."""
    slots, start = [], 0
    for init in self.object_inits:
      widths = {"joint_noise": len(init.joint_qpos)} if init.joint_qpos else {}
      if init.free_qpos >= 0 or init.flex is not None:
        widths.update({f: 3 for f in RANDOMIZED_FIELDS[:4]})
      for field in RANDOMIZED_FIELDS:
        dist = getattr(init, field)
        if field in widths and dist is not None:
          slots.append(NoiseSlot(init.name, field, start, widths[field], dist))
          start += widths[field]
    return tuple(slots)

  def unit_noise(self, key: jax.Array) -> jax.Array:
    """ONE world's standardized draws: f32[D] (uniform in [-1, 1] or standard
    normal per :attr:`noise_slots`); :meth:`initial_state_from_noise` makes
    the state from them."""
    parts = []
    for slot in self.noise_slots:
      index = next(i for i, init in enumerate(self.object_inits) if init.name == slot.object)
      keys = jax.random.split(jax.random.fold_in(key, index), len(RANDOMIZED_FIELDS))
      parts.append(_unit_draw(keys[RANDOMIZED_FIELDS.index(slot.field)], slot.dist, slot.width))
    return jnp.concatenate(parts) if parts else jnp.zeros(0, jnp.float32)

  def initial_state_from_noise(self, unit: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Initial state of ONE world from its unit noise.

    Args:
      unit: f32[D] standardized draws (:meth:`unit_noise`); each randomized
        quantity is ``mean + scale * unit`` (metres, radians, m/s, rad/s).

    Returns:
      qpos: f32[nq] and qvel: f32[nv] (the model's reference pose plus noise).
    """
    slots = {(s.object, s.field): s for s in self.noise_slots}

    def offset(init, field, width):
      slot = slots.get((init.name, field))
      if slot is None:
        return jnp.zeros(width, jnp.float32)
      return _scaled(slot.dist, unit[slot.start:slot.start + slot.width], width)

    qpos = jnp.asarray(self.model.qpos0, jnp.float32)
    qvel = jnp.zeros(self.model.nv, jnp.float32)
    for init in self.object_inits:
      if init.free_qpos >= 0:
        a = init.free_qpos
        qpos = qpos.at[a:a + 3].add(offset(init, "position", 3))
        rotvec = offset(init, "rotation", 3)
        qpos = qpos.at[a + 3:a + 7].set(rotations.quat_multiply(rotations.quat_from_rotvec(rotvec), qpos[a + 3:a + 7]))
        v = init.free_dof
        qvel = qvel.at[v:v + 3].add(offset(init, "linear_velocity", 3))
        qvel = qvel.at[v + 3:v + 6].add(offset(init, "angular_velocity", 3))
      if init.joint_qpos:
        idx = np.array(init.joint_qpos)
        qpos = qpos.at[idx].add(offset(init, "joint_noise", len(idx)))
      if init.flex is not None:  # every vertex moved: a translation, then a turn about their mean
        f = init.flex
        arm = jnp.asarray(f.arm, jnp.float32)
        turn = rotations.quat_to_matrix(rotations.quat_from_rotvec(offset(init, "rotation", 3)))
        shift = arm @ turn.T - arm + offset(init, "position", 3)
        speed = offset(init, "linear_velocity", 3) + jnp.cross(offset(init, "angular_velocity", 3), arm)
        to_joints = jnp.asarray(f.to_joints, jnp.float32)
        qpos = qpos.at[f.qpos].add(jnp.einsum("nij,nj->ni", to_joints, shift))
        qvel = qvel.at[f.dof].add(jnp.einsum("nij,nj->ni", to_joints, speed))
    return qpos, qvel

  def initial_state(self, key: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Randomized initial state of ONE world.

    Args:
      key: the world's initialization key.

    Returns:
      qpos: f32[nq] and qvel: f32[nv] (the model's reference pose plus noise).
    """
    return self.initial_state_from_noise(self.unit_noise(key))


# Prefixes that say what a name is where an object and its root body share it
# (an articulated object named after its root body ``torso``).
NAME_KINDS = ("body", "object", "group")


def split_name(name: str) -> tuple[str | None, str]:
  """``"body:torso"`` -> ("body", "torso"); a bare name -> (None, name)."""
  kind, sep, rest = str(name).partition(":")
  if sep and kind in NAME_KINDS:
    return kind, rest
  return None, str(name)


def select_bodies(names, body_names, objects, groups, field="selection", source="<bank>") -> np.ndarray:
  """Indices into ``body_names`` for any mix of body, object and group names.

  A bare name is a group, else an object, else a tracked body; ``body:NAME``,
  ``object:NAME`` and ``group:NAME`` say which (``body:torso`` is the root body
  alone where ``torso`` also names the whole object).
  """
  if isinstance(names, str):
    names = (names,)
  out: list[int] = []
  for spelled in names:
    kind, name = split_name(spelled)
    if kind in (None, "group") and name in groups:
      bodies = [b for obj in groups[name] for b in objects[obj]]
    elif kind in (None, "object") and name in objects:
      bodies = list(objects[name])
    elif kind in (None, "body") and name in body_names:
      bodies = [name]
    else:
      what = f"{kind}" if kind else "body, object or group"
      raise MwbxError(
          f"{source}: {field}: unknown {what} {spelled!r}"
          f" (objects: {', '.join(objects)}; groups: {', '.join(groups) or 'none'})"
      )
    out.extend(body_names.index(b) for b in bodies if body_names.index(b) not in out)
  return np.array(out, np.int32)


def objects_of(spelled: str, object_names, groups, field: str, source: str) -> tuple[str, ...]:
  """Object names for an object or group name; ``object:NAME`` / ``group:NAME``
  say which (a bare name is a group first, as in :func:`select_bodies`)."""
  kind, name = split_name(spelled)
  if kind in (None, "group") and name in groups:
    return tuple(groups[name])
  if kind in (None, "object") and name in object_names:
    return (name,)
  hint = "; bodies are not objects: name the object" if kind == "body" else ""
  raise MwbxError(
      f"{source}: {field}: unknown object or group {spelled!r}"
      f" (objects: {', '.join(object_names)}; groups: {', '.join(groups) or 'none'}){hint}")


def _unit_draw(key: jax.Array, dist: Distribution, width: int) -> jax.Array:
  """f32[width] in [-1, 1] (uniform) or standard normal."""
  if dist.dist == "uniform":
    return jax.random.uniform(key, (width,), jnp.float32, -1.0, 1.0)
  return jax.random.normal(key, (width,), jnp.float32)


def _scaled(dist: Distribution, unit: jax.Array, width: int) -> jax.Array:
  """``mean + scale * unit``: f32[width]."""
  scale = jnp.broadcast_to(jnp.asarray(dist.scale, jnp.float32), (width,))
  mean = jnp.broadcast_to(jnp.asarray(dist.mean, jnp.float32), (width,))
  return mean + scale * unit
