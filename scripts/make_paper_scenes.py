"""Writes the MJCF of three of the paper's §6 scenes into ``mwbx/assets``.

* ``siggraph.xml`` (Fig. 1): the letters S I G G R A P H, each a compound of
  box strokes, dropped through a peg board with eight slots; the goal is
  letter k in slot k.
* ``spiral_staircase.xml``: an articulated figure (ball hips, neck and
  waist, hinged shoulders, elbows and knees, joint limits; position servos
  on the arms) on the top landing of a three-level spiral staircase (two
  flights of eight steep steps, a short middle landing, down to the ground
  floor; a low curb on the open side).
* ``refrigerator_toy.xml`` (Fig. 8 left): a marble rolls down a chute into a
  bucket on a hinge, which tips left or right onto a chute that feeds one of
  two lower buckets.

All of them are seen through an MJCF camera ``front`` (queries and the
README pictures).

  python scripts/make_paper_scenes.py
"""

import math
import pathlib

ASSETS = pathlib.Path(__file__).resolve().parents[1] / "mwbx" / "assets"
TIMESTEP = 1.0 / 480  # s: 4 steps per 120 fps frame

# -- Spelling SIGGRAPH -------------------------------------------------------------------

LETTERS = ("S", "I", "G", "G", "R", "A", "P", "H")
SLOT = 0.14  # m, slot width; slot k is centred at SLOT_X[k]
SLOT_X = [(k - 3.5) * SLOT for k in range(8)]
W, H, T = 0.03, 0.042, 0.007  # letter half width, half height, stroke half thickness (m)
DEPTH = 0.018  # letter half depth (y), m
DIVIDER_HALF = 0.008  # m: slots 2 * (SLOT / 2 - DIVIDER_HALF) = 0.124 m wide, more than a letter's diagonal
SLOT_TOP = 0.18  # m, the dividers' height (below their roofs)
WALL_GAP = 0.1  # m: pegs keep this far from the walls
START_SPREAD = 0.8  # the letters' start x, as a share of their slots' x


def _bar(cx, cz, hx, hz, angle=0.0):
  """A stroke: box centre (cx, cz) in the letter's plane, half sizes, tilt about y (rad)."""
  return (cx, cz, hx, hz, angle)


def _diagonal(x0, z0, x1, z1):
  length = math.hypot(x1 - x0, z1 - z0)
  # A box along x turned by +a about y points along (cos a, -sin a).
  return _bar((x0 + x1) / 2, (z0 + z1) / 2, length / 2, T, math.atan2(-(z1 - z0), x1 - x0))


STROKES = {
    "S": [_bar(0, H - T, W, T), _bar(0, 0, W, T), _bar(0, -H + T, W, T),
          _bar(-W + T, H / 2, T, H / 2), _bar(W - T, -H / 2, T, H / 2)],
    "I": [_bar(0, 0, T, H), _bar(0, H - T, 0.6 * W, T), _bar(0, -H + T, 0.6 * W, T)],
    "G": [_bar(0, H - T, W, T), _bar(0, -H + T, W, T), _bar(-W + T, 0, T, H),
          _bar(W - T, -H / 2, T, H / 2), _bar(W / 2, 0, W / 2, T)],
    "R": [_bar(-W + T, 0, T, H), _bar(0, H - T, W, T), _bar(0, 0, W, T),
          _bar(W - T, H / 2, T, H / 2), _diagonal(0, 0, W, -H)],
    "A": [_diagonal(-W, -H, 0, H), _diagonal(0, H, W, -H), _bar(0, -H / 4, W / 2, T)],
    # P stands on a slab foot: on its stem alone its centre of mass (under
    # the bowl) lies outside its base and it falls flat, so it could never
    # end upright. With the foot it stands from 0.3 rad either way, as the others do.
    "P": [_bar(-W + T, 0, T, H), _bar(0, H - T, W, T), _bar(0, 0, W, T), _bar(W - T, H / 2, T, H / 2),
          _bar(-W + 0.75 * W, -H + T, 0.75 * W, T)],
    "H": [_bar(-W + T, 0, T, H), _bar(W - T, 0, T, H), _bar(0, 0, W, T)],
}
LETTER_RGB = ["0.9 0.3 0.3", "0.95 0.6 0.2", "0.9 0.85 0.2", "0.5 0.85 0.3",
              "0.2 0.75 0.7", "0.3 0.5 0.95", "0.6 0.4 0.9", "0.9 0.4 0.75"]


