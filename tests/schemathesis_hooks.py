"""Schemathesis hooks for ``schemathesis run --checks all`` against this API.

    SCHEMATHESIS_HOOKS=tests.schemathesis_hooks schemathesis run URL/openapi.json --checks all

The OpenAPI document states every rule JSON Schema can state: types (strict), bounds,
lengths, which fields go together (``oneOf``), distinct tones. A few rules relate two
values, or a value and a file's content, and no JSON Schema keyword can say them; a
schema-valid request that breaks one gets a documented 422 (docs/service.md, "Errors"),
which schemathesis' ``positive_data_acceptance`` reports as "schema-valid request
rejected". This hook forgives exactly those: the failure is ST202, the answer a 422 whose
every error item is one of the rules below (operation, where, error type). Any other
refusal of schema-valid data, and every other check, stays a failure.
"""

from __future__ import annotations

import json
import os

import schemathesis

#: (operation id, loc prefix, error type (None: any), the rule the schema cannot state)
CROSS_FIELD_RULES = [
    ("ranging_toa", ["body", "waveform"], "estimator_input",
     "sampling above twice the carrier (and the pulse's band), a burst of at least one carrier period and "
     "four samples, peak methods at >= 4 samples per period, the observation within 2^18 samples"),
    ("ranging_toa", ["body", "profile", "paths", "gain"], "estimator_input",
     "paths whose gains cancel exactly leave no signal"),
    ("ranging_pdoa", ["body", "frequencies_hz"], "estimator_input", "regression tones equally spaced"),
    ("ranging_pdoa", ["body", "profile", "paths", "gain"], "estimator_input",
     "paths whose gains cancel at every tone leave no signal"),
    ("bound_pdoa", ["body", "tone_spacing_hz"], "estimator_input", "tone spacing below twice the centre frequency"),
    *((op, ["body", "profile", "reference_frequency_hz"], "estimator_input", "a profile whose paths carry group "
       "delays names the frequency they were taken at") for op in ("ranging_toa", "ranging_pdoa", "ranging_rss")),
    *(("compute_channel", ["body", part], kind, "an antenna inside the phantom's bounds and off its surfaces, "
       "a non-zero polarization") for part in ("transmitter", "receivers")
      for kind in ("invalid_geometry", "ambiguous_position")),
    *(("compute_channel", ["body", part], "frequency_out_of_range", "a frequency whose wavelength in the "
       "transmitter's tissue fits in the phantom (geometric optics' floor)") for part in ("frequency_hz", "band")),
    ("compute_channel", ["body", "receivers"], "input", "receiver names distinct (uniqueItems cannot say it of "
     "one property of the items)"),
    ("compute_channel", ["body", "outputs"], "invalid", "an impulse response's samples and taps (l_max - l_min + 1) "
     "within the output cap, and a band that holds the taps' bandwidth"),
    *((op, ["body", "link"], "estimator_input", "the SNR a link budget and the profile's path gain give within "
       "[-300, 200] dB") for op in ("ranging_toa", "ranging_pdoa")),
    ("bound_toa", ["body", "snr_db"], "estimator_input", "the SNR a link budget and a path gain give within "
     "[-300, 200] dB"),
    ("bound_pdoa", ["body", "snr_db"], "estimator_input", "the SNR a link budget and a path gain give within "
     "[-300, 200] dB"),
    ("ranging_pdoa", ["body", "band"], "value_error", "a band's stop above its start"),
    ("compute_channel", ["body", "band"], "value_error", "a band's stop above its start"),
    ("compute_channel", ["body", "band"], "invalid", "channel outputs (cfr, cir, taps) need a band"),
    *(("compute_channel", ["body", *part], "invalid", "a request whose estimated work and memory fit the server's "
       "budget (docs/service.md, memory and work model)")
      for part in (["rays"], ["max_interactions"], ["receivers"], ["band", "points"])),
    # a full-wave job is a channel request (the same rules) whose FDTD models fit the server
    *(("submit_fullwave", ["body", part], kind, "an antenna inside the phantom's bounds and off its surfaces, "
       "a non-zero polarization") for part in ("transmitter", "receivers")
      for kind in ("invalid_geometry", "ambiguous_position")),
    *(("submit_fullwave", ["body", part], "frequency_out_of_range", "a frequency whose wavelength in the "
       "transmitter's tissue fits in the phantom (geometric optics' floor)") for part in ("frequency_hz", "band")),
    ("submit_fullwave", ["body", "receivers"], "input", "receiver names distinct"),
    ("submit_fullwave", ["body", "band"], "value_error", "a band's stop above its start"),
    *(("submit_fullwave", ["body", *part], "invalid", "a request whose estimated work and memory fit the server's "
       "budget (docs/service.md, memory and work model)")
      for part in (["rays"], ["max_interactions"], ["receivers"], ["band", "points"])),
    *(("submit_fullwave", ["body", part], "invalid", "FDTD models whose cells x time steps fit the server's "
       "bound, with the antennas inside the grid and outside its absorbing layer, a second cell size in bounds "
       "(docs/validation.md, 'Over HTTP')") for part in ("cell_m", "coarse_factor", "margin_m")),
    ("upload_phantom", ["body", "mesh"], "phantom_validation", "the mesh part is a valid binary glTF"),
    ("upload_phantom", ["body", "archive"], "invalid", "the archive part is a zip of anatomy files and a build "
     "manifest that names them (docs/phantoms.md, 'Over HTTP')"),
    *(("submit_sweep", ["body", part], "sweep_spec", "sites, positions and centrelines of the phantom; bands, "
       "methods and localizers consistent with each other (sweeps.spec)")
      for part in ("capsule_positions", "receivers", "frequencies_hz", "channel", "ranging", "localization")),
    *(("submit_sweep", ["body", part], "invalid", "each trace's estimated work and memory fit the server's budget "
       "(docs/service.md, 'Bounded before work')") for part in ("channel", "receivers")),
    ("track", ["body", "config", "particles"], "invalid", "particles x observations within the tracker's work "
     "bound, its particles within the memory share (docs/service.md, 'Bounded before work')"),
    ("track_evaluate", ["body", "rays"], "invalid", "the journey's RF traces (one per grid position it visits) "
     "within the work budget (docs/service.md, 'Bounded before work')"),
    *((op, ["body", part], kind, "sensors (and a capsule) inside the phantom's body, off its surfaces, apart from "
       "each other and not coplanar, of known sites; one measurement kind for every sensor and the method's, "
       "sigmas for all or none; methods that suit the ranging; a frequency whose wavelength fits the phantom")
      for op in ("localize", "localize_evaluate") for part in ("sensors", "capsule", "methods", "frequency_hz")
      for kind in ("estimator_input", "invalid", "invalid_geometry", "ambiguous_position", "frequency_out_of_range")),
    ("upload_phantom", ["body", "manifest"], "phantom_validation",
     "the manifest part is JSON that names the mesh's nodes, sites inside the phantom's bounds..."),
    ("vision_render", ["body", "pose"], "vision_input", "a pose inside one of the phantom's GI lumens: s_m within "
     "its centreline, a position inside an organ (of the centreline, if any), a non-zero direction"),
    ("vision_render", ["body", "texture", "fold_axis"], "vision_input", "a non-zero fold axis"),
    *(("vision_motion", ["body", part], "vision_input", "the frames are PNG files of the same size, 16-1024 px a "
       "side, not constant; options consistent (low < high); the geometry's pose in a lumen, its camera the "
       "frames' size") for part in ("reference", "moving", "options", "geometry")),
    ("plot_cfr", ["body", "profile", "paths"], "invalid", "a profile without band_gains needs the band to draw "
     "its frequency-flat gains over"),
    ("plot_crlb", ["body", "carrier"], "value_error", "a carrier grid's stop above its start"),
    ("plot_cfr", ["body", "band"], "value_error", "a band's stop above its start"),
    ("plot_crlb", ["body", "pdoa"], "invalid", "a tone spacing below twice the lowest carrier (both tones positive)"),
    ("plot_cfr", ["body", "profile", "reference_frequency_hz"], "invalid", "gains that include the delay phase "
     "name the frequency they were evaluated at"),
    ("plot_crlb", ["body", "rss"], "invalid", "an RSS bound that is not zero in float64 (shadowing_db x distance_m "
     "/ path_loss_exponent above the smallest double)"),
    ("plot_localization_cdf", ["body", "methods"], "invalid", "a method with at least one trial that has a fix; "
     "method names distinct"),
    ("plot_ranging_errors", ["body", "methods"], "invalid", "method names distinct (uniqueItems cannot say it of "
     "one property of the items)"),
    ("plot_path_loss", ["body", "path_loss_db"], "invalid", "one path loss per distance"),
    ("plot_tracking", ["body", "s_m"], "invalid", "the true arc lengths as long as t_s"),
    *((op, ["body", "observations"], "tracking_input", "roll_deg and roll_sigma_deg given together; times "
       "strictly increasing; a fix's covariance symmetric positive definite") for op in ("track",)),
    ("plot_path_loss", ["body", "distances_m"], "invalid", "distances and reference_distance_m within a factor "
     "1e300 of each other (their ratio's logarithm finite)"),
    ("plot_tracking", ["body", "trackers"], "invalid", "each tracker's series as long as t_s"),
    ("plot_tract_errors", ["body", "rows"], "invalid", "at least one row with both s_m and error_m"),
    *((op, ["body", "centreline"], "tracking_input", "a centreline of the phantom")
      for op in ("track", "track_evaluate")),
    ("track_evaluate", ["body", "journey", "start_m"], "tracking_input", "a start within the phantom's centreline"),
    ("submit_coverage", ["body", "positions"], "design_input", "exactly one of along_tract, sites and positions_m, "
     "given and not null (oneOf's required cannot exclude a null value); positions inside the phantom's lumens"),
    *(("submit_coverage", ["body", part], "design_input", "a burst of at least one carrier period sampled above "
       "twice the carrier; a non-zero polarization; candidates on the phantom's skin in the region; positions x "
       "candidates links and each trace's work and memory within the server's budget (docs/design.md)")
      for part in ("waveform", "channel", "candidates", "link", "positions")),
    ("submit_layout", ["body", "constraints"], "design_input", "keep-out boxes with each max_m coordinate above "
     "min_m's, a non-zero axis, belt counts for all belts or none summing to sensors"),
    # the JSON parts are strings to the schema: their content's errors have the body models' types
    *(("vision_motion", ["body", part], None, "the part is JSON text of its model (MotionOptions, "
       "RenderRequest)") for part in ("options", "geometry")),
]


