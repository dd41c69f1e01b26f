"""Identifiability: structural rank and named null space, Fisher information, profile
likelihoods and prior-to-posterior contraction, cross-checked in one report.

Layer 6 (imports data, model, simulate, probability and inference).
"""

from heli_uq.identifiability.fisher import fisher_information as fisher_information
from heli_uq.identifiability.fisher import fit_likelihood as fit_likelihood
from heli_uq.identifiability.report import identifiability_report as identifiability_report
from heli_uq.identifiability.structural import ParameterVector as ParameterVector
from heli_uq.identifiability.structural import analytic_null_directions as analytic_null_directions
from heli_uq.identifiability.structural import scaling_direction as scaling_direction
from heli_uq.identifiability.structural import sensitivity_matrix as sensitivity_matrix
from heli_uq.identifiability.structural import structural_analysis as structural_analysis

__all__ = ["fisher_information", "fit_likelihood", "identifiability_report", "ParameterVector",
           "analytic_null_directions", "scaling_direction", "sensitivity_matrix",
           "structural_analysis"]  # fmt: skip