def letter_names() -> list[str]:
  """letter_S, letter_I, letter_G1, letter_G2, ...: object name of letter k."""
  names, seen = [], {}
  for c in LETTERS:
    seen[c] = seen.get(c, 0) + 1
    names.append(f"letter_{c}{seen[c]}" if LETTERS.count(c) > 1 else f"letter_{c}")
  return names


def siggraph() -> str:
  half = 4 * SLOT  # inner half width of the board, m
  lines = [
      '<mujoco model="siggraph">',
      "  <!-- Fig. 1: S I G G R A P H through a peg board into eight labelled slots"
      " (scripts/make_paper_scenes.py). -->",
      f'  <option timestep="{TIMESTEP!r}" gravity="0 0 -9.81"/>',
      '  <visual><global offwidth="800" offheight="800"/></visual>',
      "  <default>",
      '    <geom friction="0.4 0.005 0.0001" solref="0.01 1"/>',
      '    <default class="static"><geom rgba="0.55 0.55 0.6 1"/></default>',
      '    <default class="peg"><geom type="capsule" size="0.012 0.04" euler="90 0 0" rgba="0.75 0.7 0.55 1"/></default>',
      "  </default>",
      "  <worldbody>",
      '    <light pos="0 -2 3" dir="0 0.5 -1"/>',
      '    <camera name="front" pos="0 -3.3 0.85" xyaxes="1 0 0 0 0 1" fovy="35"/>',
      '    <geom name="floor" type="plane" size="2 2 0.1" rgba="0.8 0.8 0.8 1"/>',
      f'    <geom name="back" class="static" type="box" size="{half + 0.02} 0.01 0.85" pos="0 0.035 0.85" rgba="0.3 0.3 0.35 1"/>',
      f'    <geom name="glass" class="static" type="box" size="{half + 0.02} 0.01 0.85" pos="0 -0.035 0.85" rgba="0.8 0.9 1 0.15"/>',
      f'    <geom name="side_left" class="static" type="box" size="0.012 0.04 0.85" pos="{-half - 0.012} 0 0.85"/>',
      f'    <geom name="side_right" class="static" type="box" size="0.012 0.04 0.85" pos="{half + 0.012} 0 0.85"/>',
  ]
  # Eight slots of one width (the outer two lined at the walls), wider than
  # a letter's diagonal: a letter never bridges a slot's mouth. A letter may
  # rest in its slot upright, on its side or upside down; the upright queries
  # ask which. A 45-degree roof on each divider (and a slope on each liner)
  # sheds a letter into a slot instead of holding it on top.
  roof = DIVIDER_HALF / math.sqrt(2)
  for k in range(1, 8):
    x = SLOT_X[k] - SLOT / 2
    lines.append(f'    <geom name="divider_{k - 1}" class="static" type="box" size="{DIVIDER_HALF} 0.04 {SLOT_TOP / 2}"'
                 f' pos="{x:.3f} 0 {SLOT_TOP / 2}"/>')
    lines.append(f'    <geom name="divider_{k - 1}_roof" class="static" type="box" size="{roof:.4f} 0.04 {roof:.4f}"'
                 f' pos="{x:.3f} 0 {SLOT_TOP}" euler="0 45 0"/>')
  for side, sx in (("left", -1), ("right", 1)):
    x = sx * (half - DIVIDER_HALF / 2)
    lines.append(f'    <geom name="liner_{side}" class="static" type="box" size="{DIVIDER_HALF / 2} 0.04 {SLOT_TOP / 2}"'
                 f' pos="{x:.3f} 0 {SLOT_TOP / 2}"/>')
    lines.append(f'    <geom name="liner_{side}_slope" class="static" type="box" size="{roof:.4f} 0.04 {roof:.4f}"'
                 f' pos="{sx * half:.3f} 0 {SLOT_TOP}" euler="0 45 0"/>')
  for k, rgb in enumerate(LETTER_RGB):  # a coloured label under each slot
    lines.append(f'    <geom name="label_{k}" type="box" size="{SLOT / 2 - 0.012:.3f} 0.002 0.012"'
                 f' pos="{SLOT_X[k]:.3f} -0.047 0.012" rgba="{rgb} 1" contype="0" conaffinity="0"/>')
  for row in range(6):
    z = 0.45 + 0.15 * row
    offset = 0.0 if row % 2 == 0 else SLOT / 2
    n = 8 if row % 2 == 0 else 7
    for i in range(n):
      x = SLOT_X[0] + offset + i * SLOT
      # No peg within WALL_GAP of a wall: a letter bridges a narrower gap
      # between a peg and the wall and wedges there.
      if abs(x) < half - WALL_GAP:
        lines.append(f'    <geom name="peg_{row}_{i}" class="peg" pos="{x:.3f} 0 {z:.3f}"/>')
  # The letters start in two staggered rows above the board, neighbours
  # swapped: "I S G G A R H P".
  start_order = [1, 0, 3, 2, 5, 4, 7, 6]  # letter k starts above slot start_order[k]
  for k, (c, name) in enumerate(zip(LETTERS, letter_names())):
    # Drawn in by START_SPREAD: the outer letters start over the pegs, not
    # over the peg-free strips along the walls, down which they would fall
    # straight into the outer slots.
    x = START_SPREAD * SLOT_X[start_order[k]]
    z = 1.42 + (0.13 if k % 2 else 0.0)
    lines.append(f'    <body name="{name}" pos="{x:.3f} 0 {z:.3f}">')
    lines.append("      <freejoint/>")
    for s, (cx, cz, hx, hz, angle) in enumerate(STROKES[c]):
      lines.append(f'      <geom name="{name}_{s}" type="box" size="{hx:.4f} {DEPTH} {hz:.4f}"'
                   f' pos="{cx:.4f} 0 {cz:.4f}" euler="0 {math.degrees(angle):.3f} 0"'
                   f' density="800" rgba="{LETTER_RGB[k]} 1"/>')
    lines.append("    </body>")
  lines += ["  </worldbody>", "</mujoco>", ""]
  return "\n".join(lines)


