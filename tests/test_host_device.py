"""mwbx's host stages (the codec, initial states from a world's key) give the
same results whatever JAX's default device is (`mwbx.host_device`): on a GPU
machine the default is the GPU, where float32 rounds differently, and a bank's
streams or a world's initial state would depend on the accelerator.

Each test runs a child with two CPU devices and the default set to the second
(standing in for an accelerator)."""

import subprocess
import sys

from conftest import REPO, TESTS

# The codec's fit is compiled host code (no JAX): the streams are the same
# with either device as the default.
_CODEC_CHILD = """
import jax
jax.config.update("jax_num_cpu_devices", 2)
import numpy as np
from mwbx.testing import codec_data as testing
from mwbx.codec import ChannelLayout, CodecBounds, encode_batch_checked
from mwbx.codec import encode

devices = jax.devices("cpu")
encode.FIT_BATCH = 4  # several batches: the pool's threads fit them
model = testing.boxes_model(3, seed=1)
qpos = testing.record_batch(model, 4, 300, seed=2)
layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
frames = np.array([300, 250, 2, 173])
streams = {}
for default in devices[::-1]:
  jax.config.update("jax_default_device", default)  # global, as an accelerator is
  streams[str(default)] = encode_batch_checked(qpos, frames, layout, CodecBounds(), 120.0).streams
assert streams[str(devices[0])] == streams[str(devices[1])]
print("ok")
"""


# Initial states from the worlds' keys: on the first device, and the same
# values with either device as the default.
_INIT_CHILD = """
import jax
jax.config.update("jax_num_cpu_devices", 2)
import numpy as np
import mwbx
from mwbx.batch_sim.sampler import world_keys

devices = jax.devices("cpu")
cfg = mwbx.load_config({config!r})
states = {{}}
with mwbx.Sampler(cfg, backend="native") as sampler:
  _, init_keys, _ = world_keys(jax.random.key(3), np.arange(5))
  for default in devices[::-1]:
    jax.config.update("jax_default_device", default)
    for n in (5, 1):
      qpos, qvel = sampler._init(init_keys[:n])
      assert qpos.devices() == qvel.devices() == {{devices[0]}}, (str(default), qpos.devices())
      states[str(default), n] = np.asarray(qpos), np.asarray(qvel)
for n in (5, 1):
  for a, b in zip(states[str(devices[0]), n], states[str(devices[1]), n]):
    np.testing.assert_array_equal(a, b)
print("ok")
"""


def _child(code: str) -> None:
  out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600, cwd=REPO)
  assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stdout[-2000:] + out.stderr[-3000:]


def test_the_codec_streams_are_the_same_whatever_the_default_device():
  _child(_CODEC_CHILD)


def test_initial_states_are_drawn_on_the_host_cpu_whatever_the_default_device():
  _child(_INIT_CHILD.format(config=str(TESTS / "scenes" / "tiny.yaml")))
