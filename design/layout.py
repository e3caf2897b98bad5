"""Layout optimisation on a finished coverage (docs/design.md, "Layout").

The spec (JSON; only ``sensors`` is required)::

    {"sensors": 8,
     "criterion": "p90",                  # or "mean" (design.criterion)
     "model_error": "none",               # or "bias": the delay model's own error too (design.criterion)
     "ranging": "toa",                    # or "rss": the RSS position bound of the CM2 path-loss model
     "rss_model": "cm2_deep_tissue",      # or "cm2_near_surface" (ranging rss)
     "max_model_error_s": null,           # links whose measured delay departs more from the model are not
                                          # usable; null: the travel-time grid's stated error n_max h / c
     "snr_db": null,                      # null: each link's SNR from the coverage's link budget; a number: every link
     "min_snr_db": null,                  # links below are not detected
     "require_direct_path": true,
     "min_sensors": 4,
     "constraints": {"axis": [0, 0, 1],   # "height" is along this axis
                     "belts": [{"height_m": 0.05, "tolerance_m": 0.01, "count": null}],
                     "keep_out": [{"min_m": [...], "max_m": [...]}, {"centre_m": [...], "radius_m": 0.05}],
                     "min_spacing_m": 0.0},
     "search": {"restarts": 4, "seed": 0, "exact_limit": 20000, "max_passes": 50},
     "evaluate": {"trials": 20, "seed": 0, "rays": 100000, "max_interactions": 6}}   # or null: bounds only

The answer: ``sensors`` (each ``position_m``, its candidate index, site name, belt), ``criterion_m``
(the optimised layout's criterion), ``baseline_criterion_m`` (the best subset of the same size of
the phantom's sensor sites, found by the same search without the constraints), per-position and
per-organ bounds of both, and with ``evaluate`` the end-to-end model-based error of both
(:mod:`design.evaluate`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from design.checks import boolean, integer, mapping, number, vector
from design.coverage import Plan, link_arrays, waveform_of
from design.criterion import STATISTICS, Problem, statistic, toa_sigma_s
from design.errors import DesignInputError
from design.optimize import Constraints, search
from estimators.rss import CM2_MODELS

MAX_SENSORS = 64
#: The ranging whose position bound is the criterion (docs/design.md, "The criterion").
RANGINGS = ("toa", "rss")
MAX_RESTARTS = 32
MAX_PASSES = 200
#: Search work bound: candidate scorings x positions (each a few 3x3 operations).
MAX_SEARCH_WORK = 2_000_000_000


def normalise_layout(data: Any, *, max_rays: int = 1_000_000, max_interactions: int = 10) -> dict:
    """The layout spec (module docstring) with defaults; :class:`DesignInputError` naming the field.
    ``max_rays`` / ``max_interactions``: the caps of the evaluation's traces (a server's settings)."""
    data = mapping(data if data is not None else {}, "", {"sensors", "criterion", "snr_db", "min_snr_db",
                                                         "require_direct_path", "min_sensors", "constraints",
                                                         "model_error", "max_model_error_s", "ranging",
                                                         "rss_model",
                                                         "search", "evaluate", "coverage"})
    if "sensors" not in data:
        raise DesignInputError("is required: how many sensors to place", "sensors")
    n = integer(data["sensors"], "sensors", lo=1, hi=MAX_SENSORS)
    kind = data.get("criterion", "p90")
    if kind not in STATISTICS:
        raise DesignInputError(f"must be one of {', '.join(STATISTICS)}", "criterion")
    snr = data.get("snr_db")
    snr = None if snr is None else number(snr, "snr_db", lo=-50.0, hi=200.0)
    min_snr = data.get("min_snr_db")
    min_snr = None if min_snr is None else number(min_snr, "min_snr_db", lo=-300.0, hi=200.0)
    cons = mapping(data.get("constraints") or {}, "constraints", {"axis", "belts", "keep_out", "min_spacing_m"})
    axis = vector(cons.get("axis", [0.0, 0.0, 1.0]), "constraints.axis")
    if not np.linalg.norm(axis) > 0:
        raise DesignInputError("must be a non-zero vector", "constraints.axis")
    belts = []
    raw = cons.get("belts") or []
    if not isinstance(raw, list) or len(raw) > 16:
        raise DesignInputError("must be a list of at most 16 belts", "constraints.belts")
    for i, b in enumerate(raw):
        f = f"constraints.belts[{i}]"
        b = mapping(b, f, {"height_m", "tolerance_m", "count"})
        if "height_m" not in b:
            raise DesignInputError("is required", f"{f}.height_m")
        belts.append({"height_m": number(b["height_m"], f"{f}.height_m"),
                      "tolerance_m": number(b.get("tolerance_m", 0.01), f"{f}.tolerance_m", lo=0.0, lo_open=True),
                      "count": None if b.get("count") is None else integer(b["count"], f"{f}.count", lo=0)})
    counts = [b["count"] for b in belts]
    if any(c is not None for c in counts):
        if any(c is None for c in counts):
            raise DesignInputError("give a count for every belt or for none", "constraints.belts")
        total = sum(int(c or 0) for c in counts)
        if total != n:
            raise DesignInputError(f"the belts' counts add up to {total}, not to sensors = {n}",
                                   "constraints.belts")
    keep_out = []
    raw = cons.get("keep_out") or []
    if not isinstance(raw, list) or len(raw) > 64:
        raise DesignInputError("must be a list of at most 64 regions", "constraints.keep_out")
    for i, r in enumerate(raw):
        f = f"constraints.keep_out[{i}]"
        r = mapping(r, f, {"min_m", "max_m", "centre_m", "radius_m"})
        if "centre_m" in r or "radius_m" in r:
            keep_out.append({"centre_m": vector(r.get("centre_m"), f"{f}.centre_m").tolist(),
                             "radius_m": number(r.get("radius_m"), f"{f}.radius_m", lo=0.0, lo_open=True)})
        else:
            lo = vector(r.get("min_m"), f"{f}.min_m")
            hi = vector(r.get("max_m"), f"{f}.max_m")
            if np.any(lo >= hi):
                raise DesignInputError("every max_m coordinate must exceed its min_m", f"{f}.max_m")
            keep_out.append({"min_m": lo.tolist(), "max_m": hi.tolist()})
    s = mapping(data.get("search") or {}, "search", {"restarts", "seed", "exact_limit", "max_passes"})
    ev = data.get("evaluate", {})
    evaluate = None
    if ev is not None:
        ev = mapping(ev, "evaluate", {"trials", "seed", "rays", "max_interactions"})
        evaluate = {"trials": integer(ev.get("trials", 20), "evaluate.trials", lo=1, hi=1000),
                    "seed": integer(ev.get("seed", 0), "evaluate.seed"),
                    "rays": integer(ev.get("rays", min(100_000, max_rays)), "evaluate.rays", lo=1, hi=max_rays),
                    "max_interactions": integer(ev.get("max_interactions", min(6, max_interactions)),
                                                "evaluate.max_interactions", lo=1,
                                                hi=max_interactions)}
    model_error = data.get("model_error", "none")
    if model_error not in ("none", "bias"):
        raise DesignInputError("must be none or bias", "model_error")
    tol = data.get("max_model_error_s")
    tol = None if tol is None else number(tol, "max_model_error_s", lo=0.0, hi=1e-6)
    ranging = data.get("ranging", "toa")
    if ranging not in RANGINGS:
        raise DesignInputError(f"must be one of {', '.join(RANGINGS)}", "ranging")
    rss_model = data.get("rss_model", "cm2_deep_tissue")
    if rss_model not in CM2_MODELS:
        raise DesignInputError(f"must be one of {', '.join(CM2_MODELS)}", "rss_model")
    if ranging == "rss" and model_error != "none":
        raise DesignInputError("the delay model's error is a TOA term: none with ranging rss", "model_error")
    return {
        "sensors": n, "criterion": kind, "snr_db": snr, "min_snr_db": min_snr, "model_error": model_error,
        "max_model_error_s": tol, "ranging": ranging, "rss_model": rss_model,
        "require_direct_path": boolean(data.get("require_direct_path", True), "require_direct_path"),
        "min_sensors": integer(data.get("min_sensors", 4), "min_sensors", lo=1, hi=MAX_SENSORS),
        "constraints": {"axis": axis.tolist(), "belts": belts, "keep_out": keep_out,
                        "min_spacing_m": number(cons.get("min_spacing_m", 0.0), "constraints.min_spacing_m", lo=0.0)},
        "search": {"restarts": integer(s.get("restarts", 4), "search.restarts", hi=MAX_RESTARTS),
                   "seed": integer(s.get("seed", 0), "search.seed"),
                   "exact_limit": integer(s.get("exact_limit", 20_000), "search.exact_limit", hi=10**6),
                   "max_passes": integer(s.get("max_passes", 50), "search.max_passes", lo=1, hi=MAX_PASSES)},
        "evaluate": evaluate,
    }


def model_tolerance_s(layout: dict, grid_error_s: float) -> float:
    """The largest |measured delay - model delay| of a usable link: ``max_model_error_s``, or the
    travel-time grid's stated error when null (docs/design.md, "The criterion")."""
    tol = layout.get("max_model_error_s")
    return float(grid_error_s if tol is None else tol)


