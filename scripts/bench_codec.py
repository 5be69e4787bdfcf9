"""Benchmark of the qpos codec against baselines at the same l-infinity bound.

Data: quickstart and pachinko banks sampled here (raw qpos kept for the
comparison) plus simulated free boxes and an articulated chain. For each data
set, in the same run and at the same bound: raw float32; float32 + zstd;
quantize-to-bound + delta (1st and 2nd order) + zstd; SZ3 (``pysz``) if it
imports; and this codec. Also rate-distortion curves (paper Fig. 3), encode and
decode throughput, and what compression adds to ``mwbx sample`` wall time.

Writes out/bench/codec.json and out/bench/codec_rd.png and prints tables.

  .venv/bin/python scripts/bench_codec.py [--worlds 128] [--quick] [--replot]
"""

from __future__ import annotations

import argparse
import json
import pathlib
import platform
import time

import numpy as np
import zstandard

from mwbx.codec import ChannelLayout, CodecBounds, decode_world, encode_batch_checked
from mwbx.testing import codec_data as testing
from mwbx.codec.batch import decode_batch

ZSTD_LEVEL = 19
DECODE_TRIES = 5
OUT = pathlib.Path("out/bench")


# -- data ------------------------------------------------------------------------------


class Data:
  """qpos f32[W, T, nq], frame_count i64[W], layout, gravity, bodies per world."""

  def __init__(self, name, qpos, frame_count, layout, gravity, n_bodies):
    self.name, self.qpos, self.frame_count = name, qpos, np.asarray(frame_count, np.int64)
    self.layout, self.gravity, self.n_bodies = layout, float(gravity), int(n_bodies)

  @property
  def body_frames(self) -> int:
    return int(self.frame_count.sum()) * self.n_bodies

  def worlds(self):
    for w, n in enumerate(self.frame_count):
      yield self.qpos[w, :n]


def bank_data(config: str, n_worlds: int, seed: int = 1) -> tuple[Data, dict]:
  """Samples a bank keeping raw qpos; also times sampling with and without the codec."""
  import jax

  import mwbx
  from mwbx.qpos_store import RawQposStore

  cfg = mwbx.load_config(f"configs/{config}.yaml")
  timing = {}
  with mwbx.Sampler(cfg) as sampler:
    start = time.perf_counter()
    _, first = sampler.run(n_worlds, jax.random.key(seed + 1))  # compiles physics and codec
    timing["first_run_codec_s"] = first.codec_seconds
    timing["first_run_wall_s"] = time.perf_counter() - start
    raw_store = RawQposStore(sampler.scene.model.nq)
    start = time.perf_counter()
    raw_bank, raw_stats = sampler.run(n_worlds, jax.random.key(seed), store=raw_store)
    timing["sample_raw_s"] = time.perf_counter() - start
    start = time.perf_counter()
    bank, stats = sampler.run(n_worlds, jax.random.key(seed))
    timing["sample_codec_s"] = time.perf_counter() - start
    timing["codec_s"] = stats.codec_seconds
    timing["codec_overhead"] = timing["sample_codec_s"] / timing["sample_raw_s"] - 1.0
    timing["codec_share_of_wall"] = stats.codec_seconds / stats.wall_seconds
  fc = raw_bank.frame_count.astype(np.int64)
  model = raw_bank.model
  qpos = np.zeros((n_worlds, int(fc.max()), model.nq), np.float32)
  for w in range(n_worlds):
    qpos[w, :fc[w]] = raw_bank.qpos_frames(w)
    qpos[w, fc[w]:] = qpos[w, max(fc[w] - 1, 0)]
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  timing["bank_stats"] = bank.qpos_store.stats()
  return Data(config, qpos, fc, layout, model.opt.gravity[2], len(raw_bank.body_names)), timing


def simulated_data(kind: str, n_worlds: int, n_frames: int) -> Data:
  model = testing.boxes_model(6, seed=0) if kind == "boxes" else testing.chain_model()
  qpos = testing.record_batch(model, n_worlds, n_frames, seed=5)
  bad = ~np.isfinite(qpos).all(axis=-1)
  fc = np.where(bad.any(axis=1), np.argmax(bad, axis=1), n_frames)
  qpos = np.nan_to_num(qpos)
  layout = ChannelLayout.from_joints(model.jnt_type, model.jnt_qposadr, model.nq)
  n_bodies = len(set(model.jnt_bodyid.tolist()))
  return Data(f"sim_{kind}", qpos, fc, layout, model.opt.gravity[2], n_bodies)


