"""The model participant: from the percept of what was played to an answer.

For a choice question the participant compares the percept of the played
stimulus with the percept of each answer option as they were told the display
shows it (:func:`told_pattern`: a named surface is its true heights in contour
lines), or, where the display traces a clean drawing, that drawing through the
same encoding; then through the coding and (simulated) device with the trial's
condition. What was played is felt where the low-speed prior puts it (P5); the
answers where their points are. With white sensory noise
(``vtexp.observer.percept`` P3) the log-likelihood of option k is

    E_k = -|D_k|^2 / 2 - xi_k + sigma_d eta_k,   D_k = s (f_played - f_k)     (M1)

where ``s = sqrt(eta / N0)`` scales the feature distance to d' units (P3),
``xi ~ N(0, D D^T)`` is the projection of one draw of sensory noise on the
differences (exactly the noise of comparing a noisy percept with every
template, without drawing the whole field), and ``eta_k ~ N(0, 1)`` is late
decision noise of size ``sigma_d``. The answer is the option with the largest
E; an "abstain" option ("uncertain") is chosen when the best leads the second
by less than the abstain criterion. A rating question takes the evidence for
its high anchor over its low anchor in SD units,

    v = (E_high - E_low) / |D_high - D_low| + bias                          (M2)

and cuts it by criteria ``rating_step`` apart, centred on 0 (equal-variance
signal detection). A count of turns is the winding of the perceived path
(``winding_turns``) plus Gaussian noise, rounded. On a lapse (probability
``lapse``) the answer is drawn uniformly from the options, scale or range.

Every random number of a trial comes from one row of uniforms keyed by
(seed, experiment, participant, session, trial), so the responder in a
session and the fast simulator give the same answers.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
from scipy.special import ndtri

from ..compile import code, encode, encoding_params, stimulus_image
from ..devices.sim import SimDevice
from ..encoding.height_contours import height_contours_of_heights
from ..errors import InputError
from ..experiment import LoadedExperiment
from ..model import Condition, DeviceProfile, Pattern, PlayReport
from ..stimuli import render
from ..stimuli.surfaces import surface_height
from .params import (
    ObserverParams,
    Participant,
    draw_participant,
    load_params,
    uniform_stream,
)
from .percept import Skin, features, felt_positions, noise_density, winding_turns
from .spec import ObserverSpec, TemplateSpec

#: Uniforms per question and trial: lapse, lapse pick, turn noise, then two per option.
FIXED_COLUMNS = 3


def _normal(u):
    """Standard normal deviates from uniforms in [0, 1) (0 maps to a large negative)."""
    return ndtri(np.maximum(u, 1e-300))


def question_columns(question) -> int:
    n = len(question.options) if question.kind == "choice" else 2
    return FIXED_COLUMNS + 2 * n


@dataclass
class _Geometry:
    """What a decision needs about one played stimulus and one question's templates."""

    gram: np.ndarray            # D D^T in feature units (without s^2)
    root: np.ndarray            # a square root of gram (xi = root @ z)
    half: np.ndarray = field(default_factory=lambda: np.zeros(0))   # diag(gram) / 2
    scale: float = 1.0          # 1 / sqrt(N0): s of (M1) is sqrt(eta) times this
    spread: float = 0.0         # |f_high - f_low| (ratings)
    turns: float = 0.0          # winding of the played percept (counts)


