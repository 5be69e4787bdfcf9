"""A world as a USD stage: every body's pose time-sampled, its geoms as prims.

Layout of the stage (Z up, metres, ``timeCodesPerSecond`` = the clip's fps,
time code k = clip frame k)::

  /World                      default prim; customData mwbx: world id, start s
    /Looks/<material>         one UsdPreviewSurface material per MJCF material
    /worldbody/<geom>         geoms of the world body, at their MJCF poses
    /bodies/<body>            one Xform per body: xformOp:translate (double3)
                              and xformOp:orient (quatd, wxyz) in the world
                              frame, time-sampled for bodies that move;
                              visibility time-sampled where its object is absent
      /<geom>                 the body's geoms at their poses in the body frame
    /flexes/<flex>            one Mesh per flex (cloth, soft solid, rope): its
                              points time-sampled in the world frame

Each geom is a USD primitive where USD has one (Sphere, Cube, Capsule,
Cylinder, Plane; an ellipsoid is a scaled Sphere) and a Mesh otherwise (mesh
geoms from the model's mesh data, height fields as the viewer draws them),
with ``primvars:displayColor``/``displayOpacity`` from the colour MuJoCo draws
it with and, where the MJCF gives it a material whose colour it shows, that
material bound. Geoms MuJoCo hides by default (groups 3-5, or alpha 0) are
written with purpose ``guide``. Each geom prim carries customData
``mujoco:geom_id``, each body prim ``mujoco:body_id``. Textures are not
exported.

usd-core (``pxr``) is imported on first use: ``pip install 'mwbx[export]'``.
"""

from __future__ import annotations

import os
import pathlib

import mujoco
import numpy as np

from mwbx.errors import MwbxError
from mwbx.export import target
from mwbx.export.poses import WorldPoses, world_poses
from mwbx.files import remove_quietly, why
from mwbx.progress import Progress, ProgressFn
from mwbx.viewer import flex as flex_lib
from mwbx.viewer.display import DEFAULT_VISIBLE_GROUPS
from mwbx.viewer.geometry import geom_rgba, hfield_mesh

USD_SUFFIXES = target.SUFFIXES["usd"]
PHASE = "writing USD"
_T = mujoco.mjtGeom


def _pxr():
  """The usd-core modules, or one MwbxError naming what to install."""
  try:
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, Vt  # lazy: usd-core is the optional `export` extra
  except ImportError:
    raise MwbxError("export_usd: needs usd-core (pip install usd-core, or pip install 'mwbx[export]')") from None
  return Gf, Sdf, Usd, UsdGeom, UsdShade, Vt


def _pxr_reason(err: Exception) -> str:
  """The message of a pxr error without its C++ location: what after the last ' : '."""
  text = str(err).strip().splitlines()[-1] if str(err).strip() else type(err).__name__
  return text.rsplit(" : ", 1)[-1].strip().strip("'")


def _unique(name: str, taken: set, fallback: str) -> str:
  """A valid USD prim name from an MJCF name, unique among ``taken``."""
  from pxr import Tf  # lazy: usd-core is the optional `export` extra
  base = Tf.MakeValidIdentifier(name) if name else fallback
  out, k = base, 1
  while out in taken:
    out, k = f"{base}_{k}", k + 1
  taken.add(out)
  return out


def _plane_extent(model: mujoco.MjModel) -> float:
  """Half-size, m, of planes the MJCF declares infinite (as the viewer draws them)."""
  return max(2.0 * float(model.stat.extent), 1.0)


def _define_geom(stage, path: str, model: mujoco.MjModel, g: int):
  """Defines geom ``g`` at ``path``; returns (prim, scale f64[3] or None), or
  None for geoms without a surface (an sdf without a mesh)."""
  _, _, _, UsdGeom, _, _ = _pxr()
  gtype = int(model.geom_type[g])
  size = np.asarray(model.geom_size[g], np.float64)
  if gtype == _T.mjGEOM_SPHERE:
    prim = UsdGeom.Sphere.Define(stage, path)
    prim.CreateRadiusAttr(float(size[0]))
    return prim, None
  if gtype == _T.mjGEOM_ELLIPSOID:
    prim = UsdGeom.Sphere.Define(stage, path)
    prim.CreateRadiusAttr(1.0)
    return prim, size
  if gtype == _T.mjGEOM_BOX:
    prim = UsdGeom.Cube.Define(stage, path)
    prim.CreateSizeAttr(2.0)  # [-1, 1]^3, scaled by the half-sizes
    return prim, size
  if gtype in (_T.mjGEOM_CAPSULE, _T.mjGEOM_CYLINDER):
    prim = (UsdGeom.Capsule if gtype == _T.mjGEOM_CAPSULE else UsdGeom.Cylinder).Define(stage, path)
    prim.CreateRadiusAttr(float(size[0]))
    prim.CreateHeightAttr(float(2 * size[1]))  # a capsule's height leaves out its caps, as in MuJoCo
    prim.CreateAxisAttr(UsdGeom.Tokens.z)
    return prim, None
  if gtype == _T.mjGEOM_PLANE:
    prim = UsdGeom.Plane.Define(stage, path)
    extent = _plane_extent(model)
    prim.CreateWidthAttr(float(2 * (size[0] if size[0] > 0 else extent)))
    prim.CreateLengthAttr(float(2 * (size[1] if size[1] > 0 else extent)))
    prim.CreateAxisAttr(UsdGeom.Tokens.z)
    return prim, None
  if gtype == _T.mjGEOM_MESH or (gtype == _T.mjGEOM_SDF and int(model.geom_dataid[g]) >= 0):
    mesh = int(model.geom_dataid[g])
    v0, nv = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    f0, nf = int(model.mesh_faceadr[mesh]), int(model.mesh_facenum[mesh])
    return _mesh(stage, path, model.mesh_vert[v0:v0 + nv], model.mesh_face[f0:f0 + nf]), None
  if gtype == _T.mjGEOM_HFIELD:
    return _mesh(stage, path, *hfield_mesh(model, int(model.geom_dataid[g]))), None
  return None


