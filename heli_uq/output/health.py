"""Health checks of a posterior run: is the result trustworthy enough to read?

Every run is checked (:func:`check_health`, from the ``summary.json`` record of
:func:`heli_uq.output.diagnostics.summarize`); a failed check gives one warning sentence
with the measured value and the limit.  Checks, and the flag they raise:

* **UNCONVERGED**: split R-hat above :data:`~heli_uq.output.diagnostics.RHAT_MAX`; bulk or
  tail ESS below :data:`~heli_uq.output.diagnostics.ESS_MIN`; any divergent transition
  (its sentence says where: one chain, or the scalars the divergent draws sit at the tail
  of, :mod:`heli_uq.output.divergences`); more than :data:`TREE_DEPTH_SATURATION_MAX` of
  the draws at the tree-depth limit; a chain whose adapted step size collapsed (below
  :data:`STEP_SIZE_MIN` in the whitened coordinates, where the posterior has unit scale,
  or :data:`STEP_SIZE_RATIO_MIN` of another chain's); E-BFMI below
  :data:`~heli_uq.output.diagnostics.BFMI_MIN`; a MAP whose Newton decrement is above
  :data:`MAP_DECREMENT_MAX`, for a sampler whose draws are centred on the MAP (Laplace, or
  a run that does not name its sampler); emcee's own warnings (chains shorter than 50
  autocorrelation times, low acceptance).
* **Notes** (no flag): the same MAP check for NUTS and emcee, whose MAP only starts the
  chains and whitens them: their draws are judged by the checks above, so a MAP that
  stopped short of the optimum (a network's capped polish) is reported, not failed; a NUTS
  run stopped by its time limit with fewer draws than asked for (the checks above judge
  the draws it made); a window whose 90 % predictive band covers a share of its samples
  outside :data:`COVERAGE90_RANGE` (model error, not a sampler fault: the checks above
  judge whether the posterior was computed right, this one whether the model fits); an
  initial angle whose posterior lies more than :data:`START_PRIOR_SDS` prior sd from its
  prior's centre (the model cannot start where the record does); a MAP whose damping sits
  at the solver's stability limit (:func:`heli_uq.simulation.stiffness.damping_edge`).
* **unphysical**: posterior-predictive draws whose simulation leaves the physical range
  (:mod:`heli_uq.simulation.physical`: |pitch| > 90 deg or non-finite); the fixed-step
  solver off the adaptive reference by more than the tolerance; draws stiffer than the
  solver's substeps keep stable (:func:`heli_uq.simulation.stiffness.stiffness_check`).

The result, ``{"ok", "flags", "warnings", "notes"}``, goes into ``summary.json`` (``health``), into
the title of ``bands.png`` (which then claims no coverage), and into the CLI's warning
block; ``--strict`` turns a failed check into a non-zero exit.
"""

from __future__ import annotations

import math

from heli_uq.inference.start import MAP_DECREMENT_MAX as _START_DECREMENT_MAX
from heli_uq.output.diagnostics import BFMI_MIN, ESS_MIN, RHAT_MAX
from heli_uq.output.divergences import divergence_text
from heli_uq.simulation.stiffness import edge_text

__all__ = ["check_health", "format_warnings", "TREE_DEPTH_SATURATION_MAX", "STEP_SIZE_MIN",
           "STEP_SIZE_RATIO_MIN", "MAP_DECREMENT_MAX", "MAP_STARTS_ONLY", "UNCONVERGED",
           "COVERAGE90_RANGE", "START_PRIOR_SDS", "UNPHYSICAL", "MIN_DRAWS_MEASURED"]  # fmt: skip

#: Largest fraction of draws at the tree-depth limit: more means the trajectories are cut
#: short (a collapsed step size or a ridge), and the chain explores by a random walk.
TREE_DEPTH_SATURATION_MAX = 0.05
#: Smallest healthy step size in the whitened coordinates (posterior sd ~ 1 in every
#: direction; healthy runs adapt 0.1-0.6): below it a trajectory needs more than the
#: 2^8 leapfrog steps of the tree-depth limit to move one posterior sd.
STEP_SIZE_MIN = 1e-3
#: A chain's step size below this fraction of another chain's has collapsed (a stuck chain).
STEP_SIZE_RATIO_MIN = 1e-2
#: Largest Newton decrement of a converged MAP, unless the run states its own
#: (``map_decrement_max``: a hybrid model's, :mod:`heli_uq.inference.start`).
MAP_DECREMENT_MAX = _START_DECREMENT_MAX
#: Samplers whose draws are judged on their own (the MAP only starts them): a MAP
#: that stopped short is a note for these, a failed check for any other.
MAP_STARTS_ONLY = ("nuts", "emcee")
#: The share of a window's samples its 90 % predictive band may cover before a note says
#: so (the calibration range the issues set for held-out windows).  Below it the model
#: misses the data by more than its posterior and noise allow; above it the band is wider
#: than the data need.  Autocorrelated residuals make a window's coverage vary more than
#: a binomial's, hence a range, not a test.
COVERAGE90_RANGE = (0.80, 0.97)
#: An initial angle whose posterior mean lies more than this many prior standard
#: deviations from its prior's centre is noted (:func:`heli_uq.output.diagnostics.start_distances`):
#: the default prior is centred on the record's first sample, whose noise is a few mrad
#: against the prior's 50, so a model that fits its start sits well inside it; the
#: mechanistic model on the rig record puts ``psi0`` 7 sd away, because it cannot hold the
#: still yaw of the first 17 s and the likelihood draws a line through it.
START_PRIOR_SDS = 4.0
#: Fewest draws per chain from which arviz measures R-hat and ESS (it gives NaN below).
MIN_DRAWS_MEASURED = 4
UNCONVERGED = "UNCONVERGED"
UNPHYSICAL = "unphysical"


