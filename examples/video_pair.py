"""A video pair: two frames of the capsule camera rendered 2 mm apart along the default torso's
colon, the second rolled by 4 deg, and the thesis' Ch. 3 estimator (maximum mutual information)
recovering the roll, the scale and from it the advance (docs/vision.md); prints the estimate
beside the truth and draws both frames.

    python examples/video_pair.py [--s-mm 400] [--advance-mm 2] [--roll-deg 4] [--size-px 192] [--out DIR]
"""

from __future__ import annotations

from _common import parser, save

from plots.figure import new_figure
from raytrace.body.torso import default_torso
from vision.advance import advance_for_scale
from vision.camera import FisheyeCamera
from vision.motion import estimate_motion
from vision.mucosa import texture_for
from vision.sequence import centreline_path, render_sequence


def main(argv=None) -> None:
    p = parser(__doc__)
    p.add_argument("--s-mm", type=float, default=420.0, help="arc length of the first frame (transverse colon)")
    p.add_argument("--advance-mm", type=float, default=2.0)
    p.add_argument("--roll-deg", type=float, default=4.0)
    p.add_argument("--size-px", type=int, default=192)
    args = p.parse_args(argv)
    torso = default_torso()
    path, offset_m, organ = centreline_path(torso, args.s_mm / 1e3, args.advance_mm / 1e3)
    seq = render_sequence(torso, path, 2, args.advance_mm / 1e3, args.roll_deg, FisheyeCamera(150.0, args.size_px),
                          start_m=offset_m, texture=texture_for(organ), organ=organ)
    a, b = seq.frames
    est = estimate_motion(a.grey(), b.grey())
    advance_m = advance_for_scale(a, est.scale)
    print(f"{organ}: rotation {est.rotation_deg:.2f} deg (true {args.roll_deg}), scale {est.scale:.4f}, "
          f"advance {advance_m * 1e3:.2f} mm (true {args.advance_mm})")
    fig = new_figure(8.0, 4.2)
    for k, (frame, label) in enumerate(((a, "reference"), (b, f"moving: +{args.advance_mm} mm, {args.roll_deg} deg"))):
        ax = fig.add_subplot(1, 2, k + 1)
        ax.imshow(frame.to_uint8())
        ax.set_title(label)
        ax.set_axis_off()
    fig.suptitle(f"{organ}: estimated roll {est.rotation_deg:.2f} deg, advance {advance_m * 1e3:.2f} mm")
    save(fig, args.out, "video_pair.png")


if __name__ == "__main__":
    main()