# -- Spiral staircase --------------------------------------------------------------------

R_IN, R_OUT = 0.15, 1.4  # m, column radius and the steps' outer radius
RISE = 0.2  # m per step: steep (about 40 degrees at mid-width), so a fall can carry on
STEPS = 8  # per flight (the upper one gives its last step to the middle landing)
STEP_DEG = 16.0  # each step turns this much
TOP = 2 * STEPS * RISE  # m, top landing height (3.2)
LANDING_DEG = 60.0  # the top landing's sweep round the column
MIDDLE_LANDING_DEG = 24.0  # short: a tumble across it is rare, not impossible
LEAN_DEG = 25.0  # the figure's forward lean at the start
START_BACK_DEG = 12.0  # the figure starts this far round the column before the top landing's edge
START_RADIUS = 0.62  # m from the column's axis
STAIR_FRICTION = 0.8
CURB_HEIGHT = 0.15  # m: a lip along the steps' outer edge; a tumble can still go over it
C = 'contype="1" conaffinity="2"'  # staircase: touches the figure
F = 'contype="2" conaffinity="1"'  # figure: touches the staircase, never itself


def _sector(name, a0_deg, a1_deg, z_top, rgba, thickness=0.06):
  """Boxes covering the annulus sector [a0, a1] (degrees) with their top at z_top."""
  out = []
  n = max(1, int(math.ceil((a1_deg - a0_deg) / 24.0)))
  span = (a1_deg - a0_deg) / n
  r_mid, half_radial = (R_IN + R_OUT) / 2, (R_OUT - R_IN) / 2
  half_tangent = R_OUT * math.tan(math.radians(span / 2)) + 0.01
  for i in range(n):
    a = a0_deg + (i + 0.5) * span
    x, y = r_mid * math.cos(math.radians(a)), r_mid * math.sin(math.radians(a))
    out.append(f'    <geom name="{name}_{i}" type="box" size="{half_radial:.3f} {half_tangent:.3f} {thickness / 2}"'
               f' pos="{x:.3f} {y:.3f} {z_top - thickness / 2:.3f}" euler="0 0 {a:.2f}" rgba="{rgba}" {C}/>')
    if CURB_HEIGHT > 0:
      xc, yc = (R_OUT - 0.015) * math.cos(math.radians(a)), (R_OUT - 0.015) * math.sin(math.radians(a))
      out.append(f'    <geom name="{name}_{i}_curb" type="box" size="0.015 {half_tangent:.3f} {CURB_HEIGHT / 2:.3f}"'
                 f' pos="{xc:.3f} {yc:.3f} {z_top + CURB_HEIGHT / 2:.3f}" euler="0 0 {a:.2f}" rgba="{rgba}" {C}/>')
  return out


