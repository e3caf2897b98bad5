"""What each operation will cost, estimated from its request before any work (service.admission).

One function per operation or family, each returning a :class:`service.admission.Cost` whose
``loc`` s are the request's own fields; the route (or the job kind) passes it to
:func:`service.admission.admit`. The models and their constants are envelopes of measured runs
(docs/service.md, "Bounded before work", says where each comes from); the work itself is also
checked while it runs (its Budget), so an estimate that is low is caught there.
"""

from __future__ import annotations

import math
from typing import Mapping, Sequence

import numpy as np

from raytrace.solver.footprint import estimate as trace_footprint
from raytrace.spec import ChannelSpec
from service.admission import Cost, Loc, Work
from service.settings import Settings

SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
#: Bytes a Monte Carlo ranging run holds per sample of one trial (the clean and the noisy complex
#: waveform, the correlation's FFT of twice the length, the chunk of trials: 16 B x 2 x 4 trials).
RANGING_BYTES_PER_SAMPLE = 128
#: Bytes one cell of a sensor's travel-time field costs (the float64 field, its copy stacked for the
#: fix: estimators.localization.TravelTimeFields).
FIELD_BYTES_PER_CELL = 16
#: Bytes one pixel of a rendered or registered frame costs at its peak (Embree's ray and hit, depth,
#: normal, colour and texture float64 planes, the 8-bit frame and its PNG; the motion estimator's
#: pyramid, filtered and warped frames and histograms).
PIXEL_BYTES = 256
#: Bytes one plotted point costs (matplotlib's artists and paths, the SVG/PDF text).
PLOT_POINT_BYTES = 2048
#: Bytes one particle costs per filter step held (state, weights, resampling indices, float64).
PARTICLE_BYTES = 64


def channel(spec: ChannelSpec, settings: Settings, rename: Mapping[str, Loc] | None = None) -> Cost:
    """A trace's cost (:func:`raytrace.solver.footprint.estimate`, docs/service.md "Memory and work model of a
    channel request"): its shooting's ray segments against ``max_ray_segments`` (field ``rays``) and its peak
    bytes by term (``band.points``, ``max_interactions``, ``rays``, ``receivers``). ``rename`` maps those
    fields onto another request's (a localization's ``sensors``)."""
    rename = rename or {}
    fp = trace_footprint(spec, settings.tracer_config())

    def loc(name: str) -> Loc:
        return rename.get(name, tuple(name.split(".")))

    knobs = (f"rays {spec.rays}, max_interactions {spec.max_interactions}, dynamic_range_db "
             f"{spec.dynamic_range_db:g}, {len(spec.receivers)} receivers"
             + (f", {band.size} band points" if (band := None if spec.band is None else spec.band.frequencies_hz)
                is not None else ""))
    lower = ", ".join(".".join(map(str, loc(n))) for n in ("rays", "max_interactions")) + " or dynamic_range_db"
    return Cost(
        work=(Work(loc("rays"), fp.ray_segments, settings.max_ray_segments, "ray segments", "max_ray_segments",
                   "the shooting", f"lower {lower}"),),
        memory=((loc("band.points"), fp.band_bytes), (loc("max_interactions"), fp.batch_bytes),
                (loc("rays"), fp.candidate_bytes), (loc("receivers"), fp.path_bytes)),
        what="the trace", knobs=knobs)


