"""The paper's Gaussian particle filter (GPF), registered as ``gpf``.

Modules: :mod:`.tracker` (the :class:`GaussianParticleFilter`), :mod:`.grid` (its
kernels for the Rayleigh grid sensor) and :mod:`.linear` (its kernels for the
superposition sensor, and the combination enumeration). The method, its equations and
its departures from the paper are in each module's docstring; the measurements behind
the defaults in docs/gpf.md.
"""

from .grid import fold_into_workspace, grid_update, known_existence_update, rect_state_moments
from .linear import enumerate_combinations, superposition_update
from .tracker import (
    DEFAULT_DEATH_FLOOR,
    EmptyPriorGPF,
    GaussianParticleFilter,
    collapse,
    condition_on_count_bound,
    merge_groups,
    merge_particles,
    truncate_to_workspace,
)

__all__ = [
    "DEFAULT_DEATH_FLOOR", "EmptyPriorGPF", "GaussianParticleFilter",
    "collapse", "condition_on_count_bound", "enumerate_combinations", "fold_into_workspace",
    "grid_update", "known_existence_update", "merge_groups", "merge_particles",
    "rect_state_moments", "superposition_update", "truncate_to_workspace",
]
