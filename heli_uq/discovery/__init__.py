"""Discovery: where a model and a record disagree, which named effect is missing, and the
refitted model that closes the gap (``heli-uq discover``).

Layer 8 (imports everything below it; only the CLI imports it).  One module per step:
``locate`` (where the base model fails), ``screen`` (the axes it fits to white noise),
``implied`` (the torque the data imply and each effect's feature), ``sindy`` (pysindy
ranking), ``candidates`` (one model fitted and scored, the Dask task), ``rounds`` (a
round of candidate fits, stored and reused),
``nesting`` (which fit can stand for or start another: restarts, pairs, carried fits),
``score`` (blocked held-out scores and gap metrics), ``decide`` (ranking, ties and the
choice), ``workflow`` (the steps), ``report`` (refit and outputs), ``report_page``
(``report.md``), ``candidates_figure`` (``candidates.png``).
"""

from heli_uq.discovery.budget import BUDGETS as BUDGETS
from heli_uq.discovery.budget import Budget as Budget
from heli_uq.discovery.report import DISCOVERY_KEYS as DISCOVERY_KEYS
from heli_uq.discovery.score import MARGIN_PER_SAMPLE as MARGIN_PER_SAMPLE
from heli_uq.discovery.score import MARGIN_SE as MARGIN_SE
from heli_uq.discovery.workflow import candidate_effects as candidate_effects
from heli_uq.discovery.workflow import discover as discover

__all__ = ["discover", "Budget", "BUDGETS", "MARGIN_SE", "MARGIN_PER_SAMPLE", "DISCOVERY_KEYS",
           "candidate_effects"]
