"""Visual odometry along a centreline: the capsule's frames at given arc lengths and rolls, rendered,
and the MI motion estimate of every consecutive pair (docs/vision.md, "Along the GI tract").

    pair_estimates(phantom, s_m, roll_deg, settings=OdometrySettings(), cache_dir=None, check=None)
        -> list[PairEstimate | None]

Frame k sits on the phantom's centreline (``centreline``, default the GI tract) at arc length
``s_m[k]``, looking along the direction of travel, rolled by ``roll_deg[k]`` from the up vector
carried along its piece by parallel transport (:func:`vision.sequence.transported_ups`: a
function of the arc length only, so a capsule moving back and forth sees the same wall from the
same pose). Each organ wears its fixed texture (:func:`vision.mucosa.texture_for`), lit by the
capsule's LEDs with the automatic exposure of every frame (a capsule's light control; MI is blind
to gain). Pair k (frames k - 1, k) is estimated by :func:`vision.motion.estimate_motion` -- with
the fisheye's tilt (``fov_deg`` given) by default, since where the centreline bends the camera
turns between frames -- and its scale turned into an advance by
:func:`vision.advance.advance_for_scale` through the reference frame's geometry. A pair whose
frames lie on different pieces (an organ junction: a scene cut) is None.

Cache: with ``cache_dir``, each pair's estimate is one JSON file named by a hash of the
settings, the phantom, and the two poses (arc lengths and rolls to 1e-12), so re-running a
journey, or another journey through the same poses, costs nothing.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path as FilePath
from typing import Callable, Sequence

import numpy as np

from .advance import advance_for_scale
from .camera import FisheyeCamera
from .errors import VisionInputError
from .motion import estimate_motion
from .mucosa import texture_for
from .render import render_frame
from .sequence import GI_TRACT, Path, path_pose, transported_ups

#: Frames per call at most (work bound).
MAX_FRAMES = 5000


@dataclass(frozen=True)
class OdometrySettings:
    """The camera and the estimator of :func:`pair_estimates`. ``tilt``: estimate the camera's
    tilt between frames (the fisheye model of :func:`vision.motion.estimate_motion`); False: the
    thesis' similarity (rotation and scale only)."""

    size_px: int = 192
    fov_deg: float = 150.0
    tilt: bool = True
    bins: int = 64


@dataclass(frozen=True)
class PairEstimate:
    """The motion from frame k - 1 to frame k: ``advance_m`` (NaN when the scale is outside what
    advances can give), ``rotation_deg`` (the roll increment), ``scale``, ``tilt_deg``, the MI."""

    advance_m: float
    rotation_deg: float
    scale: float
    tilt_deg: tuple[float, float]
    mutual_information: float
    organ: str


def _key(phantom_name: str, settings: OdometrySettings, centreline: str, a: tuple, b: tuple) -> str:
    text = json.dumps({"phantom": phantom_name, "settings": asdict(settings), "centreline": centreline,
                       "a": [round(v, 12) for v in a], "b": [round(v, 12) for v in b], "version": 1},
                      sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()[:24]


def pair_estimates(phantom, s_m: Sequence[float], roll_deg: Sequence[float],
                   settings: OdometrySettings | None = None, *, centreline: str = GI_TRACT,
                   cache_dir: str | FilePath | None = None,
                   check: Callable[[], None] | None = None) -> list[PairEstimate | None]:
    """Per step k the estimate of pair (k - 1, k) (module doc); index 0 and scene cuts: None.
    ``check`` is called between pairs (a deadline may raise there)."""
    settings = settings or OdometrySettings()
    s = np.asarray(s_m, dtype=float)
    roll = np.asarray(roll_deg, dtype=float)
    if s.ndim != 1 or roll.shape != s.shape or not (np.isfinite(s).all() and np.isfinite(roll).all()):
        raise VisionInputError("s_m and roll_deg must be equal-length 1-D arrays of finite numbers", "s_m")
    if len(s) > MAX_FRAMES:
        raise VisionInputError(f"at most {MAX_FRAMES} frames, got {len(s)}", "s_m")
    line = getattr(phantom, "centrelines", {}).get(centreline)
    if line is None:
        raise VisionInputError(f"phantom {phantom.name!r} has no {centreline!r} centreline", "centreline")
    starts = np.concatenate([[0.0], line.junctions_s_m])
    paths = [Path(p.points_m) for p in line.pieces]
    ups: dict[int, np.ndarray] = {}
    camera = FisheyeCamera(settings.fov_deg, settings.size_px)
    disk = None if cache_dir is None else FilePath(cache_dir) / "vision"
    frames: dict[int, object] = {}

    def piece(k: int) -> int:
        if not 0.0 <= s[k] <= line.length_m + 1e-12:
            raise VisionInputError(f"arc length {s[k]!r} m is off the centreline (0 to {line.length_m:.6g} m)",
                                   f"s_m[{k}]")
        return int(np.clip(np.searchsorted(starts, s[k], side="right") - 1, 0, len(paths) - 1))

    def frame(k: int, i: int):
        if k not in frames:
            if i not in ups:
                ups[i] = transported_ups(paths[i])
            local = min(max(float(s[k] - starts[i]), 0.0), paths[i].length_m)
            organ = line.pieces[i].organ
            frames[k] = render_frame(phantom, path_pose(paths[i], ups[i], local, float(roll[k])), camera,
                                     texture=texture_for(organ, phantom=phantom), organ=organ, frame_index=k)
            frames.pop(k - 2, None)
        return frames[k]

    out: list[PairEstimate | None] = [None] * len(s)
    for k in range(1, len(s)):
        if check is not None:
            check()
        i, j = piece(k - 1), piece(k)
        if i != j:
            continue
        name = _key(phantom.name, settings, centreline, (s[k - 1], roll[k - 1]), (s[k], roll[k]))
        path = None if disk is None else disk / f"{name}.json"
        if path is not None and path.exists():
            rec = json.loads(path.read_text())
            adv = math.nan if rec["advance_m"] is None else rec["advance_m"]
            out[k] = PairEstimate(adv, rec["rotation_deg"], rec["scale"], tuple(rec["tilt_deg"]),
                                  rec["mutual_information"], rec["organ"])
            continue
        a, b = frame(k - 1, i), frame(k, j)
        est = estimate_motion(a.grey(), b.grey(), bins=settings.bins,
                              fov_deg=settings.fov_deg if settings.tilt else None)
        try:
            advance = advance_for_scale(a, est.scale)
        except VisionInputError:
            advance = math.nan
        out[k] = PairEstimate(float(advance), est.rotation_deg, est.scale, est.tilt_deg, est.mutual_information,
                              line.pieces[i].organ)
        if path is not None:
            disk.mkdir(parents=True, exist_ok=True)
            rec = asdict(out[k])
            rec["advance_m"] = None if math.isnan(advance) else advance
            path.write_text(json.dumps(rec))
    return out
