"""The settings of an SBC study: what a replicate is (:class:`SBCSettings`), and the record of
them in a run directory, which refuses replicates made under other settings.

Layer 8, with :mod:`heli_uq.calibration.sbc`.
"""

from __future__ import annotations

import dataclasses
import json
import pathlib

import numpy as np

from heli_uq.errors import ParameterError
from heli_uq.io import atomic_write_text
from heli_uq.model import HeliModel, build_model

__all__ = ["SBCSettings", "MODEL", "SETTINGS_FILE", "LEGACY_SETTINGS", "stored_settings", "check_settings"]

#: The model of the study: the paper's (12 parameters, no effects).
MODEL = HeliModel()
#: The settings of a run directory (a rerun under other settings is refused).
SETTINGS_FILE = "settings.json"
#: Settings added later, with the values older run directories were made with.
LEGACY_SETTINGS = {"thin_to_ess": False, "effects": []}


@dataclasses.dataclass(frozen=True)
class SBCSettings:
    """What a replicate is: the generator, the prior and the sampler.

    Attributes
    ----------
    duration : float
        Length of each synthetic record [s] (sample time 0.01 s).
    prior_sd : float
        sigma_log of the log-normal priors around Table 1.
    h_sd : float
        Prior sd of h [m]; 0 fixes h = 0.
    chains, warmup, draws : int
        NUTS chains; warm-up and kept iterations per chain.
    adapt_mass_matrix : bool
        Adapt the mass matrix in warm-up (False: keep the Laplace covariance).
    map_maxiter : int
        L-BFGS steps before the Newton polish of the MAP (0: Newton only).
    x0_prior : {"data", "generator"}
        Centre of the initial-angle prior: the first measurement (the package's model) or
        the generator's centre (a consistent SBC).
    ranks : int
        Most draws the truth is ranked among (L; fewer if ``chains * draws`` is smaller).
    thin_to_ess : bool
        Rank among draws thinned to their ESS (:func:`~heli_uq.calibration.ranks.thinned_ranks`).
    effects : tuple of str
        Named effects added to the paper's model (``"yaw:quadratic_drag"``, ...): their
        parameters are drawn from the priors their terms declare and ranked like the others.
        A term set up from its record (a network's input scaling, a Gaussian process's
        voltage pairs: :attr:`~heli_uq.model.terms.base.AbstractTerm.record_keys`) is
        refused: a replicate's truth is drawn before its record exists.
    """

    duration: float = 5.0
    prior_sd: float = 0.1
    h_sd: float = 0.005
    chains: int = 2
    warmup: int = 200
    draws: int = 150
    adapt_mass_matrix: bool = False
    map_maxiter: int = 0
    x0_prior: str = "data"
    ranks: int = 99
    thin_to_ess: bool = True
    effects: tuple = ()

    def __post_init__(self):
        object.__setattr__(self, "effects", tuple(self.effects))
        model = build_model(list(self.effects))  # an unknown effect is refused here, by name
        from_record = [t.label for t in model.effects if t.record_keys]
        if from_record:
            raise ParameterError(f"effects: {', '.join(from_record)} set(s) itself up from the record "
                                 "(its inputs' scaling or voltage pairs), and SBC draws a replicate's "
                                 "truth before its record exists; calibrate named effects only")  # fmt: skip
        for name in ("duration", "prior_sd"):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and np.isfinite(value) and value > 0):
                raise ParameterError(f"{name}: expected a positive number, found {value!r}")
        if not (isinstance(self.h_sd, int | float) and np.isfinite(self.h_sd) and self.h_sd >= 0):
            raise ParameterError(f"h_sd: expected a number >= 0, found {self.h_sd!r}")
        for name, low in (("chains", 1), ("warmup", 0), ("draws", 1), ("map_maxiter", 0),
                          ("ranks", 1)):  # fmt: skip
            value = getattr(self, name)
            if not (isinstance(value, int) and not isinstance(value, bool) and value >= low):
                raise ParameterError(f"{name}: expected an integer >= {low}, found {value!r}")
        if not isinstance(self.thin_to_ess, bool):
            raise ParameterError(f"thin_to_ess: expected True or False, found {self.thin_to_ess!r}")
        if self.x0_prior not in ("data", "generator"):
            raise ParameterError(f"x0_prior: expected 'data' or 'generator', found {self.x0_prior!r}")

    def to_dict(self) -> dict:
        """The settings as a JSON-ready dict."""
        return {**dataclasses.asdict(self), "effects": list(self.effects)}

    @property
    def model(self) -> HeliModel:
        """The paper's model with :attr:`effects`."""
        return build_model(list(self.effects)) if self.effects else MODEL


def stored_settings(out: pathlib.Path) -> tuple[dict, pathlib.Path] | tuple[None, None]:
    """The settings a directory was run with: ``settings.json``, else those recorded in its
    first replicate (directories written before ``settings.json`` existed)."""
    path = out / SETTINGS_FILE
    if path.exists():
        return json.loads(path.read_text()), path
    for rep in sorted(out.glob("rep_*.json")):
        stored = json.loads(rep.read_text()).get("settings")
        if stored is not None:
            return stored, rep
    return None, None


def check_settings(out: pathlib.Path, settings: SBCSettings) -> None:
    """Refuse to add replicates to ``out`` under settings other than its own; record them
    on the first run."""
    stored, where = stored_settings(out)
    now = settings.to_dict()
    stored = None if stored is None else {**LEGACY_SETTINGS, **stored}
    if stored is None:
        atomic_write_text(out / SETTINGS_FILE, json.dumps(now, indent=1))
        return
    differ = [f"{k} (stored {stored[k]!r}, requested {now[k]!r})" for k in now
              if k in stored and stored[k] != now[k]]  # fmt: skip
    if differ:
        raise ParameterError(f"{out}: the replicates there were run with other settings ({where.name}): "
                             f"{'; '.join(differ)}; use another output directory or the same "
                             "settings")  # fmt: skip
    if where.name != SETTINGS_FILE:
        atomic_write_text(out / SETTINGS_FILE, json.dumps({**stored, **now}, indent=1))
