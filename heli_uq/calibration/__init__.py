"""Calibration of the package's posterior: simulation-based calibration (SBC) of NUTS on
synthetic records drawn from the prior (:mod:`heli_uq.calibration.sbc`; its settings and
their record in a run directory, :mod:`heli_uq.calibration.settings`), its rank statistics
(:mod:`heli_uq.calibration.ranks`) and
rank histograms (:mod:`heli_uq.calibration.figures`).

Layer 8 (imports everything below it except discovery and design; only scripts use it).
"""

from heli_uq.calibration.figures import plot_ranks as plot_ranks
from heli_uq.calibration.ranks import summarise as summarise
from heli_uq.calibration.sbc import load_replicates as load_replicates
from heli_uq.calibration.sbc import run_replicate as run_replicate
from heli_uq.calibration.sbc import run_sbc as run_sbc
from heli_uq.calibration.settings import SBCSettings as SBCSettings

__all__ = ["SBCSettings", "run_sbc", "run_replicate", "load_replicates", "summarise", "plot_ranks"]
