"""Score one point of an image against a template built at a point of another image.

Builds the template at pixel (X, Y) of TEMPLATE_IMAGE and scores pixel (X, Y) of IMAGE at all 48
angles. The angle is the anticlockwise rotation, as displayed (image y down), of the target in
IMAGE relative to the template; the best angle is refined between grid bins.
"""

from __future__ import annotations

import argparse
import json

import numpy as np

from common.sources.imageio import ImageReadError, read_rgb

HELP = "score a point of an image against a template (polar matching)"


def _point(text: str) -> tuple[float, float]:
    try:
        x, y = (float(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected X,Y (two numbers), got {text!r}") from None
    if not (np.isfinite(x) and np.isfinite(y)):
        raise argparse.ArgumentTypeError(f"X,Y must be finite, got {text!r}")
    return x, y


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("image", metavar="IMAGE", help="image to score")
    p.add_argument("--template", required=True, metavar="TEMPLATE_IMAGE", help="image holding the target")
    p.add_argument("--template-at", required=True, type=_point, metavar="X,Y", help="target centre in TEMPLATE_IMAGE (pixels)")
    p.add_argument("--at", required=True, type=_point, metavar="X,Y", help="point of IMAGE to score (pixels)")
    p.add_argument("--grey", action="store_true", help="match on luminance only instead of RGB")
    p.add_argument("--json", action="store_true", help="print one JSON object")


def run(args: argparse.Namespace) -> int:
    from services.commands.errors import UsageError
    from common.detector import PolarMatcher, Template, prepare_frame
    from common.detector.layout import SUPPORT_RADIUS_PX
    from common.detector.matcher import ANGLES_DEG

    try:
        timg = read_rgb(args.template)
        img = read_rgb(args.image)
    except ImageReadError as exc:
        raise UsageError(str(exc)) from None
    if args.grey:
        timg = _grey(timg)
        img = _grey(img)
    for name, im, (x, y) in (("--template-at", timg, args.template_at), ("--at", img, args.at)):
        h, w = im.shape[:2]
        r = SUPPORT_RADIUS_PX
        if not (0 <= x <= w - 1 and 0 <= y <= h - 1):
            raise UsageError(f"{name} {x:g},{y:g} is outside the {w}x{h} image")
        if not (r <= x <= w - 1 - r and r <= y <= h - 1 - r):
            raise UsageError(
                f"{name} {x:g},{y:g} is within {r} px of the edge of the {w}x{h} image; "
                f"the matcher's support needs a point at least {r} px inside it"
            )
    template = Template.from_image(timg, args.template_at)
    matcher = PolarMatcher(template)
    x, y = args.at
    r = SUPPORT_RADIUS_PX
    prep = prepare_frame(img, (x - r, y - r, x + r + 1, y + r + 1))
    best_angle, best_score, grid = matcher.refine_peak(prep, x, y)
    result = {
        "angles_deg": [float(a) for a in ANGLES_DEG],
        "scores": [round(float(s), 6) for s in grid],
        "best_angle_deg": round(best_angle, 4),
        "best_score": round(best_score, 6),
    }
    if args.json:
        print(json.dumps(result))
    else:
        print(f"best angle {best_angle:+.2f} deg, score {best_score:.4f}")
        top = np.argsort(grid)[::-1][:5]
        print("top grid angles: " + ", ".join(f"{ANGLES_DEG[i]:.1f} ({grid[i]:.3f})" for i in top))
    return 0


def _grey(img: np.ndarray) -> np.ndarray:
    return (img.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32))
