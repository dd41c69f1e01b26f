"""Experiment design (``heli-uq design``, the paper's challenge 1b): a voltage staircase within
the rig's limits that is most informative about the identifiable parameter combinations, or
that best tells two rival models apart.

Layer 8 (imports everything below it; only the CLI imports it).  One module per concept:
``staircase`` (the inputs searched over and their bounds), ``information`` (expected
information gain), ``discrimination`` (two rival models), ``search`` (random staircases,
then a hill climb), ``figures`` and ``experiment`` (the workflow and its files).
"""

from heli_uq.design.discrimination import Rivals as Rivals
from heli_uq.design.experiment import DESIGN_KEYS as DESIGN_KEYS
from heli_uq.design.experiment import design as design
from heli_uq.design.information import DesignPrior as DesignPrior
from heli_uq.design.information import InformationGain as InformationGain
from heli_uq.design.search import SEARCH_BUDGETS as SEARCH_BUDGETS
from heli_uq.design.search import search_staircase as search_staircase
from heli_uq.design.staircase import Staircase as Staircase
from heli_uq.design.staircase import StaircaseBounds as StaircaseBounds

__all__ = ["design", "DESIGN_KEYS", "DesignPrior", "InformationGain", "Rivals", "SEARCH_BUDGETS",
           "search_staircase", "Staircase", "StaircaseBounds"]
