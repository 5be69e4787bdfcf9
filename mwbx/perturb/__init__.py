"""Impact detection and plausible impulse sampling, pure JAX (paper §2)."""

from mwbx.perturb.impulses import PerturbParams
from mwbx.perturb.impulses import impulse_wrench
from mwbx.perturb.impulses import lobe_direction
from mwbx.perturb.impulses import orthonormal_basis
from mwbx.perturb.impulses import perturbation_from_uniforms
from mwbx.perturb.impulses import sample_lobe_direction
from mwbx.perturb.impulses import velocity_change
from mwbx.perturb.sparse import batch_perturbations
from mwbx.perturb.sparse import body_step_uniforms
