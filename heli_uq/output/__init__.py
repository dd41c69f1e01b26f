"""Output: InferenceData (NetCDF) with the model, diagnostics and health checks, figures,
the posterior study and the prior predictive check.

Layer 7 (imports everything below it; discovery, design and the CLI import it).
"""

from heli_uq.output.diagnostics import convergence as convergence
from heli_uq.output.diagnostics import predictive_checks as predictive_checks
from heli_uq.output.diagnostics import predictive_metrics as predictive_metrics
from heli_uq.output.diagnostics import summarize as summarize
from heli_uq.output.health import check_health as check_health
from heli_uq.output.inference_data import load_posterior as load_posterior
from heli_uq.output.inference_data import save_netcdf as save_netcdf
from heli_uq.output.inference_data import to_inference_data as to_inference_data
from heli_uq.output.plots import plot_bands as plot_bands
from heli_uq.output.plots import plot_experiment as plot_experiment
from heli_uq.output.plots import plot_simulation as plot_simulation
from heli_uq.output.posterior_study import parameter_summary as parameter_summary
from heli_uq.output.posterior_study import sample_posterior as sample_posterior
from heli_uq.output.prior_check import prior_predictive_check as prior_predictive_check

__all__ = ["convergence", "predictive_checks", "predictive_metrics", "summarize", "check_health",
           "load_posterior", "save_netcdf",
           "to_inference_data", "plot_bands", "plot_experiment", "plot_simulation",
           "parameter_summary", "sample_posterior", "prior_predictive_check"]  # fmt: skip
