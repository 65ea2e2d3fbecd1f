"""The model participant's parameters, the population they vary in, and the YAML that holds them.

Defaults live in ``protocols/observers/default.yaml`` with the source of each
value. :class:`ObserverParams` is one participant; :class:`Population` draws a
participant's own parameters deterministically from a seed.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import Field, ValidationError
from scipy.special import ndtr, ndtri

from ..errors import InputError
from ..model import Model
from ..resources import protocols_dir
from ..yamlio import load_yaml

Positive = Annotated[float, Field(gt=0)]


class PopulationSpread(Model):
    two_point_threshold_cv: Annotated[float, Field(ge=0, le=2)] = 0.25
    integration_cv: Annotated[float, Field(ge=0, le=2)] = 0.30
    intensity_levels_sd: Annotated[float, Field(ge=0, le=10)] = 0.5
    efficiency_cv: Annotated[float, Field(ge=0, le=3)] = 0.5
    decision_noise_cv: Annotated[float, Field(ge=0, le=3)] = 0.3
    lapse_logit_sd: Annotated[float, Field(ge=0, le=5)] = 0.5
    rating_bias_sd: Annotated[float, Field(ge=0, le=5)] = 0.3


class PinThermal(Model):
    """First-order heating and cooling of an SMA pin's wire (``percept.pin_strokes``)."""

    heating_ms: Positive
    cooling_ms: Positive


class FittedValue(Model):
    """A fitted parameter's population centre and its 95 % interval."""

    centre: float
    low: float
    high: float


class Fitted(Model):
    """What ``vtexp observer fit`` fitted (the ``fitted:`` section of its observer file):
    each fitted parameter's centre and 95 % interval, and the parameters the data did
    not identify. ``vtexp simulate`` reports power over these intervals."""

    by: str = ""
    interval: str = ""
    participants: int | None = None
    site: str | None = None
    params: dict[str, FittedValue] = Field(default_factory=dict)
    not_identified: list[str] = Field(default_factory=list)


#: The parameters a ``fitted:`` section can hold, and the values each can take
#: (low, high, whether the low end itself is allowed).
FITTED_RANGES: dict[str, tuple[float, float, bool]] = {
    "efficiency": (0.0, 1.0, False), "decision_noise": (0.0, float("inf"), True),
    "lapse": (0.0, 1.0, True), "abstain_criterion": (0.0, float("inf"), True),
    "rating_bias": (float("-inf"), float("inf"), True),
    "rating_step": (0.0, float("inf"), False), "turns_sd": (0.0, float("inf"), True),
    "integration_ms": (0.0, float("inf"), False),
    "two_point_threshold_mm": (0.0, float("inf"), False)}


class ObserverParams(Model):
    """One model participant (or the population's typical one)."""

    two_point_threshold_mm: dict[str, Positive] = Field(
        default_factory=lambda: {"fingertip": 2.5, "palm": 10.0, "forearm": 38.0,
                                 "lower_back": 39.0})
    site_aliases: dict[str, list[str]] = Field(default_factory=dict)
    intensity_levels: Annotated[float, Field(ge=2, le=100)] = 7.5
    integration_ms: Positive | dict[str, Positive] = 40.0
    localisation_sd_mm: dict[str, Annotated[float, Field(ge=0)]] = Field(default_factory=dict)
    speed_prior_mm_s: Annotated[float, Field(ge=0)] = 0.0
    answers_felt_as_played: bool = False
    pin_thermal: PinThermal | None = None
    efficiency: Annotated[float, Field(gt=0, le=1)] = 0.1
    decision_noise: Annotated[float, Field(ge=0)] = 1.0
    abstain_criterion: Annotated[float, Field(ge=0)] = 1.0
    rating_step: Positive = 1.0
    turns_sd: Annotated[float, Field(ge=0)] = 0.5
    lapse: Annotated[float, Field(ge=0, le=1)] = 0.02
    answer_templates: Literal["told", "rendered"] = "told"
    population: PopulationSpread = Field(default_factory=PopulationSpread)
    fitted: Fitted | None = None

    def integration_of(self, site: str) -> float:
        """The integration time constant at ``site`` (one value for every site, or the
        site's own)."""
        if isinstance(self.integration_ms, dict):
            if site not in self.integration_ms:
                raise InputError(f"integration_ms gives no value for the body site {site!r} "
                                 f"(it has {', '.join(self.integration_ms)})",
                                 key="integration_ms")
            return self.integration_ms[site]
        return self.integration_ms

    def localisation_ratio(self, site: str) -> float:
        """The site's localisation SD over its two-point threshold (0: none given), so a
        participant's SD follows their own threshold."""
        return self.localisation_sd_mm.get(site, 0.0) / self.two_point_threshold_mm[site]

    def site_of(self, body_site: str) -> str:
        """The two-point-threshold site a device profile's ``body_site`` text names."""
        text = body_site.lower()
        best: tuple[int, str] | None = None
        for site in self.two_point_threshold_mm:
            for alias in [site.replace("_", " "), *self.site_aliases.get(site, [])]:
                at = text.find(alias.lower())
                if at >= 0 and (best is None or at < best[0]):
                    best = (at, site)
        if best is None:
            raise InputError(f"the body site {body_site!r} names none of the sites with a "
                             f"two-point threshold ({', '.join(self.two_point_threshold_mm)}); "
                             "set observer.body_site in the experiment", key="body_site")
        return best[1]