def problem_of(layout: dict, coverage: dict, plan: Plan, arrays: dict[str, np.ndarray], prior_m: float,
               grid_error_s: float) -> Problem:
    """The criterion's :class:`Problem` from a coverage's link arrays (design.criterion docstring).

    A link is usable when it has a path (a refraction-only one with ``require_direct_path``), its SNR
    is at least ``min_snr_db`` and its *model mismatch* m = ranging delay - eikonal delay (what TOA
    measures without noise minus what the travel-time model predicts) is at most
    :func:`model_tolerance_s` in magnitude: a link the model cannot explain within its own stated
    accuracy biases the model-based fix, whatever its bound (docs/design.md, "Why the bound alone
    misled the search"). With ``model_error: bias`` each link's sigma also holds the grid's error as
    a uniform error (``grid_error_s`` / sqrt 3, the model-based fix's own weighting) and m enters
    as a linearised bias."""
    usable = arrays["paths"] > 0
    if layout["require_direct_path"]:
        usable &= arrays["direct_path"]
    snr = np.full(usable.shape, layout["snr_db"]) if layout["snr_db"] is not None else arrays["snr_db"]
    snr = np.where(np.isfinite(snr), snr, -np.inf)
    if layout["min_snr_db"] is not None:
        usable &= snr >= layout["min_snr_db"]
    if layout.get("ranging", "toa") == "rss":
        return Problem(rss_info(layout, plan, usable), usable, layout["criterion"], layout["min_sensors"], prior_m)
    e = arrays["ranging_delay_s"] - arrays["eikonal_delay_s"]
    with np.errstate(invalid="ignore"):
        usable &= np.abs(np.nan_to_num(e, nan=np.inf)) <= model_tolerance_s(layout, grid_error_s)
    sigma = toa_sigma_s(np.where(usable, snr, 0.0), waveform_of(coverage))
    mismatch = None
    if layout.get("model_error", "none") == "bias":
        sigma = np.sqrt(sigma**2 + grid_error_s**2 / 3.0)
        mismatch = np.where(usable, np.nan_to_num(e) / sigma, 0.0)
    info = np.where(usable[:, :, None], arrays["gradient_s_per_m"] / sigma[:, :, None], 0.0)
    return Problem(info, usable, layout["criterion"], layout["min_sensors"], prior_m, mismatch)


