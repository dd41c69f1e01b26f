"""The readable ``identifiability.md`` built from the report's JSON dict (one way: dict -> text)."""

from __future__ import annotations

__all__ = ["markdown_report"]


def _fmt(x, spec=".3g"):
    return "—" if x is None else format(x, spec)


def _table(header, rows) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return lines + [""]


def markdown_report(r: dict) -> str:
    """Markdown text of an :func:`~heli_uq.identifiability.identifiability_report` result."""
    st, pr, by = r["structural"], r["practical"], r["bayesian"]
    rec = r["record"]
    em = r["error_model"]
    lines = [
        "# Identifiability report",
        "",
        f"Model: **{r.get('model_label', 'mechanistic')}** ({r.get('substeps', 1)} RK4 substeps "
        "per sample).",
        "",
        f"Record: `{rec['source']}`, {rec['n']} samples, t = {rec['t0']:g} to {rec['t1']:g} s "
        f"(dt = {rec['dt']:g} s). Error model: **{em['kind']}**, residual sd (theta, psi) = "
        f"{_fmt(em['sigma'][0])}, {_fmt(em['sigma'][1])} rad"
        + (f", AR(1) rho = {em['rho'][0]:.4f}, {em['rho'][1]:.4f}" if em["rho"] else "")
        + " (estimated from the residuals of the fit and then held fixed).",
        "",
        f"Coordinates `w` ({len(r['parameters'])}): natural log of each free positive parameter, "
        "the others (h, offsets, rest angles) in their SI unit, initial angles in rad and rates "
        f"in rad/s. Fit: paper loss V = {r['fit']['loss_v']:.4g} rad^2, "
        f"-log L = {r['fit']['neg_log_lik']:.6g}.",
        "",
        "## 1. Structural (local): rank of the output sensitivities",
        "",
        f"Numerical rank **{st['rank']} of {st['n_parameters']}** (ranks at the fit and the random "
        f"points: {st['ranks_at_points']}). Rank tolerance: singular values below "
        f"{st['rank_rtol']:g} x the largest. The invariances are algebraic, so their singular "
        "values are floating-point round-off; here the largest value counted as zero is "
        f"{st['gap']['largest_zero']:.2g} and the smallest counted as non-zero is "
        f"{st['gap']['smallest_nonzero']:.2g} (relative), so the tolerance sits in the gap.",
        "",
        "![singular values](singular_values.png)",
        "",
        "### Null directions (named)",
        "",
    ]
    if not st["null_directions"]:
        lines += ["None: every coordinate is locally structurally identifiable.", ""]
    for d in st["null_directions"]:
        loads = ", ".join(f"{n} {v:+.3f}" for n, v in d["loadings"].items() if abs(v) > 1e-3)
        lines += [f"- **{d['key']}**: {d['description']}. Unit loadings: {loads}.", ""]
    wk = st["weakest_direction"]
    lines += [
        f"Weakest identified direction (relative singular value {wk['relative_singular_value']:.2g}): "
        f"{wk['description']}.",
        "",
        "### Identifiable combinations",
        "",
    ]
    rows = [(c["name"], f"{c['value']:.4g}", f"{c['null_leak']:.1e}",
             "yes" if c["null_leak"] < 1e-6 else "**no** (varies along the null space)")
            for c in st["identifiable_combinations"]]  # fmt: skip
    lines += _table(["combination", "value at fit", "null-space leak", "invariant"], rows)

    ev = pr["fim_eigenvalues"]
    lines += [
        "## 2. Practical: Fisher information and profile likelihoods",
        "",
        f"Fisher information (Gauss-Newton, whitened residuals): eigenvalues from {ev[0]:.3g} to "
        f"{ev[-1]:.3g}, condition number {_fmt(pr['condition_number'], '.3g')}, rank "
        f"{pr['fim_rank']}.",
        "",
        "![FIM correlation](fim_correlation.png)",
        "",
        f"Profiles: every other coordinate re-optimised at each point; threshold "
        f"{pr['threshold']:.3f} (chi2_1(0.95) / 2); explored range = prior mean +- 2 prior sd.",
        "",
        "![profiles](profiles.png)",
        "",
    ]
    rows = []
    for n in r["parameters"]:
        p = pr["profiles"][n]
        ci = "—" if p["ci95"] is None else f"[{p['ci95'][0]:.4g}, {p['ci95'][1]:.4g}]"
        rows.append((n, p["classification"].replace("_", " "), ci, _fmt(pr["cramer_rao_se"][n]),
                     _fmt(p["max_delta"]), f"{by['contraction'][n]:.3f}"))  # fmt: skip
    lines += _table(["coordinate", "profile class", "95 % profile interval", "Cramér-Rao se",
                     "max increase", "contraction"], rows)  # fmt: skip
    lines += [
        "## 3. Bayesian: prior-to-posterior contraction",
        "",
        f"Source: {by['source']}. Contraction 1 - var_post / var_prior per coordinate (table "
        "above) and along each null direction: "
        + ", ".join(f"{k} {v:.3f}" for k, v in by["contraction_along_null_directions"].items())
        + ".",
        "",
        "![contraction](contraction.png)",
        "",
        "![pairs](posterior_pairs.png)",
        "",
        "## 4. Cross-check",
        "",
    ]
    bad = [c for c in r["cross_check"] if not c["agree"]]
    lines += [f"{len(r['cross_check']) - len(bad)} of {len(r['cross_check'])} checks agree.", ""]
    if bad:
        lines += ["Disagreements:", ""] + [f"- {c['detail']}" for c in bad] + [""]
    lines += ["All checks:", ""] + [f"- {'ok' if c['agree'] else '**disagree**'}: {c['detail']}"
                                   for c in r["cross_check"]] + [""]  # fmt: skip
    t = r["timings"]
    lines += [f"Run time: {t['total_s']:.0f} s (fit {t['fit_s']:.0f} s, structural "
              f"{t['structural_s']:.0f} s, practical {t['practical_s']:.0f} s).", ""]
    return "\n".join(lines)