def subset(data: Data, kind: str) -> Data:
  """Only the translation or only the rotation channels, as their own layout."""
  lay = data.layout
  if kind == "pos":
    cols = [a + i for a in lay.pos_adr for i in range(3)]
    sub = ChannelLayout(nq=len(cols), pos_adr=tuple(range(0, len(cols), 3)))
  else:
    cols = [a + i for a in lay.rot_adr for i in range(4)]
    sub = ChannelLayout(nq=len(cols), rot_adr=tuple(range(0, len(cols), 4)))
  return Data(f"{data.name}_{kind}", data.qpos[:, :, cols], data.frame_count, sub, data.gravity,
              data.n_bodies)


# -- baselines -------------------------------------------------------------------------


def _columns(layout: ChannelLayout):
  pos = [a + i for a in layout.pos_adr for i in range(3)]
  sca = list(layout.scalar_adr)
  return pos, sca


def _quat_step(e_rot: float) -> float:
  # Each of 4 components off by <= step/2: |dq| <= step, and the rotation angle
  # error is at most about 2 |dq|.
  return 0.45 * e_rot


def _canonical_quats(q: np.ndarray) -> np.ndarray:
  """Flip signs so consecutive quaternions have a positive dot product."""
  q = q / np.linalg.norm(q, axis=-1, keepdims=True)
  dots = np.sum(q[1:] * q[:-1], axis=-1)
  sign = np.concatenate([[1.0], np.cumprod(np.where(dots < 0, -1.0, 1.0))])
  return q * sign[:, None]


def _rot_error(dec: np.ndarray, true: np.ndarray) -> float:
  t = true / np.linalg.norm(true, axis=-1, keepdims=True)
  d = dec / np.linalg.norm(dec, axis=-1, keepdims=True)
  dot = np.clip(np.abs(np.sum(d * t, axis=-1)), 0, 1)
  return float(2 * np.arccos(dot).max()) if dot.size else 0.0


def quantize_world(q: np.ndarray, layout: ChannelLayout, bounds: CodecBounds):
  """Integer codes (i64[T, C]) within the bound, and the dequantized qpos."""
  pos, sca = _columns(layout)
  cols, steps = [], []
  for c in pos:
    cols.append(q[:, c].astype(np.float64))
    steps.append(2 * bounds.e_pos)
  for c in sca:
    cols.append(q[:, c].astype(np.float64))
    steps.append(2 * bounds.e_scalar)
  dec = q.astype(np.float64).copy()
  quat_cols = []
  for a in layout.rot_adr:
    cq = _canonical_quats(q[:, a:a + 4].astype(np.float64))
    quat_cols.append((a, cq))
    for i in range(4):
      cols.append(cq[:, i])
      steps.append(_quat_step(bounds.e_rot))
  values = np.stack(cols, axis=1) if cols else np.zeros((q.shape[0], 0))
  steps = np.array(steps)
  codes = np.round(values / steps).astype(np.int64)
  deq = codes * steps
  k = 0
  for c in pos + sca:
    dec[:, c] = deq[:, k]
    k += 1
  for a, _ in quat_cols:
    dec[:, a:a + 4] = deq[:, k:k + 4] / np.linalg.norm(deq[:, k:k + 4], axis=-1, keepdims=True)
    k += 4
  return codes, dec


def errors(dec: np.ndarray, q: np.ndarray, layout: ChannelLayout) -> tuple[float, float]:
  pos, sca = _columns(layout)
  e_pos = float(np.abs(dec[:, pos] - q[:, pos]).max()) if pos and q.size else 0.0
  e_rot = max([_rot_error(dec[:, a:a + 4], q[:, a:a + 4]) for a in layout.rot_adr], default=0.0)
  return e_pos, e_rot