def rss_info(layout: dict, plan: Plan, usable: np.ndarray) -> np.ndarray:
    """(P, C, 3) information vectors of RSS ranging under the CM2 path-loss model (exponent eta,
    log-normal shadowing sigma_dB): u_pc = 10 eta / (ln 10 sigma_dB d_pc) e_pc, e_pc the unit vector
    from the candidate to the capsule and d_pc their distance (docs/science.md, the RSS bound;
    :func:`estimators.localization.rss_position_crlb`'s rows); zero where the link is not usable.
    Distance-based: it needs no delay model, so the model-mismatch rule does not apply."""
    model = CM2_MODELS[layout["rss_model"]]
    d = plan.positions.positions_m[:, None, :] - plan.candidates.positions_m[None, :, :]
    r = np.linalg.norm(d, axis=2)
    k = 10.0 * model.exponent / (np.log(10.0) * model.shadowing_db)
    return np.where(usable[:, :, None], k * d / np.maximum(r, 1e-9)[:, :, None] ** 2, 0.0)


def stated_grid_error_s(phantom, coverage: dict) -> float:
    """The travel-time fields' stated error n_max h / c (docs/localization.md), n_max the largest
    phase index of the phantom's organs at the coverage's carrier, h its cell."""
    from evaluation.fields import organ_indices

    n_max = float(np.max(organ_indices(phantom, coverage["frequency_hz"], "phase")))
    return n_max * coverage["cell_size_m"] / 299_792_458.0