def _lean_then_turn(lean_deg: float, heading_deg: float) -> str:
  """Quaternion (w x y z) of a forward lean about the body's y axis (+x
  tips down: the head goes forward), then a turn about the world z axis."""
  lean, turn = math.radians(lean_deg) / 2, math.radians(heading_deg) / 2
  qy = (math.cos(lean), 0.0, math.sin(lean), 0.0)
  qz = (math.cos(turn), 0.0, 0.0, math.sin(turn))
  w1, x1, y1, z1 = qz
  w2, x2, y2, z2 = qy
  q = (w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2, w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
       w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2, w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2)
  return " ".join(f"{c:.6f}" for c in q)


def spiral_staircase() -> str:
  lines = [
      '<mujoco model="spiral_staircase">',
      "  <!-- §6: a figure falling down a three-level spiral staircase, arms held over"
      " its head by position servos (scripts/make_paper_scenes.py). -->",
      '  <compiler angle="degree"/>',
      f'  <option timestep="{TIMESTEP!r}" gravity="0 0 -9.81"/>',
      '  <visual><global offwidth="800" offheight="800"/></visual>',
      "  <default>",
      f'    <geom friction="{STAIR_FRICTION} 0.005 0.0001" solref="0.01 1"/>',
      '    <joint damping="0.05" armature="0.002"/>',
      '    <position kp="3" ctrlrange="-3 3"/>',
      "  </default>",
      "  <worldbody>",
      '    <light pos="0 -3 6" dir="0 0.4 -1"/>',
      '    <camera name="front" pos="4.3 -6.1 4.4" xyaxes="0.82 0.57 0 -0.25 0.36 0.9" fovy="45"/>',
      f'    <geom name="floor" type="plane" size="4 4 0.1" rgba="0.8 0.8 0.8 1" {C}/>',
      f'    <geom name="column" type="cylinder" size="{R_IN} {TOP / 2 + 0.3:.2f}" pos="0 0 {TOP / 2 + 0.3:.2f}"'
      f' rgba="0.5 0.5 0.55 1" {C}/>',
  ]
  lines += _sector("landing_top", 0.0, LANDING_DEG, TOP, "0.55 0.45 0.35 1", 0.1)
  angle = LANDING_DEG
  for flight in range(2):
    for s in range(STEPS):
      z = TOP - RISE * (flight * STEPS + s + 1)
      if s == STEPS - 1 and flight == 0:  # the middle landing, one step down from the last
        continue
      lines += _sector(f"step_{flight}_{s}", angle, angle + STEP_DEG, z,
                       "0.7 0.6 0.45 1" if s % 2 else "0.65 0.55 0.4 1", RISE)
      angle += STEP_DEG
    if flight == 0:
      lines += _sector("landing_middle", angle, angle + MIDDLE_LANDING_DEG, TOP - RISE * STEPS, "0.55 0.45 0.35 1",
                       0.1)
      angle += MIDDLE_LANDING_DEG
  # The figure stands at the top landing's edge facing down the stairs (its
  # +x along the direction of increasing angle), leaning forward: it falls.
  a = math.radians(LANDING_DEG - START_BACK_DEG)
  x, y = START_RADIUS * math.cos(a), START_RADIUS * math.sin(a)
  lines += [
      f'    <body name="figure" pos="{x:.3f} {y:.3f} {TOP + 0.36:.3f}" quat="{_lean_then_turn(LEAN_DEG, LANDING_DEG - START_BACK_DEG + 90)}">',
      "      <freejoint/>",
      f'      <geom name="pelvis" type="capsule" fromto="0 -0.06 0 0 0.06 0" size="0.045" rgba="0.3 0.4 0.8 1" {F}/>',
      '      <body name="torso" pos="0 0 0.05">',
      '        <joint name="waist" type="ball" range="0 25"/>',
      f'        <geom name="torso" type="capsule" fromto="0 0 0.02 0 0 0.16" size="0.055" rgba="0.85 0.4 0.3 1" {F}/>',
      '        <body name="head" pos="0 0 0.27">',
      '          <joint name="neck" type="ball" range="0 30"/>',
      f'          <geom name="head" type="sphere" size="0.06" rgba="0.95 0.8 0.65 1" {F}/>',
      "        </body>",
  ]
  for side, sy in (("l", 1), ("r", -1)):
    lines += [
        f'        <body name="upper_arm_{side}" pos="0 {0.085 * sy} 0.17">',
        f'          <joint name="shoulder_flex_{side}" type="hinge" axis="0 1 0" range="-170 60"/>',
        f'          <joint name="shoulder_abd_{side}" type="hinge" axis="{sy} 0 0" range="-20 90"/>',
        f'          <geom name="upper_arm_{side}" type="capsule" fromto="0 0 0 0 0 -0.12" size="0.024"'
        f' rgba="0.85 0.4 0.3 1" {F}/>',
        f'          <body name="forearm_{side}" pos="0 0 -0.12">',
        f'            <joint name="elbow_{side}" type="hinge" axis="0 1 0" range="-150 0"/>',
        f'            <geom name="forearm_{side}" type="capsule" fromto="0 0 0 0 0 -0.11" size="0.02"'
        f' rgba="0.95 0.8 0.65 1" {F}/>',
        "          </body>",
        "        </body>",
    ]
  lines.append("      </body>")
  for side, sy in (("l", 1), ("r", -1)):
    lines += [
        f'      <body name="thigh_{side}" pos="0 {0.06 * sy} -0.02">',
        f'        <joint name="hip_{side}" type="ball" range="0 70" damping="0.1"/>',
        f'        <geom name="thigh_{side}" type="capsule" fromto="0 0 0 0 0 -0.15" size="0.03" rgba="0.3 0.4 0.8 1" {F}/>',
        f'        <body name="shin_{side}" pos="0 0 -0.15">',
        f'          <joint name="knee_{side}" type="hinge" axis="0 1 0" range="0 140" damping="0.1"/>',
        f'          <geom name="shin_{side}" type="capsule" fromto="0 0 0 0 0 -0.14" size="0.026" rgba="0.3 0.3 0.35 1" {F}/>',
        "        </body>",
        "      </body>",
    ]
  lines += ["    </body>", "  </worldbody>", "  <actuator>"]
  for side in ("l", "r"):
    for joint in ("shoulder_flex", "shoulder_abd", "elbow"):
      lines.append(f'    <position name="{joint}_{side}" joint="{joint}_{side}"/>')
  lines += ["  </actuator>", "</mujoco>", ""]
  return "\n".join(lines)


