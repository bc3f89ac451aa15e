"""``pmb``: a track-oriented Poisson multi-Bernoulli filter on the Rayleigh cell sensor.

Modules: :mod:`.tracker` (the :class:`PMBTracker`, registered as ``pmb``), :mod:`.update`
(the cell likelihood and the marginal multi-Bernoulli update), :mod:`.lbp` (association
marginals by loopy belief propagation), :mod:`.ppp` (the undetected-target intensity).
docs/pmb.md has the measurements and the commands that repeat them.
"""

from .lbp import Marginals, association_marginals
from .tracker import PMBTracker
from .update import CellRatios, PMBUpdate, cell_ratios, pmb_update

__all__ = ["CellRatios", "Marginals", "PMBTracker", "PMBUpdate", "association_marginals",
           "cell_ratios", "pmb_update"]