def _mesh(stage, path: str, verts: np.ndarray, faces: np.ndarray):
  """A triangle Mesh prim (flat, not subdivided): verts f[V, 3] m, faces int[F, 3]."""
  Gf, _, _, UsdGeom, _, Vt = _pxr()
  prim = UsdGeom.Mesh.Define(stage, path)
  verts = np.asarray(verts, np.float32)
  prim.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(verts))
  prim.CreateFaceVertexCountsAttr(Vt.IntArray.FromNumpy(np.full(len(faces), 3, np.int32)))
  prim.CreateFaceVertexIndicesAttr(Vt.IntArray.FromNumpy(np.asarray(faces, np.int32).reshape(-1)))
  prim.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
  if len(verts):
    prim.CreateExtentAttr(Vt.Vec3fArray([Gf.Vec3f(*map(float, verts.min(0))), Gf.Vec3f(*map(float, verts.max(0)))]))
  return prim


def _materials(stage, model: mujoco.MjModel) -> list:
  """One UsdPreviewSurface material per MJCF material, by material id."""
  Gf, Sdf, _, UsdGeom, UsdShade, _ = _pxr()
  out, taken = [], set()
  if model.nmat:
    UsdGeom.Scope.Define(stage, "/World/Looks")
  for m in range(model.nmat):
    name = _unique(model.material(m).name, taken, f"material{m}")
    material = UsdShade.Material.Define(stage, f"/World/Looks/{name}")
    shader = UsdShade.Shader.Define(stage, f"/World/Looks/{name}/surface")
    shader.CreateIdAttr("UsdPreviewSurface")
    rgba = np.asarray(model.mat_rgba[m], np.float64)
    emission = float(model.mat_emission[m])
    shader.CreateInput("diffuseColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*rgba[:3]))
    shader.CreateInput("opacity", Sdf.ValueTypeNames.Float).Set(float(rgba[3]))
    shader.CreateInput("roughness", Sdf.ValueTypeNames.Float).Set(1.0 - float(model.mat_shininess[m]))
    shader.CreateInput("emissiveColor", Sdf.ValueTypeNames.Color3f).Set(Gf.Vec3f(*(emission * rgba[:3])))
    material.CreateSurfaceOutput().ConnectToSource(shader.ConnectableAPI(), "surface")
    out.append(material)
  return out


def _place(xformable, pos, quat, scale=None) -> None:
  """Constant translate/orient(/scale) ops: pos f[3] m, quat f[4] wxyz."""
  Gf, _, _, UsdGeom, _, _ = _pxr()
  xformable.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*map(float, pos)))
  xformable.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Quatd(*map(float, quat)))
  if scale is not None:
    xformable.AddScaleOp(UsdGeom.XformOp.PrecisionDouble).Set(Gf.Vec3d(*map(float, scale)))