# -- Refrigerator toy --------------------------------------------------------------------


# The marble leaving a chute hits a stop and drops onto a bucket's pivot line:
# which side of the pivot it lands on (a few millimetres) decides the way
# the bucket tips.
STOP_TOP_X, STOP_LOW_X = 0.07, 0.64  # m, inner faces 5 mm nearer the middle
BUCKET_TOP_X, BUCKET_LOW_X = 0.035, 0.61  # m, the buckets' pivots


def _bucket(name, x, z, rgba):
  """A cup on a hinge at its bottom centre: the marble on either side of the
  pivot tips it that way (positive angle: the right side goes down)."""
  return [
      f'    <body name="{name}" pos="{x:.3f} 0 {z:.3f}">',
      f'      <joint name="{name}_hinge" type="hinge" axis="0 1 0" range="-100 100" damping="0.0005"/>',
      f'      <geom name="{name}_floor_l" type="box" size="0.03 0.025 0.004" pos="-0.028 0 0.006" euler="0 12 0" rgba="{rgba}" mass="0.004"/>',
      f'      <geom name="{name}_floor_r" type="box" size="0.03 0.025 0.004" pos="0.028 0 0.006" euler="0 -12 0" rgba="{rgba}" mass="0.004"/>',
      f'      <geom name="{name}_wall_l" type="box" size="0.004 0.025 0.03" pos="-0.06 0 0.035" rgba="{rgba}" mass="0.003"/>',
      f'      <geom name="{name}_wall_r" type="box" size="0.004 0.025 0.03" pos="0.06 0 0.035" rgba="{rgba}" mass="0.003"/>',
      f'      <geom name="{name}_weight" type="sphere" size="0.012" pos="0 0 -0.03" rgba="0.3 0.3 0.3 1" mass="0.02"/>',
      "    </body>",
  ]


