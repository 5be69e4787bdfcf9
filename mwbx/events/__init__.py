"""Contact events: which objects (and named static geoms) touched, when and how often."""

from mwbx.events.actors import Actors
from mwbx.events.actors import actors_of
from mwbx.events.detect import TOUCH_MARGIN_PER_E_POS
from mwbx.events.detect import detect_events
from mwbx.events.detect import touch_margin
from mwbx.events.record import EVENTS_VERSION
from mwbx.events.record import EventRecord