def _write_geoms(stage, parent: str, model: mujoco.MjModel, geoms: np.ndarray, materials: list) -> int:
  """Geom prims under ``parent`` (the Xform of their body) at their MJCF poses
  in the body frame. Returns how many were written."""
  Gf, Sdf, _, UsdGeom, UsdShade, Vt = _pxr()
  taken, written = set(), 0
  for g in geoms.tolist():
    name = _unique(model.geom(g).name, taken, f"geom{g}")
    made = _define_geom(stage, f"{parent}/{name}", model, g)
    if made is None:
      continue
    gprim, scale = made
    _place(gprim, model.geom_pos[g], model.geom_quat[g], scale)
    prim = gprim.GetPrim()
    if not prim.IsA(UsdGeom.Mesh):
      extent = UsdGeom.Boundable.ComputeExtentFromPlugins(gprim, 0.0)
      if extent is not None:
        gprim.CreateExtentAttr(extent)
    prim.SetCustomDataByKey("mujoco:geom_id", int(g))
    rgba = geom_rgba(model, g)
    gprim.CreateDisplayColorAttr(Vt.Vec3fArray([Gf.Vec3f(rgba.r, rgba.g, rgba.b)]))
    gprim.CreateDisplayOpacityAttr(Vt.FloatArray([rgba.a]))
    mat = int(model.geom_matid[g])
    if mat >= 0 and np.allclose(tuple(rgba), model.mat_rgba[mat]):  # the geom shows its material's colour
      UsdShade.MaterialBindingAPI.Apply(prim).Bind(materials[mat])
    if int(model.geom_group[g]) not in DEFAULT_VISIBLE_GROUPS or rgba.a <= 0:
      gprim.CreatePurposeAttr(UsdGeom.Tokens.guide)
    written += 1
  return written


def _time_samples(layer, xformable, poses: WorldPoses, b: int) -> None:
  """Body ``b``'s pose at every clip frame, and its visibility where it changes."""
  Gf, Sdf, _, UsdGeom, _, _ = _pxr()
  translate = xformable.AddTranslateOp(UsdGeom.XformOp.PrecisionDouble).GetAttr().GetPath()
  orient = xformable.AddOrientOp(UsdGeom.XformOp.PrecisionDouble).GetAttr().GetPath()
  present = poses.present[:, b]
  visibility = None
  if not present.all():
    visibility = xformable.CreateVisibilityAttr(UsdGeom.Tokens.inherited).GetPath()
  pos, quat = poses.xpos[:, b].tolist(), poses.xquat[:, b].tolist()
  with Sdf.ChangeBlock():
    for k in range(len(pos)):
      layer.SetTimeSample(translate, float(k), Gf.Vec3d(*pos[k]))
      layer.SetTimeSample(orient, float(k), Gf.Quatd(*quat[k]))
      if visibility is not None and (k == 0 or present[k] != present[k - 1]):
        layer.SetTimeSample(visibility, float(k),
                            UsdGeom.Tokens.inherited if present[k] else UsdGeom.Tokens.invisible)


def _write_flexes(stage, layer, model: mujoco.MjModel, poses: WorldPoses) -> None:
  """Each flex as a Mesh under /World/flexes, its points time-sampled (world
  frame): the surface the viewers draw (:func:`mwbx.viewer.flex.flex_surfaces`:
  a cloth's triangles, a soft solid's shell, a rope's ribbons)."""
  surfaces = flex_lib.flex_surfaces(model)
  if not surfaces:
    return
  Gf, Sdf, _, UsdGeom, _, Vt = _pxr()
  UsdGeom.Scope.Define(stage, "/World/flexes")
  taken = set()
  for f, surface in enumerate(surfaces):
    mesh = UsdGeom.Mesh.Define(stage, f"/World/flexes/{_unique(surface.name, taken, f'flex{f}')}")
    mesh.GetPrim().SetCustomDataByKey("mujoco:flex_id", int(f))
    mesh.CreateFaceVertexCountsAttr(Vt.IntArray([3] * len(surface.faces)))
    mesh.CreateFaceVertexIndicesAttr(Vt.IntArray(surface.faces.ravel().tolist()))
    mesh.CreateSubdivisionSchemeAttr(UsdGeom.Tokens.none)
    mesh.CreateDisplayColorPrimvar().Set(Vt.Vec3fArray([Gf.Vec3f(*map(float, surface.rgba[:3]))]))
    mesh.CreateDisplayOpacityPrimvar().Set(Vt.FloatArray([float(surface.rgba[3])]))
    points = mesh.CreatePointsAttr().GetPath()
    extent = mesh.CreateExtentAttr().GetPath()
    with Sdf.ChangeBlock():
      for k in range(len(poses.times)):
        vertices = surface.vertices(poses.xpos[k, surface.bodies], poses.xquat[k, surface.bodies])
        layer.SetTimeSample(points, float(k), Vt.Vec3fArray.FromNumpy(vertices))
        layer.SetTimeSample(extent, float(k), Vt.Vec3fArray([Gf.Vec3f(*map(float, vertices.min(axis=0))),
                                                             Gf.Vec3f(*map(float, vertices.max(axis=0)))]))