def _chute(name, x0, z0, x1, z1):
  """A static ramp whose top surface runs from (x0, z0) to (x1, z1)."""
  length = math.hypot(x1 - x0, z1 - z0)
  angle = math.degrees(math.atan2(-(z1 - z0), x1 - x0))
  nx, nz = -(z1 - z0) / length, (x1 - x0) / length  # up normal
  cx, cz = (x0 + x1) / 2 - 0.008 * nx, (z0 + z1) / 2 - 0.008 * nz
  return (f'    <geom name="{name}" type="box" size="{length / 2:.3f} 0.03 0.008" pos="{cx:.3f} 0 {cz:.3f}"'
          f' euler="0 {angle:.2f} 0" rgba="0.6 0.45 0.3 1"/>')


def refrigerator_toy() -> str:
  lines = [
      '<mujoco model="refrigerator_toy">',
      "  <!-- Fig. 8 left: a marble, chutes and buckets on hinges (scripts/make_paper_scenes.py). -->",
      '  <compiler angle="degree"/>',
      f'  <option timestep="{TIMESTEP!r}" gravity="0 0 -9.81"/>',
      '  <visual><global offwidth="800" offheight="800"/></visual>',
      "  <default>",
      '    <geom friction="0.5 0.005 0.0001" solref="0.005 1"/>',
      "  </default>",
      "  <worldbody>",
      '    <light pos="0 -2 3" dir="0 0.5 -1"/>',
      '    <camera name="front" pos="0 -2.6 0.6" xyaxes="1 0 0 0 0 1" fovy="35"/>',
      '    <geom name="floor" type="plane" size="2 2 0.1" rgba="0.8 0.8 0.8 1"/>',
      '    <geom name="back" type="box" size="0.7 0.01 0.6" pos="0 0.04 0.6" rgba="0.9 0.9 0.85 1"/>',
      '    <geom name="glass" type="box" size="0.7 0.01 0.6" pos="0 -0.04 0.6" rgba="0.8 0.9 1 0.1"/>',
      _chute("chute_top", -0.55, 1.0, STOP_TOP_X - 0.05, 0.96),
      _chute("chute_left", -0.01, 0.63, -0.53, 0.57),
      _chute("chute_right", 0.01, 0.63, 0.53, 0.57),
      f'    <geom name="stop_top" type="box" size="0.005 0.03 0.08" pos="{STOP_TOP_X:.3f} 0 0.95" rgba="0.6 0.45 0.3 1"/>',
      f'    <geom name="stop_left" type="box" size="0.005 0.03 0.22" pos="{-STOP_LOW_X:.3f} 0 0.64" rgba="0.6 0.45 0.3 1"/>',
      f'    <geom name="stop_right" type="box" size="0.005 0.03 0.22" pos="{STOP_LOW_X:.3f} 0 0.64" rgba="0.6 0.45 0.3 1"/>',
      '    <geom name="side_left" type="box" size="0.01 0.03 0.6" pos="-0.76 0 0.6" rgba="0.5 0.5 0.55 1"/>',
      '    <geom name="side_right" type="box" size="0.01 0.03 0.6" pos="0.76 0 0.6" rgba="0.5 0.5 0.55 1"/>',
  ]
  lines += _bucket("bucket_top", BUCKET_TOP_X, 0.72, "0.9 0.3 0.3 1")
  lines += _bucket("bucket_left", -BUCKET_LOW_X, 0.32, "0.3 0.6 0.9 1")
  lines += _bucket("bucket_right", BUCKET_LOW_X, 0.32, "0.3 0.8 0.4 1")
  lines += [
      '    <body name="marble" pos="-0.52 0 1.022">',
      "      <freejoint/>",
      '      <geom name="marble" type="sphere" size="0.015" density="7800" rgba="0.2 0.2 0.25 1"/>',
      "    </body>",
      "  </worldbody>",
      "</mujoco>",
      "",
  ]
  return "\n".join(lines)


def main():
  for name, text in (("siggraph.xml", siggraph()), ("spiral_staircase.xml", spiral_staircase()),
                     ("refrigerator_toy.xml", refrigerator_toy())):
    (ASSETS / name).write_text(text)
    print(f"wrote {ASSETS / name}")


if __name__ == "__main__":
  main()
