"""Where divergent transitions sit (heli_uq.output.divergences): by chain and by position."""

import arviz as az
import jax
import jax.numpy as jnp
import numpy as np
import numpyro
import numpyro.distributions as dist
import pytest
from numpyro.infer import MCMC, NUTS

from heli_uq.output import check_health, convergence
from heli_uq.output.divergences import Z_NAMED, divergence_sites, divergence_text, normal_scores

#: Under the null z has sd 1; over REPEATS subsets the Monte Carlo error of its estimated sd
#: is about 1/sqrt(2 REPEATS) = 2.2 %, that of the shifts' sd inside z 1/sqrt(2 SHIFTS).
REPEATS = 1000
NULL_SD_TOL = 0.08
NULL_MEAN_TOL = 0.1
#: Runs of divergences on an autocorrelated scalar they do not depend on: the share of
#: records on which it is named must stay below this.
FALSE_NAMING_MAX = 0.05


def test_normal_scores_are_ranks_mapped_to_the_normal():
    rng = np.random.default_rng(0)
    x = rng.normal(size=500)
    s = normal_scores(x)
    np.testing.assert_array_equal(s, normal_scores(np.exp(x)))  # any monotone map of x
    assert np.argsort(s).tolist() == np.argsort(x).tolist()
    assert abs(s.mean()) < 1e-12 and abs(s.std() - 1) < 0.02
    tied = normal_scores(np.array([1.0, 1.0, 2.0, 0.0]))
    assert tied[0] == tied[1] and tied[3] < tied[0] < tied[2]


def _idata(posterior: dict, div: np.ndarray):
    return az.from_dict(posterior=posterior, sample_stats={"diverging": div})


def test_z_is_standard_normal_where_divergences_fall_at_random():
    rng = np.random.default_rng(1)
    chains, draws, n = 4, 500, 14
    posterior = {"a": rng.normal(size=(chains, draws))}
    zs = []
    for _ in range(REPEATS):
        div = np.zeros(chains * draws, bool)
        div[rng.choice(chains * draws, n, replace=False)] = True
        sites = divergence_sites(_idata(posterior, div.reshape(chains, draws)), z_named=0.0)
        zs.append(sites["named"][0]["z"])
    zs = np.array(zs)
    assert abs(zs.mean()) < NULL_MEAN_TOL
    assert abs(zs.std() - 1) < NULL_SD_TOL


def test_a_run_of_divergences_does_not_name_an_autocorrelated_scalar_it_does_not_depend_on():
    """A chain stuck for 30 draws diverges at each; an AR(1) scalar (rho 0.99) wanders on
    its own.  Against 1/sqrt(n) the run's mean score looks extreme on most records; against
    the circular shifts of the run it is named as rarely as a 3-sigma rule allows."""
    rng = np.random.default_rng(3)
    chains, draws, run, records = 2, 1000, 30, 200
    named = naive = 0
    for _ in range(records):
        a = np.zeros((chains, draws))
        for t in range(1, draws):
            a[:, t] = 0.99 * a[:, t - 1] + rng.normal(size=chains)
        div = np.zeros((chains, draws), bool)
        start = rng.integers(0, draws - run)
        div[0, start:start + run] = True
        sites = divergence_sites(_idata({"a": a}, div))
        named += bool(sites["named"])
        scores = normal_scores(a.reshape(-1))[div.reshape(-1)]
        naive += abs(scores.mean() * np.sqrt(run)) >= Z_NAMED
    assert named / records < FALSE_NAMING_MAX
    assert naive / records > 0.5, "the case should defeat the independent-draws standard error"


#: The narrow region: below X_EDGE the scale of y falls to exp(-DEPTH) of its value above.
X_EDGE = -1.0
DEPTH = 4.0


def _narrow_region():
    x = numpyro.sample("x", dist.Normal(0.0, 1.0))
    numpyro.sample("y", dist.Normal(0.0, jnp.exp(-DEPTH * jax.nn.sigmoid(-4.0 * (x - X_EDGE)))))
    numpyro.sample("unrelated", dist.Normal(0.0, 1.0))


def test_divergences_are_placed_where_the_posterior_narrows():
    """Where x < X_EDGE, y's scale is 50 times smaller than the step size adapted to the
    rest: the integrator diverges there, so divergent draws sit at low x, and nowhere in
    particular in the unrelated coordinate."""
    mcmc = MCMC(NUTS(_narrow_region), num_warmup=300, num_samples=1000, num_chains=2,
                chain_method="sequential", progress_bar=False)  # fmt: skip
    mcmc.run(jax.random.PRNGKey(0))
    idata = az.from_numpyro(mcmc)
    sites = divergence_sites(idata)
    assert sites["count"] >= 20, "the narrow region should make the integrator diverge"
    first = sites["named"][0]
    assert (first["variable"], first["side"]) == ("x", "low")
    assert first["z"] <= -Z_NAMED
    assert "unrelated" not in [r["variable"] for r in sites["named"]]
    assert "at low x (" in divergence_text(sites)


def test_divergences_of_one_chain_are_said_and_reach_the_health_sentence():
    rng = np.random.default_rng(2)
    chains, draws = 4, 300
    div = np.zeros((chains, draws), bool)
    div[2, rng.choice(draws, 6, replace=False)] = True
    shape = (chains, draws)
    stats = {"diverging": div, "tree_depth": np.ones(shape), "n_steps": np.ones(shape),
             "energy": rng.normal(size=shape)}  # fmt: skip
    posterior = {"a": rng.normal(size=shape), "b": rng.normal(size=shape)}
    idata = az.from_dict(posterior=posterior, sample_stats=stats)
    summary = convergence(idata)
    assert summary["divergences"] == 6
    assert summary["divergence_sites"]["per_chain"] == [0, 0, 6, 0]
    text = divergence_text(summary["divergence_sites"])
    assert text.startswith("all 6 in chain 2")
    assert "at no scalar in particular" in text
    warnings = check_health(summary)["warnings"]
    assert any(w.startswith("6 divergent transitions") and "all 6 in chain 2" in w for w in warnings)
    div[2] = False
    div[1, 7] = True
    one = divergence_sites(az.from_dict(posterior=posterior, sample_stats={"diverging": div}))
    assert divergence_text(one).startswith("in chain 1")


@pytest.mark.parametrize("diverging", [np.zeros((2, 50), bool), None])
def test_no_divergences_no_sites(diverging):
    stats = {} if diverging is None else {"diverging": diverging}
    idata = az.from_dict(posterior={"a": np.ones((2, 50))}, sample_stats=stats or None)
    assert divergence_sites(idata) is None
    assert divergence_text(None) == ""
