"""Where the base model fails (:mod:`heli_uq.discovery.locate`): the worst axis."""

from types import SimpleNamespace

import numpy as np
import pytest

from heli_uq.discovery.locate import failed_draws, locate, noise_scale
from heli_uq.errors import ParameterError

#: Relative accuracy of the difference-based noise scale on 20,000 white samples
#: (its standard error is about 0.9 %).
NOISE_RTOL = 0.04


def _fitted(resid, sigma, dt=0.01, draws=8):
    """A base fit whose mean simulation misses the data ``y = 0`` by ``-resid`` (n, 2) [rad],
    with fitted error scales ``sigma`` (2,) [rad]; held out: the last 30 %."""
    n = resid.shape[0]
    y = np.zeros((n, 2))
    sim = np.broadcast_to(-resid, (draws, n, 2))
    problem = SimpleNamespace(y=y, u=np.ones((n, 2)), t=dt * np.arange(n), dt=dt, source="rec.csv",
                              n_train=int(0.7 * n),
                              windows=lambda: {"train": (0, int(0.7 * n)), "test": (int(0.7 * n), n)})
    rng = np.random.default_rng(0)
    return SimpleNamespace(start=SimpleNamespace(problem=problem, solver_edge=None), y_sim=sim,
                           y_pred=sim + sigma * rng.standard_normal((draws, n, 2)),
                           sigma=np.broadcast_to(sigma, (draws, 2)))  # fmt: skip


def test_the_worst_axis_is_where_the_misfit_exceeds_the_datas_own_noise():
    """A pitch with a smooth misfit (4 mrad) over 3 mrad of noise, its fitted error scale
    inflated to the residuals' RMS (so held-out RMSE / fitted scale is 1.0), and a yaw at
    its 8 mrad noise whose fitted scale is a little low (ratio 1.05): the pitch is named,
    by its RMSE over the noise its successive differences show (5/3 against 1)."""
    rng = np.random.default_rng(1)
    n = 20_000
    t = 0.01 * np.arange(n)
    pitch = 0.003 * rng.standard_normal(n) + 0.004 * np.sqrt(2) * np.sin(2 * np.pi * t / 7.0)
    yaw = 0.008 * rng.standard_normal(n)
    resid = np.column_stack([pitch, yaw])
    test = slice(int(0.7 * n), n)
    rms = np.sqrt(np.mean(resid[test] ** 2, axis=0))
    where = locate(_fitted(resid, np.array([rms[0], rms[1] / 1.05])))
    assert where["axis"] == "pitch", where["error_ratio"]
    assert where["error_ratio"]["theta"] > 1.5 > 1.1 > where["error_ratio"]["psi"]


def test_the_noise_scale_of_white_noise_is_its_sd_and_a_smooth_misfit_barely_enters():
    rng = np.random.default_rng(2)
    n = 20_000
    white = rng.standard_normal((n, 2)) * np.array([0.003, 0.008])
    drift = 0.05 * np.sin(2 * np.pi * 0.01 * np.arange(n) / 5.0)[:, None]
    np.testing.assert_allclose(noise_scale(white), [0.003, 0.008], rtol=NOISE_RTOL)
    np.testing.assert_allclose(noise_scale(white + drift), [0.003, 0.008], rtol=NOISE_RTOL)


def test_the_residuals_figure_shows_the_misses_apart_from_the_residual_lines(tmp_path, monkeypatch):
    """The samples outside the 90 % band are drawn as dots of their own colour, darker
    than their axis' residual line and named in the legend, one dot per miss: drawn in
    the line's own colour they vanish into it."""
    import matplotlib.colors as mcolors

    import heli_uq.discovery.locate as loc

    figures = []
    monkeypatch.setattr(loc, "save_figure", lambda fig, path: figures.append(fig))
    rng = np.random.default_rng(3)
    n = 4000
    t = 0.01 * np.arange(n)
    resid = np.column_stack([0.003 * rng.standard_normal(n),
                             0.008 * rng.standard_normal(n) + 0.05 * np.sin(2 * np.pi * t / 9.0)])
    where = locate(_fitted(resid, np.array([0.003, 0.008])), out_dir=tmp_path)
    (fig,) = figures
    top = fig.axes[0]
    lines = {ln.get_label(): ln for ln in top.get_lines()}
    for j, name in enumerate(("pitch", "yaw")):
        dots, line = lines[f"{name} outside the 90 % band"], lines[f"{name} residual"]
        assert dots.get_linestyle() == "None" and dots.get_marker() == "."
        assert mcolors.to_rgb(dots.get_color()) == mcolors.to_rgb(loc.OUTSIDE_COLORS[j])
        assert mcolors.to_rgb(dots.get_color()) != mcolors.to_rgb(line.get_color())
        assert sum(mcolors.to_rgb(dots.get_color())) < sum(mcolors.to_rgb(line.get_color()))  # darker
    yaw_misses = len(lines["yaw outside the 90 % band"].get_xdata())
    assert where["axis"] == "yaw" and yaw_misses > 0.1 * n
    (segment,) = where["segments"]  # constant voltages: one input segment, the whole record
    assert yaw_misses == round(segment["outside90_psi"] * n)
    legend = {text.get_text() for text in top.get_legend().get_texts()}
    assert {"pitch outside the 90 % band", "yaw outside the 90 % band"} <= legend


def test_a_base_fit_none_of_whose_draws_simulate_is_refused_not_read_as_missing_nothing():
    """A band of NaN contains nothing and excludes nothing: its misses had read 0 % on every
    window and segment, and the run had gone on to decide.  Some failed draws are counted;
    all failed is refused, naming the windows."""
    fitted = _fitted(0.001 * np.ones((100, 2)), np.array([0.003, 0.008]))
    assert failed_draws(fitted) == 0
    fitted.y_pred[:3] = np.nan
    assert failed_draws(fitted) == 3
    fitted.y_pred[:] = np.nan
    with pytest.raises(ParameterError, match=r"rec.csv: the base model fitted on 0:0.7 s cannot be "
                                             r"simulated to 1 s \(all 8 of its predictive draws fail\)"):
        failed_draws(fitted)