#: Rules about the body as a whole, forgiven only at exactly that loc.
WHOLE_BODY_RULES = [
    *((op, "value_error", "the image at most 3000 px a side: width_in and height_in times dpi")
      for op in ("plot_pdp", "plot_cfr", "plot_crlb", "plot_ranging_errors", "plot_localization_cdf",
                 "plot_tract_errors", "plot_path_loss", "plot_tracking")),
]


def _forgiven(operation_id: str, item: dict) -> bool:
    loc, kind = item.get("loc", []), item.get("type")
    if loc == ["body"] and any(op == operation_id and typ == kind for op, typ, _ in WHOLE_BODY_RULES):
        return True
    return any(op == operation_id and loc[: len(prefix)] == prefix and typ in (kind, None)
               for op, prefix, typ, _ in CROSS_FIELD_RULES)


#: The 5xx answers a bounded server gives by design (docs/service.md, "Concurrency and limits"): 503 when
#: every compute slot or the sweep queue is taken (with Retry-After), 504 when a computation reaches the
#: deadline, 501 when a full-wave job needs gprMax and the server has none. Any other 5xx (a 500 above all)
#: stays a failure.
UNAVAILABLE = {503: "saturated", 504: "deadline_exceeded", 501: "not_installed"}


def _documented_unavailable(case, response) -> bool:
    kind = UNAVAILABLE.get(response.status_code)
    if kind is None or str(response.status_code) not in case.operation.definition.raw.get("responses", {}):
        return False
    try:
        detail = response.json()["detail"]
    except (ValueError, KeyError, TypeError):
        return False
    return bool(detail) and all(item.get("type") == kind for item in detail)


@schemathesis.hook
def filter_failure(context, failure, case, response) -> bool:
    """Keep every failure except: a 422 to schema-valid data for a rule the schema cannot state; a
    documented 503 (saturated) or 504 (deadline) the operation declares; a 413 (a body over the
    operation's byte cap, refused while it streams in) to schema-invalid data, which is a refusal
    although ``negative_data_rejection`` does not count it as one."""
    code = getattr(failure, "code", None)
    if code == "ST201" and response.status_code == 413:
        return False
    if code == "ST101" and _documented_unavailable(case, response):
        return False
    if code != "ST202" or response.status_code != 422:
        return True
    try:
        detail = response.json()["detail"]
    except (ValueError, KeyError, TypeError):
        return True
    operation_id = case.operation.definition.raw.get("operationId", "")
    forgiven = bool(detail) and all(_forgiven(operation_id, item) for item in detail)
    log = os.environ.get("CAPSULE_RT_FORGIVEN_LOG")  # to review what was forgiven
    if forgiven and log:
        with open(log, "a") as fh:
            fh.write(json.dumps({"operation": operation_id, "detail": detail}) + "\n")
    return not forgiven
