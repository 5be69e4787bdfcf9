"""Line segments as a binary glTF (GLB) file: native WebGL lines on the page.

viser draws its own line segments (``add_line_segments``) as one instanced
screen-space quad per segment (three.js ``LineSegments2``), which software
WebGL pays for per instance (about 22 µs a segment a frame). A GLB whose one
primitive is in ``LINES`` mode (glTF ``mode`` 1) with an unlit material
becomes a plain ``THREE.LineSegments`` in the page (``add_glb``): one draw
call, a pixel wide, the colour unshaded.

The file holds one mesh node with one primitive: ``POSITION`` (float32, two
vertices a segment) and a ``KHR_materials_unlit`` material whose base colour
is the segments' colour (glTF colour factors are linear; the page shows
sRGB). :func:`read_line_segments` is its reader (the tests also read the file
with trimesh, an independent glTF reader).
"""

from __future__ import annotations

import json
import struct

import numpy as np

# Binary glTF 2.0 framing: the header's magic, then chunks of these types.
GLB_MAGIC = 0x46546C67  # b"glTF"
GLB_VERSION = 2
CHUNK_JSON = 0x4E4F534A  # b"JSON"
CHUNK_BIN = 0x004E4942  # b"BIN\0"
MODE_LINES = 1
FLOAT32 = 5126  # glTF componentType
ARRAY_BUFFER = 34962  # glTF bufferView target


def srgb_to_linear(c: np.ndarray) -> np.ndarray:
  """Linear channel values f64[...] in [0, 1] from sRGB ones (IEC 61966-2-1)."""
  c = np.asarray(c, np.float64)
  return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(c: np.ndarray) -> np.ndarray:
  """sRGB channel values from linear ones: the inverse of :func:`srgb_to_linear`."""
  c = np.asarray(c, np.float64)
  return np.where(c <= 0.0031308, c * 12.92, 1.055 * c ** (1 / 2.4) - 0.055)


def _padded(data: bytes, fill: bytes) -> bytes:
  return data + fill * (-len(data) % 4)


def line_segments(segments: np.ndarray, rgb: tuple[int, int, int]) -> bytes:
  """A GLB file of line segments in one colour.

  Args:
    segments: f32[N, 2, 3] segment end points, m (N >= 1).
    rgb: the colour, sRGB 0-255 (as the page shows it).

  Returns:
    The file's bytes (for ``server.scene.add_glb``).

  Example:
    >>> data = line_segments(np.zeros((1, 2, 3)), (0, 128, 0))
    >>> read_line_segments(data)[1]
    (0, 128, 0)
  """
  points = np.ascontiguousarray(np.asarray(segments, np.float32).reshape(-1, 3))
  if points.shape[0] == 0:
    raise ValueError("a GLB of line segments needs at least one segment")
  blob = points.tobytes()
  colour = srgb_to_linear(np.asarray(rgb, np.float64) / 255.0).tolist() + [1.0]
  doc = {
      "asset": {"version": "2.0", "generator": "mwbx"},
      "scene": 0,
      "scenes": [{"nodes": [0]}],
      "nodes": [{"mesh": 0}],
      "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "mode": MODE_LINES, "material": 0}]}],
      "materials": [{"pbrMetallicRoughness": {"baseColorFactor": colour, "metallicFactor": 0.0},
                     "extensions": {"KHR_materials_unlit": {}}}],
      "extensionsUsed": ["KHR_materials_unlit"],
      "buffers": [{"byteLength": len(blob)}],
      "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(blob), "target": ARRAY_BUFFER}],
      "accessors": [{"bufferView": 0, "componentType": FLOAT32, "count": int(points.shape[0]), "type": "VEC3",
                     "min": points.min(axis=0).tolist(), "max": points.max(axis=0).tolist()}],
  }
  text = _padded(json.dumps(doc, separators=(",", ":")).encode(), b" ")
  blob = _padded(blob, b"\0")
  body = struct.pack("<II", len(text), CHUNK_JSON) + text + struct.pack("<II", len(blob), CHUNK_BIN) + blob
  return struct.pack("<III", GLB_MAGIC, GLB_VERSION, 12 + len(body)) + body


def _document(data: bytes) -> dict:
  magic, version, length = struct.unpack_from("<III", data, 0)
  if magic != GLB_MAGIC or version != GLB_VERSION or length != len(data):
    raise ValueError("not a GLB 2.0 file")
  text_len, kind = struct.unpack_from("<II", data, 12)
  if kind != CHUNK_JSON:
    raise ValueError("a GLB file's first chunk is its JSON")
  return json.loads(data[20:20 + text_len])


def segment_count(data: bytes) -> int:
  """Segments in a file written by :func:`line_segments` (its JSON read alone)."""
  doc = _document(data)
  primitive = doc["meshes"][0]["primitives"][0]
  return int(doc["accessors"][primitive["attributes"]["POSITION"]]["count"]) // 2


def read_line_segments(data: bytes) -> tuple[np.ndarray, tuple[int, int, int]]:
  """(segments f32[N, 2, 3], sRGB colour 0-255) of a file written by
  :func:`line_segments` (its twin, for tests and tools)."""
  doc = _document(data)
  text_len = struct.unpack_from("<I", data, 12)[0]
  blob_len, kind = struct.unpack_from("<II", data, 20 + text_len)
  blob = data[28 + text_len:28 + text_len + blob_len]
  primitive = doc["meshes"][0]["primitives"][0]
  if primitive.get("mode") != MODE_LINES:
    raise ValueError("the GLB's primitive is not LINES")
  accessor = doc["accessors"][primitive["attributes"]["POSITION"]]
  view = doc["bufferViews"][accessor["bufferView"]]
  start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
  points = np.frombuffer(blob, np.float32, accessor["count"] * 3, start).reshape(-1, 2, 3)
  factor = doc["materials"][primitive["material"]]["pbrMetallicRoughness"]["baseColorFactor"]
  rgb = np.round(linear_to_srgb(np.asarray(factor[:3])) * 255.0).astype(int)
  return points, tuple(int(c) for c in rgb)