def baseline_sizes(data: Data, bounds: CodecBounds, with_sz3: bool = True) -> dict:
  """Bytes per method (each world compressed on its own) and the errors they reach."""
  cctx = zstandard.ZstdCompressor(level=ZSTD_LEVEL)
  sizes = {"raw float32": 0, "float32+zstd": 0, "quant+delta1+zstd": 0, "quant+delta2+zstd": 0}
  worst = {k: [0.0, 0.0] for k in list(sizes) + ["sz3"]}
  sz3 = _sz3() if with_sz3 else None
  if sz3 is not None:
    sizes["sz3"] = 0
  for q in data.worlds():
    sizes["raw float32"] += q.nbytes
    sizes["float32+zstd"] += len(cctx.compress(np.ascontiguousarray(q.T).tobytes()))
    codes, dec = quantize_world(q, data.layout, bounds)
    e = errors(dec, q, data.layout)
    for order in (1, 2):
      d = codes.copy()
      for _ in range(order):
        d = np.concatenate([d[:1], np.diff(d, axis=0)])
      zz = ((d << 1) ^ (d >> 63)).astype(np.uint32)  # zigzag, fits: deltas of bounded codes
      name = f"quant+delta{order}+zstd"
      sizes[name] += len(cctx.compress(np.ascontiguousarray(zz.T).tobytes()))
      worst[name] = np.maximum(worst[name], e).tolist()
    if sz3 is not None:
      nbytes, dec = sz3(q, data.layout, bounds)
      sizes["sz3"] += nbytes
      worst["sz3"] = np.maximum(worst["sz3"], errors(dec, q, data.layout)).tolist()
  return {"bytes": sizes, "max_error": worst}


def _sz3():
  try:
    from pysz import sz, szConfig, szErrorBoundMode
  except ImportError:
    return None

  def compress(q, layout, bounds):
    pos, sca = _columns(layout)
    dec = q.astype(np.float64).copy()
    total = 0
    groups = [(pos, bounds.e_pos), (sca, bounds.e_scalar)]
    canon = {}
    for a in layout.rot_adr:
      canon[a] = _canonical_quats(q[:, a:a + 4].astype(np.float64)).astype(np.float32)
    if layout.rot_adr:
      groups.append(("quat", _quat_step(bounds.e_rot) / 2))
    for cols, bound in groups:
      if not len(cols) or q.shape[0] < 2:
        continue
      if cols == "quat":
        block = np.concatenate([canon[a] for a in layout.rot_adr], axis=1)
      else:
        block = q[:, cols]
      block = np.ascontiguousarray(block.T, np.float32)
      conf = szConfig()
      conf.errorBoundMode = szErrorBoundMode.ABS
      conf.absErrorBound = float(bound)
      conf.setDims(*block.shape)
      comp, _ = sz.compress(block, conf)
      total += comp.nbytes
      out, _ = sz.decompress(comp, np.float32, block.shape)
      out = np.asarray(out).T
      if cols == "quat":
        for i, a in enumerate(layout.rot_adr):
          qq = out[:, 4 * i:4 * i + 4].astype(np.float64)
          dec[:, a:a + 4] = qq / np.linalg.norm(qq, axis=-1, keepdims=True)
      else:
        dec[:, cols] = out
    return total, dec

  return compress


# -- the codec -------------------------------------------------------------------------


def codec_run(data: Data, bounds: CodecBounds, repeats: int = 1) -> dict:
  best_enc = np.inf
  for _ in range(repeats + 1):  # the first run compiles
    start = time.perf_counter()
    enc = encode_batch_checked(data.qpos, data.frame_count, data.layout, bounds, 120.0,
                               data.gravity)
    best_enc = min(best_enc, time.perf_counter() - start)
  blob = np.frombuffer(b"".join(enc.streams), np.uint8)
  offsets = np.concatenate([[0], np.cumsum([len(s) for s in enc.streams])])
  # One object: the channels of the first joint's body (a free body: 2 channels).
  lay = data.layout
  first = (lay.pos_adr + lay.rot_adr + lay.scalar_adr)[0]
  one_object = lay.channels_for(np.arange(first, first + 7 if lay.pos_adr else first + 1))
  best_dec = best_single = best_one = np.inf
  for _ in range(repeats):
    for _ in range(DECODE_TRIES):  # a decode takes ~10 ms: a few tries per repeat, best kept
      start = time.perf_counter()
      decode_batch(blob, offsets)
      best_dec = min(best_dec, time.perf_counter() - start)
      start = time.perf_counter()
      decode_batch(blob, offsets, channels=one_object)
      best_one = min(best_one, time.perf_counter() - start)
    start = time.perf_counter()
    for stream in enc.streams[:32]:
      decode_world(stream)
    best_single = min(best_single, (time.perf_counter() - start) / min(32, len(enc.streams)))
  nbytes = sum(len(s) for s in enc.streams)
  return {"bytes": nbytes, "max_error": enc.max_error.max(axis=0).tolist(),
          "raw_channels": int(enc.raw_channels.sum()), "encode_s": best_enc, "decode_s": best_dec,
          "encode_body_frames_per_s": data.body_frames / best_enc,
          "decode_body_frames_per_s": data.body_frames / best_dec,
          "decode_one_object_s": best_one, "decode_one_object_vs_all": best_one / best_dec,
          "decode_one_world_ms": 1e3 * best_single}