def write_stage(model: mujoco.MjModel, poses: WorldPoses, path: str | os.PathLike,
                progress: ProgressFn | None = None) -> pathlib.Path:
  """Writes the USD stage of ``poses`` (of a world of ``model``) to ``path``.

  The format follows the suffix: ``.usda`` text, ``.usd``/``.usdc`` binary.
  The file is written beside its target and renamed over it (whole or not at
  all); the target must be a new file or a regular one (see
  :mod:`mwbx.export.target`).
  """
  _pxr()  # a missing usd-core is named before anything is created
  path = target.check_target(path, "usd")
  tmp = target.reserve_temp(path)  # the folder is writable before the stage is built
  try:
    return _write_stage(model, poses, path, tmp, progress)
  finally:
    remove_quietly(tmp)  # gone after the rename; left by a failure


def _write_stage(model: mujoco.MjModel, poses: WorldPoses, path: pathlib.Path, tmp: pathlib.Path,
                 progress: ProgressFn | None) -> pathlib.Path:
  """write_stage's body: the stage built in memory, exported to ``tmp``, renamed over ``path``."""
  Gf, Sdf, Usd, UsdGeom, _, _ = _pxr()
  stage = Usd.Stage.CreateInMemory()
  UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
  UsdGeom.SetStageMetersPerUnit(stage, 1.0)
  stage.SetTimeCodesPerSecond(poses.fps)
  stage.SetFramesPerSecond(poses.fps)
  stage.SetStartTimeCode(0.0)
  stage.SetEndTimeCode(float(len(poses.times) - 1))
  root = UsdGeom.Xform.Define(stage, "/World").GetPrim()
  stage.SetDefaultPrim(root)
  root.SetCustomDataByKey("mwbx:world", int(poses.world))
  root.SetCustomDataByKey("mwbx:start_s", float(poses.times[0]))
  materials = _materials(stage, model)
  layer = stage.GetRootLayer()
  geoms_of = [np.flatnonzero(model.geom_bodyid == b) for b in range(model.nbody)]
  UsdGeom.Xform.Define(stage, "/World/worldbody")  # the world body's frame is the world frame
  _write_geoms(stage, "/World/worldbody", model, geoms_of[0], materials)
  UsdGeom.Scope.Define(stage, "/World/bodies")
  taken = set()
  for b in range(1, model.nbody):
    name = _unique(model.body(b).name, taken, f"body{b}")
    body = UsdGeom.Xform.Define(stage, f"/World/bodies/{name}")
    body.GetPrim().SetCustomDataByKey("mujoco:body_id", int(b))
    if int(model.body_weldid[b]) == 0:  # welded to the world: one pose
      _place(body, poses.xpos[0, b], poses.xquat[0, b])
    else:
      _time_samples(layer, body, poses, b)
    _write_geoms(stage, f"/World/bodies/{name}", model, geoms_of[b], materials)
    if progress is not None:
      progress(Progress(PHASE, b / model.nbody, 1, 0))
  _write_flexes(stage, layer, model, poses)
  try:
    if not layer.Export(str(tmp)):
      raise OSError(f"USD could not write {tmp}")
  except OSError as err:
    raise MwbxError(f"{path}: cannot write USD export ({why(err)})") from None
  except Exception as err:  # pxr's Tf.ErrorException: one line naming the file
    raise MwbxError(f"{path}: cannot write USD export ({_pxr_reason(err)})") from None
  target.replace(tmp, path, "USD export")
  if progress is not None:
    progress(Progress(PHASE, 1, 1, 0))
  return path


def export_usd(bank, world: int, path: str | os.PathLike, *, fps: float | None = None, start: float = 0.0,
               stop: float | None = None, progress: ProgressFn | None = None) -> pathlib.Path:
  """Writes world ``world`` as a USD stage with time-sampled body poses.

  Args:
    bank: a :class:`mwbx.Bank`.
    world: world id.
    path: ``.usda`` (text), ``.usd`` or ``.usdc`` (binary) file: a new file,
      or a regular file replaced whole or not at all (a symlink, FIFO,
      device or directory is refused).
    fps: time samples per second; None (default) writes every recorded
      frame (``bank.record_fps``), else the nearest recorded frame to each
      ``start + k / fps``.
    start, stop: time span, s (default: the whole recording); time code 0 is
      ``start``.
    progress: optional callback taking :class:`mwbx.progress.Progress`
      (phase ``writing USD``, ``done`` the fraction of the world written).

  Returns:
    the path written.

  Raises:
    MwbxError: naming the world, span or file at fault, or saying to install
      usd-core.

  Example:
    >>> export_usd(bank, 3, "world3.usda")
    >>> from pxr import Usd, UsdGeom
    >>> stage = Usd.Stage.Open("world3.usda")
    >>> body = UsdGeom.Xformable(stage.GetPrimAtPath("/World/bodies/letter_S"))
    >>> body.ComputeLocalToWorldTransform(120.0).ExtractTranslation()  # m, at 1 s (120 fps)
  """
  _pxr()
  target.check_target(path, "usd")  # before decoding: a bad name costs nothing
  poses = world_poses(bank, world, fps=fps, start=start, stop=stop)
  return write_stage(bank.model, poses, path, progress)

