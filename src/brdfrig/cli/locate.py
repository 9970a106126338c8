"""brdfrig locate: find the chrome ball and the sample spheres in a test shot; print their plan lines.

The image is a test shot of the bench (a raw file, TIFF, EXR or .hdr). Every sphere is
found to sub-pixel accuracy; the one that looks most like a mirror (its brightest
pixels far above its typical ones: it reflects the lights themselves) is the probe. The
output is the [plan.probe] and [[plan.samples]] tables to paste into a session plan;
rename the samples as you like.
"""

from __future__ import annotations

from pathlib import Path

from brdfrig.cli._command import add_command


def register(subparsers) -> None:
    p = add_command(subparsers, "locate", "find the probe and sample spheres in a test shot (plan lines)", __doc__)
    p.add_argument("image", type=Path, help="test shot of the bench")
    p.add_argument("--max", type=int, default=8, metavar="N", help="at most N spheres (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print JSON instead of plan lines")
    p.set_defaults(func=run)


def locate(path: Path, max_count: int) -> dict:
    """``{"probe": circle, "samples": [circle, ...], "mirror_scores": [...]}`` of the spheres in an image."""
    from brdfrig.hdr.detect import detect_spheres, mirror_score
    from brdfrig.hdr.raw import read_frame

    image = read_frame(path)[0]
    circles = detect_spheres(image, max_count=max_count, name=str(path))
    scores = [mirror_score(image, c) for c in circles]
    probe = int(max(range(len(circles)), key=scores.__getitem__))
    return {"probe": circles[probe], "samples": [c for i, c in enumerate(circles) if i != probe],
            "mirror_scores": scores}


def run(args) -> int:
    import json

    from brdfrig.errors import InputError

    if not 1 <= args.max <= 64:
        raise InputError(f"--max must be an integer in [1, 64], got {args.max}")
    found = locate(args.image, args.max)
    if args.json:
        print(json.dumps(found, indent=1))
        return 0

    def circle(c) -> str:
        return "[" + ", ".join(f"{v:.2f}" for v in c) + "]"

    lines = ["[plan.probe]", f"circle = {circle(found['probe'])}", ""]
    for k, c in enumerate(found["samples"], 1):
        lines += ["[[plan.samples]]", f'name = "sample{k}"', f"circle = {circle(c)}", ""]
    print("\n".join(lines).rstrip())
    return 0
