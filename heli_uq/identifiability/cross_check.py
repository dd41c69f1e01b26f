"""The identifiability report's cross-check: where the structural, practical and Bayesian
views agree on each structural null direction and each coordinate, and why not where
they disagree (:func:`heli_uq.identifiability.report.identifiability_report`, step 5).

* A structural null direction should have a flat profile for every coordinate taking part
  in it (loading above :data:`LOADING_PART`) and contract by less than
  :data:`CONTRACTION_LOW` along it.
* An identifiable coordinate (a profile crossing the 95 % threshold on both sides) should
  contract by at least :data:`CONTRACTION_HIGH`; a structurally non-identifiable one
  should lie on a null direction; a practically non-identifiable one should not contract
  fully.
* No coordinate or null direction may come out wider in the posterior than in the prior
  by more than Monte Carlo error (contraction below :data:`CONTRACTION_WIDER`): for a
  Gaussian prior in the sampled coordinates conditioning only narrows, so such a
  posterior is unconverged or was computed under other priors.
"""

from __future__ import annotations

__all__ = ["cross_check", "CONTRACTION_LOW", "CONTRACTION_HIGH", "CONTRACTION_WIDER", "LOADING_PART"]

#: Contraction below this counts as "the data did not inform it"; above HIGH as "well informed".
CONTRACTION_LOW = 0.1
CONTRACTION_HIGH = 0.5
#: Contraction below this (posterior variance above 1.25x the prior's) is not a posterior of
#: that prior: the variance of 400 effective draws has a relative error of about 0.07, so
#: this is 3.5 of them.
CONTRACTION_WIDER = -0.25
#: Said where a contraction is below CONTRACTION_WIDER.
WIDER_TEXT = ("; the posterior is wider than the prior, which conditioning on data cannot make: the "
              "posterior is not converged, or was sampled under other priors")

#: A null direction's loading above this counts the coordinate as taking part in it.
LOADING_PART = 0.1


def cross_check(names, structural, profiles, per_contraction, null_contraction) -> list[dict]:
    """Compare the three views; one entry per check with ``agree`` and a reason.

    Parameters
    ----------
    names : list of str
        The coordinates of ``w`` (P,).
    structural : dict
        :func:`~heli_uq.identifiability.structural.structural_analysis`'s result; its
        ``null_directions`` carry ``key`` and ``loadings`` ``{name: float}``.
    profiles : list of Profile
        One classified profile per coordinate (:mod:`heli_uq.identifiability.profiles`).
    per_contraction : array, shape (P,)
        Prior-to-posterior contraction of each coordinate.
    null_contraction : array, shape (k,)
        Contraction along each null direction.

    Returns
    -------
    list of dict
        ``{"check": "null_direction" | "parameter", "subject", "agree", "detail"}``.
    """
    out = []
    prof = {p.name: p for p in profiles}
    for d, c in zip(structural["null_directions"], null_contraction):
        parts = [n for n, v in d["loadings"].items() if abs(v) > LOADING_PART]
        flat = [n for n in parts if prof[n].flat]
        agree = len(flat) == len(parts) and c < CONTRACTION_LOW
        detail = (f"null direction '{d['key']}' ({', '.join(parts)}): profiles flat for "
                  f"{len(flat)}/{len(parts)}, contraction along it {c:.3f}")
        if not agree:
            why = []
            if len(flat) < len(parts):
                why.append("a profile that rises along a structural null direction means the "
                           "direction is null only locally: it runs into a bound (e.g. J_bc > 0 "
                           "ends the r_c-m-J_bc trade at r_c = M11 / (m r_c)) or a degenerate "
                           "value, or the re-optimisation did not follow a curved valley")
            if c >= CONTRACTION_LOW:
                why.append("contraction along an exactly null direction comes from the prior "
                           "(non-isotropic prior sds) or from a posterior that is not converged")
            detail += "; " + "; ".join(why)
        if c < CONTRACTION_WIDER:
            agree, detail = False, detail + WIDER_TEXT
        out.append({"check": "null_direction", "subject": d["key"], "agree": bool(agree),
                    "detail": detail})  # fmt: skip
    for i, n in enumerate(names):
        p = prof[n]
        c = float(per_contraction[i])
        if p.classification == "identifiable":
            width = p.upper - p.lower
            agree = c >= CONTRACTION_HIGH
            detail = f"{n}: identifiable, 95 % profile interval width {width:.3g}; contraction {c:.3f}"
            if not agree:
                detail += ("; a narrow profile with little contraction means the prior is as "
                           "narrow as the likelihood, or the posterior and the fit disagree")
        elif p.classification == "structurally_non_identifiable":
            in_null = any(abs(d["loadings"].get(n, 0.0)) > LOADING_PART
                          for d in structural["null_directions"])  # fmt: skip
            agree = in_null
            detail = f"{n}: flat profile and on a structural null direction; contraction {c:.3f}"
            if c >= CONTRACTION_LOW:
                detail += (" (its marginal contracts because the prior ties it to the identified "
                           "ratios: along the null direction itself the contraction is ~0)")
        else:
            agree = c < 1.0 - 1e-9
            detail = (f"{n}: practically non-identifiable (profile crosses the threshold on "
                      f"{int(p.lower is not None) + int(p.upper is not None)} side(s) within the "
                      f"prior range); contraction {c:.3f}")
            if p.flat:
                detail += ("; the profile is flat although the sensitivities have full rank: a "
                           "direction so weakly identified that only the prior bounds it")
        if c < CONTRACTION_WIDER:
            agree, detail = False, detail + WIDER_TEXT
        out.append({"check": "parameter", "subject": n, "agree": bool(agree), "detail": detail})
    return out