def constraints_of(layout: dict, candidates_m: np.ndarray, is_site: np.ndarray) -> tuple[Constraints, np.ndarray]:
    """The search's :class:`Constraints` over the coverage's non-site candidates, and each candidate's
    belt (-1: none). :class:`DesignInputError` naming the constraint that leaves too few."""
    c = layout["constraints"]
    n = layout["sensors"]
    allowed = ~is_site
    if int(allowed.sum()) < n:
        raise DesignInputError(f"sensors = {n} exceeds the coverage's {int(allowed.sum())} candidates", "sensors")
    for i, r in enumerate(c["keep_out"]):
        if "radius_m" in r:
            inside = np.linalg.norm(candidates_m - np.asarray(r["centre_m"]), axis=1) <= r["radius_m"]
        else:
            inside = np.all((candidates_m >= r["min_m"]) & (candidates_m <= r["max_m"]), axis=1)
        allowed &= ~inside
    if not allowed.any():
        raise DesignInputError("the keep-out regions cover every candidate", "constraints.keep_out")
    if int(allowed.sum()) < n:
        raise DesignInputError(f"the keep-out regions leave {int(allowed.sum())} candidates, fewer than sensors = {n}",
                               "constraints.keep_out")
    belt_of = np.full(len(candidates_m), -1)
    quota = None
    if c["belts"]:
        axis = np.asarray(c["axis"], float)
        height = candidates_m @ (axis / np.linalg.norm(axis))
        best = np.full(len(candidates_m), np.inf)
        for b, belt in enumerate(c["belts"]):
            d = np.abs(height - belt["height_m"])
            on = (d <= belt["tolerance_m"]) & (d < best)
            belt_of[on] = b
            best[on] = d[on]
            if not (allowed & (np.abs(height - belt["height_m"]) <= belt["tolerance_m"])).any():
                raise DesignInputError(f"no allowed candidate lies within {belt['tolerance_m']:g} m of the belt at "
                                       f"{belt['height_m']:g} m", f"constraints.belts[{b}]")
        allowed &= belt_of >= 0
        if int(allowed.sum()) < n:
            raise DesignInputError(f"the belts hold {int(allowed.sum())} allowed candidates, fewer than sensors = {n}",
                                   "constraints.belts")
        if c["belts"][0]["count"] is not None:
            quota = tuple(b["count"] for b in c["belts"])
            for b, q in enumerate(quota):
                if int((allowed & (belt_of == b)).sum()) < q:
                    raise DesignInputError(f"belt {b} holds fewer allowed candidates than its count {q}",
                                           f"constraints.belts[{b}].count")
    return Constraints(allowed, candidates_m, c["min_spacing_m"], belt_of, quota), belt_of


def search_work(layout: dict, positions: int, candidates: int) -> int:
    """Candidate scorings x positions of the search, at most (greedy, then every pass of every start)."""
    n, s = layout["sensors"], layout["search"]
    if math.comb(candidates, n) <= s["exact_limit"]:
        return math.comb(candidates, n) * positions * n
    return (1 + s["restarts"]) * (n + s["max_passes"] * n) * candidates * positions


def _per_organ(organs, values: np.ndarray, kind: str) -> dict[str, float | None]:
    out = {}
    for o in dict.fromkeys(organs):
        rows = np.array([k for k, g in enumerate(organs) if g == o])
        v = float(statistic(values[rows], kind))
        out[o] = v if np.isfinite(v) else None
    return out


def _finite(a) -> list:
    return [float(v) if np.isfinite(v) else None for v in np.asarray(a, float)]


