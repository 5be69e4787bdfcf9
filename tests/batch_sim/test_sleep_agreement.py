"""Sleep on and off sample the same distribution of outcomes.

A small tower (4 layers of 8 blocks: 32 trees, so ``auto`` turns sleep on)
is hit by a ball thrown at it with a random speed and aim, with the paper's
perturbations. 32 worlds with ``sim.sleep: true`` (seed 1) and 32 with
``false`` (seed 2) are independent draws; per outcome (blocks knocked down,
the ball's final place, the tower's path length) the two means are compared
with a Welch z, Bonferroni-corrected over the outcomes at a family-wise
1 %, and the samples with a two-sample Kolmogorov-Smirnov test at the same
level, as the engine-agreement test compares engines. The seeds are fixed,
so the test is deterministic; it fails where sleep moves an outcome by more
than chance does (e.g. freezing blocks that would fall). scripts/bench_tower.py
measures the same on the paper's tower with more worlds.

The second variant starts the tower asleep (MuJoCo's sleep policy ``init``,
as the paper's tower ships), from where it rests: its blocks where 1 s of
plain MuJoCo left them (this tower's upper layers partly fall by
themselves; started asleep at the MJCF's pose they would stand frozen until
the ball wakes them, and the outcomes would differ: a tower must start
asleep only where it rests).
"""

import re
import textwrap

import jax
import mujoco
import numpy as np
import pytest
from scipy import stats

import mwbx

WORLDS = 32
FAMILY_ALPHA = 0.01
KNOCKED_DOWN = 0.02  # m a block's COM ends from where it started


def tower_mjcf() -> str:
  blocks = []
  for layer in range(4):
    for i in range(8):  # two rows of four, crossed layer to layer
      along = (i % 4 - 1.5) * 0.051
      across = (i // 4 - 0.5) * 0.051
      x, y = (along, across) if layer % 2 == 0 else (across, along)
      blocks.append(f'<body name="block_{layer}_{i}" pos="{x:.4f} {y:.4f} {0.025 + 0.05 * layer:.4f}"><freejoint/>'
                    f'<geom type="box" size="0.025 0.025 0.025" mass="0.05"/></body>')
  return (f'<mujoco><option timestep="0.0020833333333333333"/><worldbody>'
          f'<geom name="floor" type="plane" size="3 3 0.1"/>{"".join(blocks)}'
          f'<body name="ball" pos="-0.6 0 0.08"><freejoint/><geom type="sphere" size="0.03" mass="0.2"/></body>'
          f'</worldbody></mujoco>')


def resting_asleep(mjcf: str, seconds: float = 1.0) -> str:
  """``mjcf`` with every block where ``seconds`` of plain MuJoCo leave it, asleep from the start."""
  model = mujoco.MjModel.from_xml_string(mjcf)
  data = mujoco.MjData(model)
  mujoco.mj_step(model, data, nstep=int(round(seconds / model.opt.timestep)))

  def settled(match):
    body = model.body(match.group(1))
    q = data.qpos[model.jnt_qposadr[body.jntadr[0]]:][:7]
    return (f'<body name="{match.group(1)}" pos="{q[0]:.7f} {q[1]:.7f} {q[2]:.7f}"'
            f' quat="{q[3]:.8f} {q[4]:.8f} {q[5]:.8f} {q[6]:.8f}" sleep="init">')
  out, n = re.subn(r'<body name="(block_\d+_\d+)" pos="[^"]*">', settled, mjcf)
  assert n == 32, n
  return out


def sample(tmp_path, sleep: bool, seed: int, start_asleep: bool = False):
  (tmp_path / "tower.xml").write_text(resting_asleep(tower_mjcf()) if start_asleep else tower_mjcf())
  config = tmp_path / f"tower_{sleep}.yaml"
  config.write_text(textwrap.dedent(f"""\
      scene:
        mjcf: tower.xml
        groups: {{tower: ["block_*"]}}
      randomize:
        ball:
          linear_velocity: {{dist: uniform, mean: [3.0, 0.0, 0.5], scale: [0.8, 0.3, 0.2]}}
      sim: {{end_time: 1.5, chunk_size: 32, sleep: {'on' if sleep else 'off'}}}
      rest: {{duration: 0.1}}
      """))
  bank = mwbx.sample(mwbx.load_config(config), n_worlds=WORLDS, key=jax.random.key(seed), backend="native")
  assert bank.run["sleep"]["enabled"] is sleep
  return bank


def outcomes(bank) -> dict[str, np.ndarray]:
  rows = np.arange(bank.n_worlds)
  last, first = bank.com[rows, bank.com_count - 1], bank.com[:, 0]
  names = list(bank.body_names)
  blocks = [i for i, b in enumerate(names) if b.startswith("block_")]
  ball = names.index("ball")
  path = list(bank.metric_names).index("path_length")
  return {
      "knocked_down": (np.linalg.norm(last[:, blocks] - first[:, blocks], axis=-1) > KNOCKED_DOWN).sum(axis=1),
      "ball_x": last[:, ball, 0], "ball_y": last[:, ball, 1],
      "tower_path_length": bank.metrics[:, blocks, path].sum(axis=1),
  }


@pytest.mark.parametrize("start_asleep", [False, True], ids=["falls_asleep", "starts_asleep"])
def test_sleep_on_and_off_agree_on_a_struck_tower(tmp_path, start_asleep):
  on, off = sample(tmp_path, True, 1, start_asleep), sample(tmp_path, False, 2, start_asleep)
  assert on.valid.all() and off.valid.all()
  a, b = outcomes(on), outcomes(off)
  assert a["knocked_down"].mean() > 1 and b["knocked_down"].mean() > 1  # the ball does hit the tower
  z_crit = stats.norm.ppf(1 - FAMILY_ALPHA / 2 / len(a))
  report = {}
  for name in a:
    x, y = np.asarray(a[name], float), np.asarray(b[name], float)
    se = np.sqrt(x.var(ddof=1) / len(x) + y.var(ddof=1) / len(y))
    z = 0.0 if se == 0 else (x.mean() - y.mean()) / se
    report[name] = (round(float(x.mean()), 4), round(float(y.mean()), 4), round(float(z), 2),
                    round(float(stats.ks_2samp(x, y).pvalue), 4))
  print(report)  # (mean on, mean off, z, KS p) per outcome
  assert all(abs(r[2]) < z_crit for r in report.values()), report
  assert all(r[3] > FAMILY_ALPHA / len(a) for r in report.values()), report