def baseline_speed(data: Data, bounds: CodecBounds, repeats: int) -> dict:
  """Encode/decode throughput of quantize + delta2 + zstd, the same way (per world)."""
  cctx, dctx = zstandard.ZstdCompressor(level=ZSTD_LEVEL), zstandard.ZstdDecompressor()
  worlds = list(data.worlds())
  best_enc = best_dec = np.inf
  for _ in range(repeats):
    start = time.perf_counter()
    blobs = []
    for q in worlds:
      codes, _ = quantize_world(q, data.layout, bounds)
      d = np.diff(np.diff(codes, axis=0, prepend=0), axis=0, prepend=0)
      blobs.append((cctx.compress(np.ascontiguousarray(((d << 1) ^ (d >> 63)).astype(np.uint32).T)
                                  .tobytes()), codes.shape))
    best_enc = min(best_enc, time.perf_counter() - start)
    for _ in range(DECODE_TRIES):  # as many tries as the codec's decode gets
      start = time.perf_counter()
      for blob, shape in blobs:
        zz = np.frombuffer(dctx.decompress(blob), np.uint32).reshape(shape[::-1]).T.astype(np.int64)
        d = (zz >> 1) ^ -(zz & 1)
        np.cumsum(np.cumsum(d, axis=0), axis=0)
      best_dec = min(best_dec, time.perf_counter() - start)
  return {"encode_body_frames_per_s": data.body_frames / best_enc,
          "decode_body_frames_per_s": data.body_frames / best_dec}


def compare(data: Data, bounds: CodecBounds, repeats: int) -> dict:
  base = baseline_sizes(data, bounds)
  ours = codec_run(data, bounds, repeats)
  speed = baseline_speed(data, bounds, repeats)
  raw = base["bytes"]["raw float32"]
  rows = {name: {"bytes": b, "ratio_vs_float32": raw / b,
                 "bits_per_body_frame": 8 * b / data.body_frames,
                 "max_error_pos_m": base["max_error"][name][0],
                 "max_error_rot_deg": float(np.rad2deg(base["max_error"][name][1]))}
          for name, b in base["bytes"].items()}
  rows["mwbx codec"] = {"bytes": ours["bytes"], "ratio_vs_float32": raw / ours["bytes"],
                        "bits_per_body_frame": 8 * ours["bytes"] / data.body_frames,
                        "max_error_pos_m": ours["max_error"][0],
                        "max_error_rot_deg": float(np.rad2deg(ours["max_error"][1]))}
  best = min((r["bytes"], n) for n, r in rows.items() if n not in ("raw float32", "mwbx codec"))
  return {"worlds": int(data.qpos.shape[0]), "body_frames": data.body_frames, "rows": rows,
          "best_baseline": best[1], "gain_vs_best_baseline": best[0] / ours["bytes"],
          "codec": ours, "quant+delta2+zstd speed": speed}


def rate_distortion(data: Data, scales) -> dict:
  """Bits per channel-frame (one free-joint translation, or one quaternion, for one
  frame) vs bound, translation and rotation separately."""
  out = {}
  for kind in ("pos", "rot"):
    sub = subset(data, kind)
    if sub.layout.n_channels == 0:
      continue
    curve = []
    for s in scales:
      bounds = CodecBounds(e_pos=1e-3 * s, e_rot=float(np.deg2rad(0.5)) * s, e_scalar=1e-3 * s)
      enc = encode_batch_checked(sub.qpos, sub.frame_count, sub.layout, bounds, 120.0,
                                 sub.gravity)
      nbytes = sum(len(x) for x in enc.streams)
      channel_frames = int(sub.frame_count.sum()) * sub.layout.n_channels
      curve.append({"bound": bounds.e_pos if kind == "pos" else float(np.rad2deg(bounds.e_rot)),
                    "bits_per_channel_frame": 8 * nbytes / channel_frames})
    out[kind] = curve
  return out