def _bad(value, limit, above: bool) -> bool:
    """``value`` beyond ``limit`` (None and NaN are not measured: not a failure here;
    :func:`_unmeasured` fails a NaN R-hat or ESS)."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return False
    return value > limit if above else value < limit


def _unmeasured(s: dict) -> list[str]:
    """R-hat or ESS that the draws were too few to measure (arviz gives NaN below
    :data:`MIN_DRAWS_MEASURED` draws per chain): such a run is not shown to converge, so it
    fails; ``None`` (a summary without these keys) is not judged."""
    nan = [label for key, label in (("rhat_max", "R-hat"), ("ess_bulk_min", "bulk ESS"),
                                    ("ess_tail_min", "tail ESS"))
           if isinstance(s.get(key), float) and math.isnan(s[key])]  # fmt: skip
    if not nan:
        return []
    names = nan[0] if len(nan) == 1 else f"{', '.join(nan[:-1])} and {nan[-1]}"
    return [f"{names} cannot be measured from {s.get('chains', '?')} chain(s) of "
            f"{s.get('draws', '?')} draws (at least {MIN_DRAWS_MEASURED} draws per chain are "
            f"needed, {2 * MIN_DRAWS_MEASURED} for one chain): convergence is not shown"]


def _sampler_warnings(s: dict) -> list[str]:
    out = _unmeasured(s)
    if _bad(s.get("rhat_max"), RHAT_MAX, True):
        out.append(f"R-hat {s['rhat_max']:.3g} > {RHAT_MAX} (worst: {s.get('worst_rhat_variable')}): "
                   "the chains disagree")  # fmt: skip
    for key, label in (("ess_bulk_min", "bulk"), ("ess_tail_min", "tail")):
        if _bad(s.get(key), ESS_MIN, False):
            out.append(f"{label} ESS {s[key]:.0f} < {ESS_MIN}"
                       + (f" (worst: {s.get('worst_ess_variable')})" if label == "bulk" else ""))
    if s.get("divergences", 0) > 0:
        where = divergence_text(s.get("divergence_sites"))
        out.append(f"{s['divergences']} divergent transitions (of {s['chains'] * s['draws']} draws)"
                   + (f": {where}" if where else ""))
    if _bad(s.get("tree_depth_saturation"), TREE_DEPTH_SATURATION_MAX, True):
        out.append(f"{100 * s['tree_depth_saturation']:.0f} % of draws at the tree-depth limit "
                   f"(> {100 * TREE_DEPTH_SATURATION_MAX:.0f} %)")  # fmt: skip
    steps = s.get("step_size")
    if isinstance(steps, (int, float)):
        steps = [steps]
    if steps:
        largest = max(steps)
        for chain, step in enumerate(steps):
            if step < STEP_SIZE_MIN:
                out.append(f"chain {chain}'s step size collapsed to {step:.2g} (< {STEP_SIZE_MIN:g} "
                           "in whitened coordinates)")  # fmt: skip
            elif step < STEP_SIZE_RATIO_MIN * largest:
                out.append(f"chain {chain}'s step size collapsed to {step:.2g}, less than "
                           f"{STEP_SIZE_RATIO_MIN:g} of another chain's ({largest:.2g})")  # fmt: skip
    if _bad(s.get("bfmi_min"), BFMI_MIN, False):
        out.append(f"E-BFMI {s['bfmi_min']:.2g} < {BFMI_MIN}")
    if not _map_starts_only(s):
        out.extend(_map_warnings(s))
    out.extend(str(w) for w in (s.get("warnings") or []))  # emcee's own
    return out


def _map_starts_only(s: dict) -> bool:
    return s.get("sampler") in MAP_STARTS_ONLY


def _map_warnings(s: dict) -> list[str]:
    limit = s.get("map_decrement_max") or MAP_DECREMENT_MAX
    if not _bad(s.get("map_decrement"), limit, True):
        return []
    return [f"the MAP did not converge (Newton decrement {s['map_decrement']:.2g} > {limit:g})"]


def _physical_warnings(s: dict, solver_tol: float | None) -> list[str]:
    out = []
    bad = s.get("unphysical_draws") or {}
    if bad.get("count", 0) > 0:
        out.append(f"{bad['count']} of {bad['of']} posterior-predictive simulations leave the "
                   "physical range (|pitch| > 90 deg or a blow-up)")  # fmt: skip
    stiff = s.get("stiffness") or {}
    if stiff.get("beyond", 0) > 0:
        out.append(f"{stiff['beyond']} of {stiff['of']} draws are stiffer than the solver's "
                   f"{s.get('substeps', '?')} substeps keep stable (rate up to "
                   f"{stiff['rate_max']:.4g} 1/s, limit {stiff['rate_limit']:.4g}): their "
                   "simulations are wrong; more substeps are needed")  # fmt: skip
    err = s.get("solver_error_rad")
    if solver_tol is not None and err is not None and not err <= solver_tol:
        out.append(f"the fixed-step solver is {err:.2g} rad from the adaptive reference "
                   f"(tolerance {solver_tol:g}); more substeps are needed")  # fmt: skip
    return out


def _coverage_notes(s: dict, converged: bool) -> list[str]:
    """A note per window and angle whose coverage is outside :data:`COVERAGE90_RANGE`; a
    low one is called model error only when the sampler's checks passed."""
    lo, hi = COVERAGE90_RANGE
    out = []
    for window, checks in (s.get("windows") or {}).items():
        for angle, cov in (checks.get("coverage90") or {}).items():
            if cov is None or not math.isfinite(cov) or lo <= cov <= hi:
                continue
            where = f"the {window} window's {angle}" + (f" ({checks['n_samples']} samples)"
                                                        if "n_samples" in checks else "")
            why = ("the band is wider than the data need" if cov > hi else
                   "the model misses the data there by more than its posterior and noise allow: "
                   "model error, not a sampler fault (`heli-uq discover` looks for the missing effect)"
                   if converged else "not judged: the run failed its convergence checks")  # fmt: skip
            out.append(f"the 90 % band covers {100 * cov:.0f} % of {where}, outside "
                       f"{100 * lo:.0f}-{100 * hi:.0f} %: {why}")  # fmt: skip
    return out


