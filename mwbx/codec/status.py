"""Status codes of the codec's compiled loops, and their one decorator.

The loops (``rice_kernels``, ``stream_kernels``, ``eval_kernels``) run under
numba with ``cache=True`` and ``nogil=True`` (a sampler may compress in one
thread while another decodes). They never raise: a problem comes back as a
status code and the caller turns it into a ``CodecError`` naming it.
"""

from __future__ import annotations

STATUS_OK = 0
STATUS_TRUNCATED = 1
STATUS_COUNT = 2
STATUS_UNARY_LENGTH = 3
STATUS_UNARY_CODES = 4
STATUS_UNARY_TOO_LONG = 5
STATUS_BLOB_LENGTH = 6
STATUS_VALUE_RANGE = 7
STATUS_HEADER = 8
STATUS_SEGMENT_COUNT = 9
STATUS_SEGMENT_SIZE = 10
STATUS_SEGMENT_LENGTH = 11
STATUS_VELOCITY = 12

STATUS_TEXT = {
    STATUS_TRUNCATED: "truncated stream",
    STATUS_COUNT: "too many values",
    STATUS_UNARY_LENGTH: "unary length out of range",
    STATUS_UNARY_CODES: "unary codes do not match counts",
    STATUS_UNARY_TOO_LONG: "unary code too long",
    STATUS_BLOB_LENGTH: "blob length mismatch",
    STATUS_VALUE_RANGE: "value out of range",
    STATUS_HEADER: "header does not match the batch",
    STATUS_SEGMENT_COUNT: "segment count out of range",
    STATUS_SEGMENT_SIZE: "segment data size does not match segment counts",
    STATUS_SEGMENT_LENGTH: "segment lengths do not add up to the frame count",
    STATUS_VELOCITY: "velocity out of range",
}
