"""The paper's §6 scenes load, sample without unstable worlds and answer their
query files (configs/{siggraph,spiral_staircase,refrigerator_toy}.yaml)."""

import jax
import numpy as np
import pytest

import mwbx
from conftest import REPO

SCENES = ("siggraph", "spiral_staircase", "refrigerator_toy")


@pytest.mark.parametrize("name", SCENES)
def test_scene_samples_stably_and_its_queries_load(name):
  cfg = mwbx.load_config(REPO / "configs" / f"{name}.yaml")
  bank = mwbx.sample(cfg, n_worlds=4, key=jax.random.key(0), backend="native")
  assert bank.valid.all(), bank.flags
  queries = mwbx.load_queries(REPO / "configs" / "queries" / f"{name}.yaml", bank=bank)
  each = mwbx.evaluate_each(bank, queries)
  assert each.shape == (4, len(queries.queries))


def test_staircase_servos_raise_the_arms():
  """The figure's shoulder servos follow the config's schedule: the arms are
  raised over the head (target -2.6 rad) once the ramp is over."""
  cfg = mwbx.load_config(REPO / "configs" / "spiral_staircase.yaml")
  scene = mwbx.Scene(cfg)
  bank = mwbx.sample(scene, n_worlds=2, key=jax.random.key(1), backend="native")
  column = scene.model.jnt_qposadr[scene.model.joint("shoulder_flex_l").id]
  for w in bank.world_ids:
    angle = bank.qpos_frames(int(w))[:, column]
    assert abs(angle[0]) < 0.05
    assert np.median(angle[60:]) < -1.5  # after 0.5 s: raised (falls jolt it about)


def _siggraph_model():
  import mujoco
  return mujoco.MjModel.from_xml_path(str(REPO / "mwbx" / "assets" / "siggraph.xml"))


def _letter_extent(model, body: int) -> tuple[float, float]:
  """(width along x, height along z) of a letter's strokes in its own frame, m."""
  import mujoco
  corners = []
  for g in np.flatnonzero(model.geom_bodyid == body):
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, model.geom_quat[g])
    signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    corners.append(model.geom_pos[g] + (signs * model.geom_size[g]) @ rot.reshape(3, 3).T)
  corners = np.concatenate(corners)
  return float(np.ptp(corners[:, 0])), float(np.ptp(corners[:, 2]))


def test_siggraph_slots_are_alike_and_no_letter_bridges_one():
  """The eight slots (between dividers, or a divider and a wall liner) are
  equally wide and wider than any letter's diagonal, so no letter jams across
  a slot's mouth; the dividers reach the query's slot tops (0.18 m)."""
  model = _siggraph_model()
  letters = [b for b in range(model.nbody) if model.body(b).name.startswith("letter_")]
  diagonal = max(np.hypot(*_letter_extent(model, b)) for b in letters)
  walls = [model.geom(n) for n in ("liner_left", "liner_right")]
  faces = [walls[0].pos[0] + walls[0].size[0], walls[1].pos[0] - walls[1].size[0]]
  for k in range(7):
    d = model.geom(f"divider_{k}")
    assert d.pos[2] + d.size[2] >= 0.18 - 1e-6
    faces += [d.pos[0] - d.size[0], d.pos[0] + d.size[0]]
  faces = np.sort(faces)
  widths = faces[1::2] - faces[0::2]
  assert len(widths) == 8
  assert np.ptp(widths) < 1e-6, widths
  assert widths.min() > diagonal, (widths, diagonal)


def test_siggraph_letters_start_over_the_pegs():
  """Every letter starts above a peg-covered stretch (not over the peg-free
  strips by the walls, down which it would fall untouched)."""
  model = _siggraph_model()
  pegs = [g for g in range(model.ngeom) if model.geom(g).name.startswith("peg_")]
  reach = max(abs(model.geom_pos[g][0]) for g in pegs)
  for b in range(model.nbody):
    if model.body(b).name.startswith("letter_"):
      assert abs(model.body_pos[b][0]) < reach, model.body(b).name


def test_siggraph_no_letter_wedges_between_a_peg_and_a_wall():
  """The gap between the outermost pegs and the side walls is wider than any
  letter's diagonal (a narrower gap held S and H against the walls)."""
  model = _siggraph_model()
  letters = [b for b in range(model.nbody) if model.body(b).name.startswith("letter_")]
  diagonal = max(np.hypot(*_letter_extent(model, b)) for b in letters)
  inner = model.geom("side_right").pos[0] - model.geom("side_right").size[0]
  pegs = [g for g in range(model.ngeom) if model.geom(g).name.startswith("peg_")]
  assert pegs
  gap = min(inner - abs(model.geom_pos[g][0]) - model.geom_size[g][0] for g in pegs)
  assert gap > diagonal, (gap, diagonal)


def test_siggraph_queries_ask_each_letter_in_its_slot_and_upright_facing_the_viewer():
  """16 queries: letter k in slot k (either G in either G slot), and each
  letter's end rotation within 25 degrees of the identity (it starts
  upright, read from the front camera)."""
  cfg = mwbx.load_config(REPO / "configs" / "siggraph.yaml")
  bank = mwbx.sample(cfg, n_worlds=2, key=jax.random.key(0), backend="native")
  queries = mwbx.load_queries(REPO / "configs" / "queries" / "siggraph.yaml", bank=bank).queries
  assert len(queries) == 16
  slots, upright = queries[:8], queries[8:]
  assert all(isinstance(q, mwbx.Query) for q in slots)
  assert all(isinstance(q, mwbx.OrientationQuery) for q in upright)
  letters = ["S", "I", "G1", "G2", "R", "A", "P", "H"]
  for k, (s, u) in enumerate(zip(slots, upright)):
    assert u.bodies == (f"letter_{letters[k]}",)
    if letters[k].startswith("G"):  # the two Gs are one letter: either fills either G slot
      assert s.bodies == ("letter_G1", "letter_G2") and s.mode == "any"
    else:
      assert s.bodies == u.bodies
    assert u.window is None and u.include and u.target == (1.0, 0.0, 0.0, 0.0)
    assert u.within_deg == 25
