"""The bank: every world of one scene, its ids and lineage, on disk as shards."""

from mwbx.bank.flags import FLAG_AT_REST
from mwbx.bank.flags import FLAG_CONTACT_OVERFLOW
from mwbx.bank.flags import FLAG_FINISHED
from mwbx.bank.flags import FLAG_SIM_ERROR
from mwbx.bank.flags import FLAG_UNSTABLE
from mwbx.bank.stores import QPOS_STORES
from mwbx.bank.core import Bank
from mwbx.bank.core import rows_of
from mwbx.bank.shards import BankDirectory
