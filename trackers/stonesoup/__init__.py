"""Stone Soup's trackers as peers, registered as ``ss-gnn``, ``ss-gmphd`` and ``ss-jpda``.

Modules: :mod:`.peers` (the adapter shared by the peers, :class:`StoneSoupGNN` and
:class:`StoneSoupGMPHD`), :mod:`.gnn_cells` (what ``ss-gnn`` reads from the cell geometry:
the gate's distance to a detection's cell, labels that follow a target) and :mod:`.jpda`
(:class:`StoneSoupJPDA`). Stone Soup is an
optional extra (``pip install 'mttbench[stonesoup]'``): this package imports without it,
and the peers import Stone Soup on their first reset.
"""

from .jpda import StoneSoupJPDA
from .peers import EXTRA_HINT, StoneSoupGMPHD, StoneSoupGNN, missing_extra

__all__ = ["EXTRA_HINT", "StoneSoupGMPHD", "StoneSoupGNN", "StoneSoupJPDA", "missing_extra"]