def run_layout(layout: dict, record: dict, plan: Plan, table, phantom, *,
               check: Callable[[str], None] | None = None) -> dict:
    """Search, baseline and (optionally) the end-to-end evaluation (module docstring): the result dict."""
    coverage = record["spec"]
    P, C = len(plan.positions), len(plan.candidates)
    arrays = link_arrays(table, P, C)
    lo, hi = (np.asarray(b, float) for b in phantom.bounds_m)
    prior = float(np.linalg.norm(hi - lo))
    grid_error = stated_grid_error_s(phantom, coverage)
    problem = problem_of(layout, coverage, plan, arrays, prior, grid_error)
    cands = plan.candidates.positions_m
    is_site = np.array([bool(s) for s in plan.candidates.site])
    cons, belt_of = constraints_of(layout, cands, is_site)
    work = search_work(layout, P, int(cons.allowed.sum()))
    if work > MAX_SEARCH_WORK:
        raise DesignInputError(f"the search is bounded at {MAX_SEARCH_WORK:.3g} candidate scorings x positions; this "
                               f"one may take {work:.3g}: fewer restarts or max_passes, or a coarser coverage",
                               "search.restarts")
    n, s = layout["sensors"], layout["search"]
    if check is not None:
        check("search")
    found = search(problem, cons, n, restarts=s["restarts"], seed=s["seed"], exact_limit=s["exact_limit"],
                   max_passes=s["max_passes"])
    if not found.subset:
        raise DesignInputError(f"no {n} candidates satisfy the constraints together (min_spacing_m "
                               f"{layout['constraints']['min_spacing_m']:g} m)", "constraints.min_spacing_m")
    best = problem.evaluate(found.subset)
    baseline = None
    if int(is_site.sum()) >= n:
        if check is not None:
            check("baseline")
        base_cons = Constraints(is_site.copy(), cands)
        base = search(problem, base_cons, n, restarts=s["restarts"], seed=s["seed"], exact_limit=max(s["exact_limit"],
                      math.comb(int(is_site.sum()), n) if math.comb(int(is_site.sum()), n) <= 10**6 else 0),
                      max_passes=s["max_passes"])
        baseline = {"subset": base.subset, "method": base.method, **problem.evaluate(base.subset)}
    organs = plan.positions.organ
    out: dict[str, Any] = {
        "sensors": [{"position_m": cands[c].tolist(), "candidate_index": int(c), "belt": int(belt_of[c])
                     if belt_of[c] >= 0 else None} for c in found.subset],
        "criterion": layout["criterion"], "criterion_m": best["criterion_m"], "uncovered_positions": best["uncovered"],
        "ranging": layout["ranging"],
        "model_tolerance_s": model_tolerance_s(layout, grid_error) if layout["ranging"] == "toa" else None,
        "baseline_criterion_m": None if baseline is None else baseline["criterion_m"],
        "baseline_sensors": None if baseline is None else [
            {"position_m": cands[c].tolist(), "candidate_index": int(c), "site": plan.candidates.site[c]}
            for c in baseline["subset"]],
        "baseline_uncovered_positions": None if baseline is None else baseline["uncovered"],
        "search": {"method": found.method, "evaluations": found.evaluations, "swaps": found.swaps,
                   "starts": found.starts, "candidates_allowed": int(cons.allowed.sum()),
                   "baseline_method": None if baseline is None else baseline["method"]},
        "positions": {"labels": list(plan.positions.labels), "organ": list(organs), "s_m": list(plan.positions.s_m),
                      "bound_m": _finite(best["bounds_m"]),
                      "baseline_bound_m": None if baseline is None else _finite(baseline["bounds_m"])},
        "per_organ": {o: {"bound_m": v} for o, v in _per_organ(organs, best["bounds_m"], layout["criterion"]).items()},
    }
    if baseline is not None:
        for o, v in _per_organ(organs, baseline["bounds_m"], layout["criterion"]).items():
            out["per_organ"][o]["baseline_bound_m"] = v
    if layout["evaluate"] is not None:
        from design.evaluate import evaluate_layouts

        ev = layout["evaluate"]
        layouts = {"optimized": cands[found.subset]}
        if baseline is not None:
            layouts["baseline"] = cands[baseline["subset"]]
        res = evaluate_layouts(phantom, plan.positions.positions_m, layouts, coverage=coverage,
                               snr_db=layout["snr_db"], min_snr_db=layout["min_snr_db"],
                               require_direct_path=layout["require_direct_path"], trials=ev["trials"],
                               ranging=layout["ranging"], rss_model=layout["rss_model"],
                               seed=ev["seed"], rays=ev["rays"], max_interactions=ev["max_interactions"],
                               check=None if check is None else (lambda p: check(f"evaluate {p + 1}/{P}")))
        out["evaluation"] = {"trials": ev["trials"], "seed": ev["seed"], "rays": ev["rays"],
                             "max_interactions": ev["max_interactions"]}
        for name, r in res.items():
            err = r["errors_m"]
            pooled = err[np.isfinite(err)]
            field = "evaluation" if name == "optimized" else "baseline_evaluation"
            out[field] = {
                **({} if name != "optimized" else out["evaluation"]),
                "rmse_m": float(np.sqrt(np.mean(pooled**2))) if len(pooled) else None,
                "p90_error_m": float(np.percentile(pooled, 90)) if len(pooled) else None,
                "positions_without_fix": int(np.sum(~np.isfinite(r["rmse_m"]))),
                "exact_bound_criterion_m": _finite([statistic(r["bound_m"], layout["criterion"])])[0],
                "rmse_per_position_m": _finite(r["rmse_m"]), "bound_per_position_m": _finite(r["bound_m"]),
                "per_organ": {o: {"rmse_m": _rms_rows(err, organs, o), "bound_m": v}
                              for o, v in _per_organ(organs, r["bound_m"], layout["criterion"]).items()},
            }
    return out