def toa(samples_per_trial: int, paths: int, trials: int, settings: Settings,
        paths_loc: Loc = ("profile", "paths"), trials_loc: Loc = ("trials",), runs: int = 1) -> Cost:
    """TOA ranging (estimators.toa_samples): synthesising the received waveform costs samples x paths,
    the Monte Carlo samples x trials, each against ``max_ranging_samples``; ``runs`` profiles ranged
    (a localization evaluation ranges every sensor)."""
    cap = settings.max_ranging_samples
    n = samples_per_trial
    return Cost(
        work=(Work(paths_loc, runs * n * paths, cap, "samples", "max_ranging_samples",
                   f"synthesising {paths} paths x {n} samples per trial" + (f" x {runs} sensors" if runs > 1 else ""),
                   "drop weak or late paths, or lower waveform.sample_rate_hz"),
              Work(trials_loc, runs * n * trials, cap, "samples", "max_ranging_samples",
                   f"{trials} trials x {n} samples per trial" + (f" x {runs} sensors" if runs > 1 else ""),
                   f"lower {'.'.join(map(str, trials_loc))} (at most {max(cap // max(runs * n, 1), 1)} here), or "
                   "shorten the observation (the last path's delay, waveform.duration_s) or waveform.sample_rate_hz")),
        memory=((trials_loc, RANGING_BYTES_PER_SAMPLE * n),), what="the ranging")


def tones(paths: int, tones_: int, trials: int, settings: Settings, tones_loc: Loc) -> Cost:
    """PDOA / RSS ranging: the frequency response at every tone (paths x tones), then every trial's
    noisy tones (trials x tones), against ``max_ranging_samples``."""
    cap = settings.max_ranging_samples
    return Cost(work=(Work(("profile", "paths"), paths * tones_, cap, "samples", "max_ranging_samples",
                           f"{paths} paths x {tones_} tones", "drop weak paths"),
                      Work(("trials",), trials * tones_, cap, "samples", "max_ranging_samples",
                           f"{trials} trials x {tones_} tones", f"lower trials or {'.'.join(map(str, tones_loc))}")),
                what="the ranging")


def travel_time_fields(cells: int, sensors: int, sensors_loc: Loc = ("sensors",)) -> Cost:
    """The model-based fix's eikonal fields: one field of the phantom's grid per sensor, held together."""
    return Cost(memory=((sensors_loc, float(FIELD_BYTES_PER_CELL) * cells * sensors),),
                what=f"the travel-time fields ({sensors} sensors x {cells} cells)")


def latest_delay_s(phantom, frequency_hz: float, max_interactions: int) -> float:
    """An envelope of the latest delay a traced path can have: at most ``max_interactions + 1`` straight
    segments, each at most the phantom's bounding-box diagonal, in its slowest medium (largest Re n)."""
    from raytrace.solver.media import MediaTable

    lo, hi = np.asarray(phantom.bounds_m, float)
    diagonal = float(np.linalg.norm(hi - lo))
    n_max = float(MediaTable.build(phantom, np.array([frequency_hz])).n_real.max())
    return (max_interactions + 1) * diagonal * n_max / SPEED_OF_LIGHT_M_PER_S


def toa_samples_envelope(phantom, frequency_hz: float, max_interactions: int, waveform=None) -> int:
    """Samples per trial of a TOA run on any profile the tracer can return for these knobs (an
    envelope of :func:`estimators.waveforms.observation_samples`)."""
    from estimators.toa import make_waveform

    wf = make_waveform(waveform if waveform is not None else {"carrier_hz": frequency_hz})
    t_end = latest_delay_s(phantom, frequency_hz, max_interactions) + 1.5 * wf.duration_s + 4.0 / wf.carrier_hz
    return int(math.ceil(t_end * wf.sample_rate_hz)) + 1