@dataclass
class ObserverModel:
    """An experiment's model participants: templates, percepts and decisions.

    Holds every rendered template and computed geometry in caches, so that many
    participants with the same skin share one computation.
    """

    lx: LoadedExperiment
    profile: DeviceProfile
    params: ObserverParams
    spec: ObserverSpec
    site: str
    _reports: dict = field(default_factory=dict, repr=False)
    _geometry: dict = field(default_factory=dict, repr=False)
    _images: dict = field(default_factory=dict, repr=False)

    @classmethod
    def for_experiment(cls, lx: LoadedExperiment, profile: DeviceProfile | None = None, *,
                       params_file=None, overrides: dict | None = None) -> ObserverModel:
        exp = lx.experiment
        cams = [n for n, s in exp.stimuli.items() if s.is_camera]
        if cams:
            raise lx.error("a model participant cannot feel a camera stimulus (what the camera "
                           "will see is not known in advance); use a person or a scripted "
                           "responder", ("stimuli", cams[0]))
        spec = getattr(exp, "observer", None) or ObserverSpec()
        profile = profile or DeviceProfile.load(exp.device)
        try:
            params = load_params(params_file, {**spec.params, **(overrides or {})})
        except InputError as e:
            if e.path is None and (e.key or "").startswith("observer.params"):
                raise InputError(e.message, path=str(lx.path), key=e.key,
                                 line=lx.source.line_of(("observer", "params"))) from None
            raise
        site = params.site_of(spec.body_site or profile.geometry.body_site)
        model = cls(lx, profile, params, spec, site)
        model._check()
        return model

    # ------------------------------------------------------------------ declaration checks
    def _check(self) -> None:
        exp = self.lx.experiment
        for q in exp.asked():
            if q.kind == "choice":
                for o in q.options:
                    if o not in self.spec.abstain:
                        self._template_spec(o, q.name)
            elif q.kind == "rating":
                if q.name not in self.spec.ratings:
                    raise self._error(f"the model observer needs the anchors of rating question "
                                      f"{q.name!r}: observer.ratings.{q.name}: "
                                      "{low: TEMPLATE, high: TEMPLATE}", ("observer",))
                a = self.spec.ratings[q.name]
                self._template_spec(a.low, q.name)
                self._template_spec(a.high, q.name)
            elif q.kind == "number" and q.name not in self.spec.counts:
                raise self._error(f"the model observer does not know what number question "
                                  f"{q.name!r} counts: observer.counts.{q.name}: turns",
                                  ("observer",))

    def _error(self, msg: str, keypath: tuple) -> InputError:
        try:
            return self.lx.error(msg, keypath)
        except Exception:           # noqa: BLE001 - a key not in the file: no line number
            return InputError(msg, path=str(self.lx.path), key=".".join(keypath))

    def _template_spec(self, name: str, question: str) -> TemplateSpec:
        if name in self.spec.templates:
            return self.spec.templates[name]
        if name in self.lx.experiment.stimuli:
            return TemplateSpec(stimulus=name)
        raise self._error(f"answer {name!r} of question {question!r} is neither a stimulus nor "
                          f"a template: add observer.templates.{name}", ("observer", "templates"))

    # ------------------------------------------------------------------ participants
    def participant(self, seed: int, participant: str, *, typical: bool = False) -> Participant:
        return draw_participant(self.params, self.site, seed, participant, typical=typical)

    def uniforms(self, seed: int, participant: str, session: int, n_trials: int) -> np.ndarray:
        """The uniforms of every trial (rows, by trial number) and question (columns)."""
        cols = sum(question_columns(q) for q in self.lx.experiment.asked())
        rng = uniform_stream("trials", seed, self.lx.experiment.name, participant, session)
        return rng.random((n_trials, cols))

    # ------------------------------------------------------------------ templates
    def template_report(self, name: str, condition: Condition) -> PlayReport:
        """The answer ``name`` as the device would play it in ``condition``."""
        ts = self._template_spec(name, "")
        # An adaptive stimulus level applies to the experiment's stimuli as templates too.
        level = repr(sorted(condition.stimulus_params.items()))
        key = (name, repr(sorted(condition.encoding_params.items())),
               repr(sorted(condition.coding_params.items())), level)
        if key in self._reports:
            return self._reports[key]
        exp = self.lx.experiment
        image = self._images.get((name, level))
        if image is None:
            if ts.stimulus is not None:
                if ts.stimulus not in exp.stimuli:
                    raise self._error(f"template {name!r} names no stimulus of the experiment "
                                      f"({ts.stimulus!r})", ("observer", "templates", name))
                image = stimulus_image(self.lx, ts.stimulus, self.profile,
                                       condition.stimulus_params)
            else:
                image = render(ts.generator, ts.params, self.profile.rows, self.profile.cols)
            self._images[(name, level)] = image
        pattern = None
        if self.params.answer_templates == "told":
            pattern = told_pattern(self.lx, ts, self.profile, condition)
        if pattern is None:
            pattern = encode(self.lx, image, self.profile, condition.encoding_params)
        if not pattern.points:
            raise self._error(f"template {name!r} gives an empty pattern on {self.profile.name}",
                              ("observer", "templates", name))
        schedule = code(self.lx, pattern, self.profile, condition.coding_params)
        with SimDevice(self.profile) as dev:
            report = dev.play(schedule)
        if ts.scramble:
            report = _scrambled(report, name)
        self._reports[key] = report
        return report

    # ------------------------------------------------------------------ geometry
    def skin(self, who: Participant) -> Skin:
        """What shapes participant ``who``'s percept: their own blur, integration time and
        levels; the localisation SD in the same ratio to their blur as the site's
        (P5); the device's pin physics (P6)."""
        p = self.params
        thermal = (None if p.pin_thermal is None
                   else (p.pin_thermal.heating_ms, p.pin_thermal.cooling_ms))
        sigma_s = p.localisation_ratio(self.site) * who.two_point_threshold_mm
        return Skin(who.two_point_threshold_mm, who.integration_ms, who.intensity_levels,
                    localisation_sd_mm=sigma_s,
                    speed_sd_mm_s=p.speed_prior_mm_s, pin_thermal=thermal)

    def geometry(self, question, condition: Condition, played: PlayReport,
                 who: Participant, played_key: tuple | None = None) -> _Geometry:
        """Cached by question, condition, what was played and the participant's skin.

        ``played_key`` names the report when the caller knows it (the simulator
        plays each condition once); else the report's content is the key.
        """
        key = (question.name, condition.index, played_key or _report_key(played), who.key)
        g = self._geometry.get(key)
        if g is not None:
            return g
        skin = self.skin(who)
        if question.kind == "number":
            g = _Geometry(np.zeros((0, 0)), np.zeros((0, 0)),
                          turns=winding_turns(played, self.profile, skin))
        else:
            if question.kind == "choice":
                names = [o for o in question.options if o not in self.spec.abstain]
            else:
                a = self.spec.ratings[question.name]
                names = [a.low, a.high]
            reports = [played] + [self.template_report(n, condition) for n in names]
            # What was played is felt where the low-speed prior puts it (P5); an answer
            # is expected where the told shape's points are, unless the observer file
            # says answers are felt with the same displacements.
            answers_skin = skin if self.params.answers_felt_as_played else \
                dataclasses.replace(skin, speed_sd_mm_s=0.0)
            felt = [felt_positions(played, self.profile, skin)] + \
                [felt_positions(r, self.profile, answers_skin) for r in reports[1:]]
            f = features(reports, self.profile, skin, felt=felt)
            D = f[:1] - f[1:]
            gram = (D @ D.T).astype(np.float64)
            w, V = np.linalg.eigh(gram)
            g = _Geometry(gram, V * np.sqrt(np.clip(w, 0, None)), half=np.diag(gram) / 2,
                          scale=float(1.0 / np.sqrt(noise_density(skin))),
                          spread=float(np.linalg.norm((f[2] - f[1]).astype(np.float64))) if question.kind == "rating"
                          else 0.0)
        self._geometry[key] = g
        return g

    # ------------------------------------------------------------------ decisions
    def answer(self, question, condition: Condition, played: PlayReport, who: Participant,
               u: np.ndarray, played_key: tuple | None = None) -> str:
        """The answer of participant ``who`` given the trial's uniforms ``u`` for this question."""
        return self.answers(question, condition, played, who, u[None, :], played_key)[0]

    def answers(self, question, condition: Condition, played: PlayReport, who: Participant,
                U: np.ndarray, played_key: tuple | None = None) -> list[str]:
        """The answers to several trials of one condition, one row of uniforms each.

        Row by row the arithmetic is the same whatever the number of rows (element-wise
        operations and reductions along rows, no matrix products), so a trial's answer
        does not depend on how many trials are decided together.
        """
        g = self.geometry(question, condition, played, who, played_key)
        lapsed = U[:, 0] < who.lapse
        if question.kind == "number":
            lo, hi = question.minimum, question.maximum
            pick = lo + np.minimum((U[:, 1] * (hi - lo + 1)).astype(int), hi - lo)
            n = np.clip(np.round(g.turns + self.params.turns_sd * _normal(U[:, 2])), lo, hi)
            return [str(int(x)) for x in np.where(lapsed, pick, n)]
        opts = question.options if question.kind == "choice" else [str(v) for v in question.scale]
        pick = np.minimum((U[:, 1] * len(opts)).astype(int), len(opts) - 1)
        s = g.scale * np.sqrt(who.efficiency)
        k = g.gram.shape[0]
        zz = _normal(U[:, FIXED_COLUMNS:FIXED_COLUMNS + 2 * k])
        noise = (zz[:, None, :k] * g.root[None, :, :]).sum(axis=2)    # xi = root @ z per row
        E = -s * s * g.half[None, :] - s * noise + who.decision_noise * zz[:, k:]   # (M1)
        if question.kind == "rating":
            spread = s * g.spread
            v = E[:, 1] - E[:, 0]
            if spread > 1e-12:
                v = v / spread
            v = v + who.rating_bias                                                # (M2)
            n = len(opts)
            cuts = (np.arange(n - 1) - (n - 2) / 2) * self.params.rating_step
            idx = np.searchsorted(cuts, v)
        else:
            names = [o for o in question.options if o not in self.spec.abstain]
            order = np.argsort(-E, axis=1, kind="stable")
            idx = np.array([question.options.index(names[i]) for i in order[:, 0]])
            if self.spec.abstain:
                abstain = question.options.index(
                    next(o for o in question.options if o in self.spec.abstain))
                if k < 2:
                    idx[:] = abstain
                else:
                    rows = np.arange(len(E))
                    lead = E[rows, order[:, 0]] - E[rows, order[:, 1]]
                    idx = np.where(lead < self.params.abstain_criterion, abstain, idx)
        return [opts[i] for i in np.where(lapsed, pick, idx)]