def _start_notes(s: dict) -> list[str]:
    out = []
    for name, d in (s.get("start_distances") or {}).items():
        if not d["prior_sds"] > START_PRIOR_SDS:
            continue
        out.append(f"{name}'s posterior mean {d['posterior_mean']:.3g} rad lies {d['prior_sds']:.1f} "
                   f"prior sd from its prior's centre {d['prior_mean']:.3g} rad (sd {d['prior_sd']:.2g}, "
                   "the record's first sample by default): the model cannot start where the record "
                   "does, and the data outweigh the prior there: model error")  # fmt: skip
    return out


def _edge_notes(s: dict) -> list[str]:
    edge = s.get("solver_edge")
    return [f"at the MAP {edge_text(edge)}: model error, not a sampler fault"] if edge else []


def check_health(summary: dict, *, solver_tol: float | None = None) -> dict:
    """``{"ok": bool, "flags": [...], "warnings": [...], "notes": [...]}`` of a
    ``summary.json`` record (``notes``: reported, not failed; module docstring).

    Parameters
    ----------
    summary : dict
        From :func:`heli_uq.output.diagnostics.summarize` (with ``solver_error_rad`` if
        the solver was checked).
    solver_tol : float, optional
        Largest acceptable ``solver_error_rad`` [rad].
    """
    sampler = _sampler_warnings(summary)
    physical = _physical_warnings(summary, solver_tol)
    flags = ([UNCONVERGED] if sampler else []) + ([UNPHYSICAL] if physical else [])
    notes = []
    if _map_starts_only(summary):
        notes = [f"{w}; it only started {summary['sampler']}, whose draws are judged by the other checks"
                 for w in _map_warnings(summary)]  # fmt: skip
    requested = summary.get("draws_requested")
    if requested is not None and summary.get("draws", requested) < requested:
        notes.append(f"stopped at its time limit after {summary['draws']} of {requested} draws per chain "
                     "(the other checks judge the draws made; a resume continues to the rest)")  # fmt: skip
    extended = summary.get("draws_extended_from")
    if extended is not None:
        notes.append(f"{summary.get('draws')} draws per chain where {extended} were asked for: sampling "
                     "went on while R-hat or ESS failed their checks")  # fmt: skip
    cut_from = summary.get("warmup_requested")
    if cut_from is not None:
        notes.append(f"its warm-up was cut from {cut_from} to {summary.get('warmup')} iterations, step size "
                     "only, to leave time for its draws before the time limit")  # fmt: skip
    notes.extend(_coverage_notes(summary, converged=not sampler))
    notes.extend(_start_notes(summary))
    notes.extend(_edge_notes(summary))
    return {"ok": not flags, "flags": flags, "warnings": sampler + physical, "notes": notes}


def format_warnings(health: dict) -> str:
    """The warning block: a header line and one ``  - ...`` line per failed check."""
    n = len(health["warnings"])
    lines = [f"WARNING: {', '.join(health['flags'])} result ({n} failed health check"
             f"{'s' if n != 1 else ''}); do not read it as a calibrated posterior:"]
    lines += [f"  - {w}" for w in health["warnings"]]
    return "\n".join(lines)
