"""Joint queries: a hinge's change over a window, from the decoded stored qpos."""

import jax
import numpy as np
import pytest

import mwbx
from mwbx.queries import joint as joint_lib
from conftest import TESTS


@pytest.fixture(scope="module")
def servo_bank():
  cfg = mwbx.load_config(TESTS / "scenes" / "servo_arm.yaml")
  return mwbx.sample(cfg, n_worlds=8, key=jax.random.key(0), backend="native")


def test_joint_turn_is_the_decoded_change(servo_bank):
  bank = servo_bank
  turn = joint_lib.joint_turn(bank, "shoulder", (0.5, 1.2))
  for w in range(bank.n_worlds):
    q = bank.qpos_frames(int(bank.world_ids[w]))[:, 0]
    assert turn[w] == pytest.approx(float(q[144]) - float(q[60]), abs=1e-6)
  # The servo lifts the arm by about -0.8 rad after 0.6 s: every world turns
  # the negative way, none the positive way.
  down = mwbx.JointQuery("shoulder", turn=(None, -0.5), window=(0.5, None))
  up = mwbx.JointQuery("shoulder", turn=(0.5, None), window=(0.5, None))
  each = mwbx.evaluate_each(bank, [down, up])
  assert each[:, 0].all() and not each[:, 1].any()
  # Mixed with a COM query: the conjunction of both.
  high = mwbx.Query.region((-1, -1, 0.6), (1, 1, 2), bodies="ball")
  np.testing.assert_array_equal(mwbx.evaluate(bank, [down, high]), mwbx.evaluate(bank, [high]))
  # Before the ramp the arm only sags: a turn of less than 0.1 rad either way.
  still = mwbx.JointQuery("shoulder", turn=(-0.1, 0.1), window=(0.0, 0.55))
  assert mwbx.evaluate(bank, [still]).all()
  # Extremes over the window: the lowest point of the arm's path against a
  # decoded reference.
  low = joint_lib.joint_turn(bank, "shoulder", (0.5, None), of="min")
  for w in range(bank.n_worlds):
    q = bank.qpos_frames(int(bank.world_ids[w]))[:, 0]
    assert low[w] == pytest.approx(float(q[60:].min()) - float(q[60]), abs=1e-6)
  assert (low <= joint_lib.joint_turn(bank, "shoulder", (0.5, None)) + 1e-9).all()


def test_joint_queries_load_save_and_name_mistakes(servo_bank, tmp_path):
  path = tmp_path / "q.yaml"
  path.write_text("queries:\n  - {name: lifted, joint: shoulder, turn: [null, -0.5], window: [0.5, null]}\n")
  qs = mwbx.load_queries(path, bank=servo_bank)
  assert isinstance(qs.queries[0], mwbx.JointQuery)
  assert mwbx.evaluate(servo_bank, qs).all()
  again = mwbx.load_queries(qs.save(tmp_path / "again.yaml"), bank=servo_bank)
  assert again.queries[0].turn == (None, -0.5) and again.queries[0].window == (0.5, None)
  for text, message in [
      ("{joint: elbow, turn: [0, 1]}", "queries[0]: joint query: unknown joint 'elbow' (hinge and slide joints: shoulder)"),
      ("{joint: shoulder}", "queries[0]: a joint query needs both 'joint' and 'turn'"),
      ("{joint: shoulder, turn: [1, 0]}", "queries[0]: query 'queries[0]': turn is empty"),
      ("{joint: shoulder, turn: [0, 1], bodies: [ball]}", "a joint query takes joint, turn, of, window and name, not bodies"),
      ("{joint: shoulder, turn: [0, 1], of: mean}", "queries[0].of: Input should be 'change', 'max' or 'min'"),
  ]:
    path.write_text(f"queries:\n  - {text}\n")
    with pytest.raises(mwbx.MwbxError) as err:
      mwbx.load_queries(path, bank=servo_bank)
    assert message in str(err.value), str(err.value)