def load_params(path: Path | str | None = None, overrides: dict[str, Any] | None = None
                ) -> ObserverParams:
    """Read an observer file (default: the shipped one) and apply ``overrides``."""
    p = Path(path) if path is not None else protocols_dir() / "observers" / "default.yaml"
    if not p.is_file():
        raise InputError("no such observer file", path=str(p))
    doc = load_yaml(p)
    data = dict(doc.data or {})
    for k, v in (overrides or {}).items():       # mappings (sites, population) merge
        data[k] = {**data[k], **v} if isinstance(v, dict) and isinstance(data.get(k), dict) \
            else v
    try:
        params = ObserverParams.model_validate(data)
    except ValidationError as e:
        err = e.errors()[0]
        key = ".".join(str(x) for x in err["loc"])
        if err["loc"] and err["loc"][0] in (overrides or {}):
            raise InputError(f"{err['msg']} (an override of {p.name})",
                             key=f"observer.params.{key}") from None
        raise InputError(f"{err['msg']}", path=str(p), key=key) from None
    if params.fitted is not None:
        check_fitted(params.fitted, p)
    return params


def check_fitted(fitted: Fitted, path: Path) -> None:
    """The ``fitted:`` section's values make sense: each a parameter a fit estimates,
    ``low <= centre <= high``, each a value the parameter can take."""
    for name, v in fitted.params.items():
        key = f"fitted.params.{name}"
        if name not in FITTED_RANGES:
            raise InputError(f"no parameter {name!r} is fitted; the parameters are "
                             + ", ".join(FITTED_RANGES), path=str(path), key=key)
        lo, hi, closed = FITTED_RANGES[name]
        for end in ("low", "centre", "high"):
            x = getattr(v, end)
            if not (x == x) or x > hi or x < lo or (x == lo and not closed):
                side = "[" if closed else "("
                raise InputError(f"{x} is not a value of {name} (it takes {side}{lo:g}, "
                                 f"{hi:g}])", path=str(path), key=f"{key}.{end}")
        if not v.low <= v.centre <= v.high:
            raise InputError(f"the interval [{v.low:g}, {v.high:g}] does not hold the "
                             f"centre {v.centre:g} (low <= centre <= high)",
                             path=str(path), key=key)
    for name in fitted.not_identified:
        if name not in FITTED_RANGES:
            raise InputError(f"no parameter {name!r} is fitted; the parameters are "
                             + ", ".join(FITTED_RANGES), path=str(path),
                             key="fitted.not_identified")


# --------------------------------------------------------------------------- the population

#: Blur and integration time are drawn in 5 equal-probability bins of their
#: distributions, each participant taking their bin's median (these z-scores):
#: participants in the same bins share one computed percept.
BINS = 5
Z_BINS = np.array([float(ndtri((i + 0.5) / BINS)) for i in range(BINS)])



def _seed_words(*parts: object) -> list[int]:
    """Four 32-bit words of SHA-256 over ``parts``: a portable seed for numpy's SeedSequence."""
    h = hashlib.sha256("\x00".join(map(str, ("vtexp-observer", *parts))).encode()).digest()
    return [int.from_bytes(h[i:i + 4], "big") for i in range(0, 16, 4)]


def uniform_stream(*parts: object) -> np.random.Generator:
    """A generator keyed by ``parts``. Only its uniform draws are used (``random``), whose
    stream numpy keeps stable; normals are made from them by the inverse CDF."""
    return np.random.Generator(np.random.PCG64(np.random.SeedSequence(_seed_words(*parts))))


def normals(rng: np.random.Generator, shape) -> np.ndarray:
    u = rng.random(shape)
    return ndtri(np.clip(u, 1e-300, 1.0 - 2.0 ** -53))


@dataclass(frozen=True)
class Participant:
    """One simulated participant: their own parameters, drawn from the population."""

    id: str
    two_point_threshold_mm: float
    intensity_levels: int
    integration_ms: float
    efficiency: float
    decision_noise: float
    lapse: float
    rating_bias: float
    key: tuple                       # what their percept depends on (shared in a cache)


def draw_participant(params: ObserverParams, site: str, seed: int, participant: str, *,
                     typical: bool = False) -> Participant:
    """The parameters of ``participant`` under ``seed``: the same on every machine.

    Blur, integration time, efficiency and decision noise are log-normal with their
    medians at the defaults; blur and integration time take the median of
    their bin among ``BINS`` equal-probability bins (so percepts can be shared);
    the intensity levels are normal, rounded to a whole number; the lapse rate
    logit-normal; the rating bias normal around 0;
    ``typical=True`` gives the population's central participant.
    """
    pop = params.population
    z = np.zeros(7) if typical else normals(uniform_stream("population", seed, participant), 7)
    zt, zi = (float(Z_BINS[min(int(ndtr(v) * BINS), BINS - 1)]) for v in z[:2])

    def lognormal(mean: float, cv: float, zz: float) -> float:
        s = np.sqrt(np.log1p(cv * cv))
        return float(mean * np.exp(s * zz))

    tpt = lognormal(params.two_point_threshold_mm[site], pop.two_point_threshold_cv, zt)
    tau = lognormal(params.integration_of(site), pop.integration_cv, zi)
    levels = max(2, round(params.intensity_levels + pop.intensity_levels_sd * float(z[2])))
    eff = min(1.0, lognormal(params.efficiency, pop.efficiency_cv, z[3]))
    dn = lognormal(params.decision_noise, pop.decision_noise_cv, z[4]) \
        if params.decision_noise > 0 else 0.0
    if 0.0 < params.lapse < 1.0:
        logit = np.log(params.lapse / (1 - params.lapse)) + pop.lapse_logit_sd * z[5]
        lapse = float(1 / (1 + np.exp(-logit)))
    else:
        lapse = params.lapse
    bias = float(pop.rating_bias_sd * z[6])
    return Participant(participant, tpt, levels, tau, eff, dn, lapse, bias,
                       key=(round(tpt, 9), levels, round(tau, 9)))