def _rms_rows(err: np.ndarray, organs, organ: str) -> float | None:
    rows = [k for k, g in enumerate(organs) if g == organ]
    e = err[rows]
    e = e[np.isfinite(e)]
    return float(np.sqrt(np.mean(e**2))) if len(e) else None


def report_markdown(result: dict, layout: dict) -> str:
    """The comparison of the optimised layout with the built-in sites, per organ (docs/design.md)."""
    mm = 1e3

    def f(v, d=3):
        return "-" if v is None else f"{v * mm:.{d}f}"

    lines = [f"# Layout: {len(result['sensors'])} sensors, criterion {result['criterion']} of the "
             f"{result.get('ranging', 'toa').upper()} position bound",
             "",
             f"criterion: optimized {f(result['criterion_m'])} mm, built-in sites "
             f"{f(result['baseline_criterion_m'])} mm"
             f" (uncovered positions {result['uncovered_positions']} / {result['baseline_uncovered_positions']}); "
             f"search {result['search']['method']}, {result['search']['candidates_allowed']} allowed candidates", ""]
    ev, bev = result.get("evaluation"), result.get("baseline_evaluation")
    head = "| organ | bound, optimized [mm] | bound, built-in [mm] |"
    sep = "|---|---|---|"
    if ev is not None:
        fix = "RSS" if result.get("ranging") == "rss" else "model-based"
        head += f" {fix} RMSE, optimized [mm] | {fix} RMSE, built-in [mm] |"
        sep += "---|---|"
    lines += [head, sep]
    for o, row in result["per_organ"].items():
        line = f"| {o} | {f(row['bound_m'])} | {f(row.get('baseline_bound_m'))} |"
        if ev is not None:
            other = (bev or {}).get("per_organ", {}).get(o, {}).get("rmse_m")
            line += f" {f(ev['per_organ'][o]['rmse_m'], 1)} | {f(other, 1)} |"
        lines.append(line)
    if ev is not None:
        lines.append(f"| **whole tract** | {f(result['criterion_m'])} | {f(result['baseline_criterion_m'])} | "
                     f"**{f(ev['rmse_m'], 1)}** | **{f((bev or {}).get('rmse_m'), 1)}** |")
        own = ("over the links the evaluation's traces found usable" if result.get("ranging") == "rss"
               else "with the sensors' own travel-time fields")
        lines += ["", f"Bounds {own} ({result['criterion']}): optimized "
                      f"{f(ev['exact_bound_criterion_m'])} mm, built-in "
                      f"{f((bev or {}).get('exact_bound_criterion_m'))} mm; "
                      f"{'RSS' if result.get('ranging') == 'rss' else 'model-based'} fixes: {ev['trials']} trials "
                      f"per position, seed {ev['seed']}, {ev['rays']} rays."]
    lines += ["", "Sensors (optimized): " + "; ".join(
        "[" + ", ".join(f"{v:.4f}" for v in s["position_m"]) + "]" for s in result["sensors"])]
    if result.get("baseline_sensors"):
        lines.append("Built-in sites chosen: " + ", ".join(s["site"] for s in result["baseline_sensors"]))
    return "\n".join(lines) + "\n"
