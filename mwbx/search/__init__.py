"""Goal-seeking (beyond the paper): :func:`solve` searches refinements for a
world that meets every query by itself (how it searches: :class:`SolveOptions`);
:func:`guided_sample` learns where in the configured randomization such
worlds start (optax, evolution strategies).

It simulates nothing of its own: it calls the sampler and
:mod:`mwbx.refinement`, and reads queries' answers and gaps from
:mod:`mwbx.queries`.
"""

from mwbx.search.guided import GuidedResult
from mwbx.search.guided import GuidedRound
from mwbx.search.guided import default_optimizer
from mwbx.search.guided import guided_sample
from mwbx.search.objects import involved_objects
from mwbx.search.proposal import Proposal
from mwbx.search.proposal import init_proposal
from mwbx.search.solver import Budget
from mwbx.search.solver import SolveInterrupted
from mwbx.search.solver import SolveOptions
from mwbx.search.solver import SolveResult
from mwbx.search.solver import SolveStep
from mwbx.search.solver import place_queries
from mwbx.search.solver import progress_plot
from mwbx.search.solver import solve