def _report_key(r: PlayReport) -> tuple:
    return tuple((p.row, p.col, round(p.onset_ms, 6), round(p.duration_ms, 6), p.level,
                  None if p.train is None else (p.train.amplitude_v, p.train.frequency_hz,
                                                p.train.pulse_width_ms)) for p in r.pulses)


def _scrambled(report: PlayReport, name: str) -> PlayReport:
    """The same pulses at shuffled positions (a fixed permutation for the template)."""
    cells = sorted({(p.row, p.col) for p in report.pulses})
    rng = uniform_stream("scramble", name, len(cells))
    perm = np.argsort(rng.random(len(cells)), kind="stable")
    to = {c: cells[int(i)] for c, i in zip(cells, perm, strict=True)}
    pulses = [p.model_copy(update={"row": to[(p.row, p.col)][0], "col": to[(p.row, p.col)][1]})
              for p in report.pulses]
    return report.model_copy(update={"pulses": pulses})


def told_pattern(lx: LoadedExperiment, ts: TemplateSpec, profile: DeviceProfile,
                 condition: Condition) -> Pattern | None:
    """What the participant was told answer ``ts`` is, as the display draws it; None
    where the pipeline's rendering of the answer's image already is that.

    The instructions say what the display means (seed 000 §3.4: "the greater
    vibration intensity represents a greater height value"), not how the image processing arrives at
    it, so a participant expects a named shape to feel like its truth drawn by the
    display's code. For ``height-contours`` and a ``surface`` answer that truth is the
    surface's height map (:func:`~vtexp.stimuli.surfaces.surface_height`) through
    steps 3-7 of the pipeline, not shape from shading of its rendered image: a bowl is
    low in the middle however it shades. Outline pipelines (``edge-trace``,
    ``snake-corners``, ``spiral-path``) trace the clean drawing of the named shape, so
    their rendering is already the told shape and None is returned.
    """
    exp = lx.experiment
    if exp.encoding.pipeline != "height-contours":
        return None
    if ts.stimulus is not None:
        spec = exp.stimuli.get(ts.stimulus)
        if spec is None or spec.generator != "surface":
            return None
        params = {**spec.params, **condition.stimulus_params}
    elif ts.generator == "surface":
        params = dict(ts.params)
    else:
        return None
    height, mask = surface_height(**params)
    return height_contours_of_heights(height, mask, profile.rows, profile.cols,
                                      **encoding_params(lx, condition.encoding_params))
