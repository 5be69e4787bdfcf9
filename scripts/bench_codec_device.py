"""The codec with JAX's default device the accelerator and the host's CPU, in one run.

On a GPU machine JAX's default device is the GPU. The codec's fit is
compiled host code (``mwbx.codec.fit_kernels``), so a bank's streams must not
depend on it; this checks that on the same recordings (boxes dropped in
MuJoCo C, 8 free bodies): the seconds of ``encode_batch_checked`` with each
default, alternating (the first run includes loading the compiled code), and
whether the two give the same streams.

  python scripts/bench_codec_device.py [--worlds 512] [--frames 600] --out out/bench/gpu.json

Adds a ``codec_fit`` entry to the --out JSON (scripts/gpu_check.sh's), which
``make_benchmarks_doc.py`` shows in the GPU section.
"""

from __future__ import annotations

import argparse
import json
import pathlib
import time

import jax
import numpy as np

from mwbx.codec import ChannelLayout, CodecBounds, encode_batch_checked
from mwbx.host_device import host_cpu
from mwbx.testing import codec_data as testing

REPO = pathlib.Path(__file__).resolve().parents[1]


def main() -> None:
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--worlds", type=int, default=512)
  parser.add_argument("--frames", type=int, default=600)
  parser.add_argument("--repeats", type=int, default=3)
  parser.add_argument("--out", type=pathlib.Path, default=REPO / "out" / "bench" / "gpu.json")
  args = parser.parse_args()
  start = time.perf_counter()
  model = testing.boxes_model(8, seed=0)
  qpos = testing.record_batch(model, args.worlds, args.frames, seed=5)
  frames = np.full(args.worlds, args.frames)
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  print(f"recorded {args.worlds} worlds x {args.frames} frames in {time.perf_counter() - start:.1f} s;"
        f" JAX's default device {jax.devices()[0]}", flush=True)
  result = {"worlds": args.worlds, "frames": args.frames, "bodies": 8, "default_device": str(jax.devices()[0]),
            "host_device": str(host_cpu()), "runs": []}
  streams = {}
  for repeat in range(args.repeats):
    for fit_on in ("default", "host cpu"):
      with jax.default_device(None if fit_on == "default" else host_cpu()):
        start = time.perf_counter()
        encoded = encode_batch_checked(qpos, frames, layout, CodecBounds(), 120.0, float(model.opt.gravity[2]))
        seconds = time.perf_counter() - start
      streams[fit_on] = encoded.streams
      result["runs"].append({"repeat": repeat, "fit_on": fit_on, "seconds": seconds,
                             "bytes": sum(map(len, encoded.streams))})
      print(result["runs"][-1], flush=True)
  result["same_streams"] = streams["default"] == streams["host cpu"]
  print(f"same streams: {result['same_streams']}")
  data = json.loads(args.out.read_text()) if args.out.exists() else {}
  data["codec_fit"] = result
  args.out.parent.mkdir(parents=True, exist_ok=True)
  args.out.write_text(json.dumps(data, indent=1))
  print(f"wrote {args.out}")


if __name__ == "__main__":
  main()
