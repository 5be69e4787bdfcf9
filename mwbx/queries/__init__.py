"""Screen-space frustum queries and ranking metrics over a bank (paper §4)."""

from mwbx.queries.camera import Camera
from mwbx.queries.camera import ScreenBox
from mwbx.queries.event import OrderQuery
from mwbx.queries.event import TouchQuery
from mwbx.queries.frustum import Frustum
from mwbx.queries.gaps import query_gaps
from mwbx.queries.joint import JointQuery
from mwbx.queries.metrics import Term
from mwbx.queries.metrics import metric
from mwbx.queries.metrics import orientation_error
from mwbx.queries.metrics import rank
from mwbx.queries.metrics import score
from mwbx.queries.orientation import OrientationQuery
from mwbx.queries.paths import body_radii
from mwbx.queries.paths import first_entry
from mwbx.queries.query import Query
from mwbx.queries.query import VolumeQuery
from mwbx.queries.query import constraints_satisfied
from mwbx.queries.query import evaluate
from mwbx.queries.query import evaluate_each
from mwbx.queries.query import Kept
from mwbx.queries.query import kept
from mwbx.queries.query_file import QuerySet
from mwbx.queries.query_file import load_queries