def _table(name: str, result: dict) -> str:
  lines = [f"\n{name}: {result['worlds']} worlds, {result['body_frames']:,} body-frames",
           f"{'method':<20}{'bytes':>12}{'x float32':>11}{'bits/body-frame':>17}"
           f"{'max err mm':>12}{'max err deg':>13}"]
  for method, r in result["rows"].items():
    lines.append(f"{method:<20}{r['bytes']:>12,}{r['ratio_vs_float32']:>11.1f}"
                 f"{r['bits_per_body_frame']:>17.2f}{1e3 * r['max_error_pos_m']:>12.3f}"
                 f"{r['max_error_rot_deg']:>13.3f}")
  c, b = result["codec"], result["quant+delta2+zstd speed"]
  lines.append(f"codec vs best baseline ({result['best_baseline']}): "
               f"{result['gain_vs_best_baseline']:.2f}x smaller")
  lines.append(f"encode {c['encode_body_frames_per_s'] / 1e6:.2f} M body-frames/s "
               f"(quant+delta2+zstd {b['encode_body_frames_per_s'] / 1e6:.2f}), decode all worlds "
               f"{c['decode_body_frames_per_s'] / 1e6:.2f} M body-frames/s (quant+delta2+zstd "
               f"{b['decode_body_frames_per_s'] / 1e6:.2f}), one world {c['decode_one_world_ms']:.2f} ms, "
               f"one object of every world {1e3 * c['decode_one_object_s']:.1f} ms "
               f"({c['decode_one_object_vs_all']:.2f} of decoding everything)")
  return "\n".join(lines)


def _plot(rd: dict, path: pathlib.Path):
  import matplotlib
  import matplotlib.ticker
  matplotlib.use("Agg")
  import matplotlib.pyplot as plt
  fig, axes = plt.subplots(1, 2, figsize=(10, 4))
  for ax, kind, unit in ((axes[0], "pos", "bound (m)"), (axes[1], "rot", "bound (deg)")):
    for name, curves in rd.items():
      if kind in curves:
        xs = [p["bound"] for p in curves[kind]]
        ys = [p["bits_per_channel_frame"] for p in curves[kind]]
        ax.plot(xs, ys, "o-", label=name)
    ax.set_xscale("log")
    ticks = sorted({p["bound"] for curves in rd.values() for p in curves.get(kind, [])})
    ax.set_xticks(ticks, [f"{t:.3g}" for t in ticks])
    ax.xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    ax.set_xlabel(unit)
    ax.set_ylabel("bits per channel-frame")
    ax.set_title("translation (free joints)" if kind == "pos" else "rotation (free and ball joints)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
  fig.tight_layout()
  fig.savefig(path, dpi=120)


def main():
  parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
  parser.add_argument("--replot", action="store_true", help="redraw the PNG from the JSON")
  parser.add_argument("--worlds", type=int, default=128, help="worlds per sampled bank")
  parser.add_argument("--quick", action="store_true", help="small run (smoke test)")
  args = parser.parse_args()
  if args.replot:
    _plot(json.loads((OUT / "codec.json").read_text())["rate_distortion"], OUT / "codec_rd.png")
    return
  n = 16 if args.quick else args.worlds
  repeats = 1 if args.quick else 3
  bounds = CodecBounds()
  OUT.mkdir(parents=True, exist_ok=True)
  machine = f"{platform.machine()} {platform.processor() or ''}".strip()
  report = {"machine": machine, "cpu_count": __import__("os").cpu_count(),
            "bounds": bounds.to_json(), "zstd_level": ZSTD_LEVEL, "data": {}, "sampling": {},
            "rate_distortion": {}}
  sets = []
  for config in ("quickstart", "pachinko"):
    data, timing = bank_data(config, n)
    report["sampling"][config] = timing
    sets.append(data)
  sets.append(simulated_data("boxes", max(4, n // 8), 480))
  sets.append(simulated_data("chain", max(4, n // 8), 480))
  for data in sets:
    result = compare(data, bounds, repeats)
    report["data"][data.name] = result
    print(_table(data.name, result), flush=True)
  scales = [0.25, 0.5, 1, 2, 4] if not args.quick else [0.5, 1, 2]
  for data in sets:
    if data.name in ("pachinko", "sim_chain", "quickstart"):
      report["rate_distortion"][data.name] = rate_distortion(data, scales)
  for config, t in report["sampling"].items():
    print(f"\nmwbx sample {config} ({n} worlds, compiled): raw store {t['sample_raw_s']:.2f} s, "
          f"compressed {t['sample_codec_s']:.2f} s (+{100 * t['codec_overhead']:.1f} %), codec "
          f"{t['codec_s']:.2f} s = {100 * t['codec_share_of_wall']:.1f} % of wall; first run "
          f"(compiling): codec {t['first_run_codec_s']:.2f} s of {t['first_run_wall_s']:.2f} s")
  (OUT / "codec.json").write_text(json.dumps(report, indent=2, default=float))
  _plot(report["rate_distortion"], OUT / "codec_rd.png")
  print(f"\nwrote {OUT / 'codec.json'} and {OUT / 'codec_rd.png'}")


if __name__ == "__main__":
  main()