def localization_evaluation(phantom, capsule_m, sensors_m, *, ranging: str, model_based: bool, frequency_hz: float,
                            trials: int, rays: int, max_interactions: int, near_field: bool, band: dict | None,
                            grid_cells: int, settings: Settings) -> Cost:
    """POST /v1/localize/evaluate (evaluation.localization.evaluate_localization): the one trace from the
    capsule to every sensor (:func:`channel`, its ``receivers`` the request's ``sensors`` and a PDOA band
    its ``ranging``), the Monte Carlo ranging of every sensor (TOA: trials x samples per trial x sensors,
    the samples from :func:`toa_samples_envelope`; PDOA and RSS: trials x tones x sensors) and the
    model-based travel-time fields. The synthesis of each sensor's waveform (paths x samples) depends on
    the paths the trace finds: it is checked while it runs."""
    from estimators.errors import EstimatorInputError
    from estimators.toa import METHODS as TOA_METHODS
    from raytrace.spec import Antenna, Band

    sensors = tuple(Antenna(position_m=np.asarray(p, float), name=f"sensor_{i}") for i, p in enumerate(sensors_m))
    spec = ChannelSpec(Antenna(position_m=np.asarray(capsule_m, float), name="capsule"), sensors,
                       frequency_hz=frequency_hz, band=None if band is None else Band(**band), rays=rays,
                       max_interactions=max_interactions, near_field=near_field)
    parts = [channel(spec, settings, {"receivers": ("sensors",), "band.points": ("ranging",)})]
    if ranging in TOA_METHODS:
        try:
            n = toa_samples_envelope(phantom, frequency_hz, max_interactions)
        except EstimatorInputError as exc:  # the default waveform cannot carry this frequency: the request's field
            raise EstimatorInputError(f"TOA ranging's default waveform at this carrier: {exc.reason}; use a lower "
                                      "frequency_hz, or pdoa / rss ranging", "frequency_hz") from None
        cap = settings.max_ranging_samples
        runs = len(sensors)
        parts.append(Cost(work=(Work(("trials",), float(trials) * n * runs, cap, "samples", "max_ranging_samples",
                                     f"{trials} trials x {n} samples per trial (an envelope of the latest delay) x "
                                     f"{runs} sensors", f"lower trials (at most {max(cap // (n * runs), 1)} here), "
                                     "sensors or max_interactions"),),
                          memory=((("trials",), float(RANGING_BYTES_PER_SAMPLE) * n),), what="the ranging"))
    else:
        tones_ = 1 if band is None else int(band["points"])
        parts.append(Cost(work=(Work(("trials",), float(trials) * tones_ * len(sensors), settings.max_ranging_samples,
                                     "samples", "max_ranging_samples", f"{trials} trials x {tones_} tones x "
                                     f"{len(sensors)} sensors", "lower trials or sensors"),)))
    if model_based:
        parts.append(travel_time_fields(grid_cells, len(sensors)))
    out = total(parts)
    return Cost(out.work, out.memory, "the evaluation (trace, ranging, travel-time fields)", parts[0].knobs)


def pixels(side_px: int, frames: int, loc: Loc, what: str) -> Cost:
    """A camera frame (or a pair registered) of ``side_px`` a side."""
    return Cost(memory=((loc, float(PIXEL_BYTES) * side_px * side_px * frames),), what=what)


def plot(width_px: float, height_px: float, points: int) -> Cost:
    """A figure: its canvas (RGBA, the PNG) and its artists, one per point."""
    return Cost(memory=((("dpi",), 16.0 * width_px * height_px), (("points",), float(PLOT_POINT_BYTES) * points)),
                what="the figure")


def particles(particles_: int, observations: int, settings: Settings, cap_steps: int) -> Cost:
    """A particle filter: particles x observations steps, its particle arrays held."""
    return Cost(work=(Work(("config", "particles"), particles_ * observations, cap_steps, "particle steps",
                           "MAX_PARTICLE_STEPS", f"{particles_} particles x {observations} observations",
                           "lower config.particles or send fewer observations"),),
                memory=((("config", "particles"), float(PARTICLE_BYTES) * particles_),), what="the particle filter")


def repeat(cost: Cost, times: int, work_loc: Loc | None = None, what: str = "") -> Cost:
    """``times`` runs of ``cost`` one after the other: the work adds up (named at ``work_loc`` when
    given), the memory does not (one run at a time)."""
    work = tuple(Work(work_loc or w.loc, w.amount * times, w.cap, w.unit, w.setting,
                      f"{w.what} x {times} {what}".strip(), w.advice) for w in cost.work)
    return Cost(work, cost.memory, cost.what, cost.knobs)


def total(costs: Sequence[Cost]) -> Cost:
    out = Cost()
    for c in costs:
        out = out + c
    return Cost(out.work, out.memory, costs[0].what if len(costs) == 1 else "the request", out.knobs)
