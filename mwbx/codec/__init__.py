"""Error-bounded trajectory codec (paper section 3): piecewise fits, Rice codes."""

from mwbx.codec.batch import decode_batch
from mwbx.codec.decode import decode_world
from mwbx.codec.encode import EncodedBatch
from mwbx.codec.encode import encode_batch
from mwbx.codec.encode import encode_batch_checked
from mwbx.codec.encode import encode_world
from mwbx.codec.layout import ChannelLayout
from mwbx.codec.layout import CodecBounds
from mwbx.codec.layout import CodecError
from mwbx.codec.store import CompressedQposStore
from mwbx.codec.stream import Quanta
