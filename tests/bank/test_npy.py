"""mwbx.bank.npy.read returns what np.load(allow_pickle=False) returns, and
fails where it fails, for every file a shard could hold."""

import numpy as np
import pytest

from mwbx.bank import npy

ARRAYS = {
    "i8": np.arange(256),
    "f4_2d": np.linspace(0, 1, 15, dtype=np.float32).reshape(5, 3),
    "bool": np.array([True, False]),
    "u1_empty_rows": np.zeros((0, 3), np.uint8),
    "scalar": np.array(3.5),
    "empty": np.zeros(0, np.int16),
    "c8": np.array([1 + 2j], np.complex64),
    "big_endian": np.arange(4, dtype=">i4"),  # the pattern's path too
    "fortran": np.asfortranarray(np.arange(12.0).reshape(3, 4)),  # np.load's path
    "unicode": np.array(["ab", "c"]),  # np.load's path
}


@pytest.mark.parametrize("name", sorted(ARRAYS))
def test_reads_what_np_load_reads(tmp_path, name):
  path = tmp_path / f"{name}.npy"
  np.save(path, ARRAYS[name])
  got, expected = npy.read(path), np.load(path, allow_pickle=False)
  assert got.dtype == expected.dtype and got.shape == expected.shape
  np.testing.assert_array_equal(got, expected)
  assert got.flags.writeable and got.flags.c_contiguous == expected.flags.c_contiguous
  got[...] = 0  # its own memory: the file is untouched
  np.testing.assert_array_equal(np.load(path), ARRAYS[name])


def test_a_truncated_or_padded_file_fails_as_np_load_does(tmp_path):
  path = tmp_path / "ids.npy"
  np.save(path, np.arange(100))
  data = path.read_bytes()
  path.write_bytes(data[:-8])  # a row short: the header's size disagrees
  with pytest.raises(ValueError):
    npy.read(path)
  path.write_bytes(data + b"\0" * 8)  # a row too many: np.load reads the header's count
  np.testing.assert_array_equal(npy.read(path), np.load(path))


def test_objects_are_never_unpickled(tmp_path):
  path = tmp_path / "objects.npy"
  np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
  with pytest.raises(ValueError, match="allow_pickle"):
    npy.read(path)


def test_not_an_npy_file(tmp_path):
  path = tmp_path / "junk.npy"
  path.write_bytes(b"\x93NUMPY\x01\x00\xff\xff{'descr'")  # a header longer than the file
  with pytest.raises(ValueError):
    npy.read(path)
