"""mwbx: Many-Worlds Browsing on JAX and MuJoCo.

Sample thousands of plausible variations of a multibody scene, keep them in a
bank, find the world you want with queries and metrics, refine it, view it.

Example::

  import jax, mwbx
  scene = mwbx.load_config("configs/quickstart.yaml")
  bank = mwbx.sample(scene, n_worlds=1024, key=jax.random.key(0))
  bank.save("out/quick"); bank2 = mwbx.Bank.load("out/quick")
"""

from mwbx.bank import Bank
from mwbx.bank import FLAG_AT_REST
from mwbx.bank import FLAG_FINISHED
from mwbx.bank import FLAG_UNSTABLE
from mwbx.batch_sim import METRIC_NAMES
from mwbx.batch_sim import SampleStats
from mwbx.batch_sim import Sampler
from mwbx.batch_sim import sample
from mwbx.batch_sim.refine import refine
from mwbx.config import Config
from mwbx.config import config_from_dict
from mwbx.config import load_config
from mwbx.errors import MwbxError
from mwbx.scene import Scene

__version__ = "0.1.0"
