#!/usr/bin/env python3
"""Picture strip of an interior walk: six frames spread over the path (0, N/5, ..., N),
rendered by `coherent render` at 192x108 and stitched side by side; prints each frame's
most-common-colour share (exact RGB). With --every STEP, also renders every STEP-th frame of
the path and prints the largest share among them and the frames over 40%. Needs Pillow.

usage: scripts/interior_strip.py SCENE NATURAL_FRAMES OUT.png [COHERENT] [--every STEP]
(NATURAL_FRAMES: the interior path's length in frames, 30 per key.)
"""
import subprocess
import sys
import tempfile
from collections import Counter

from PIL import Image


W, H = 192, 108


def render(exe, scene, frame, png):
    """Renders one frame of the interior path; returns the image and its most-common-colour
    share."""
    subprocess.run(
        [exe, "render", "--scene", scene, "--path", "interior", "--frame", str(frame),
         "--size", f"{W}x{H}", "--no-validation", "--out", png],
        check=True, stdout=subprocess.DEVNULL)
    im = Image.open(png).convert("RGB")
    b = im.tobytes()
    return im, Counter(zip(b[0::3], b[1::3], b[2::3])).most_common(1)[0][1] / (W * H)


def main():
    args = sys.argv[1:]
    every = None
    if "--every" in args:
        i = args.index("--every")
        every = int(args[i + 1])
        del args[i:i + 2]
    scene, frames, out = args[0], int(args[1]), args[2]
    exe = args[3] if len(args) > 3 else "target/release/coherent"
    strip = Image.new("RGB", (6 * W, H))
    shares = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(6):
            im, share = render(exe, scene, frames * k // 5, f"{tmp}/{k}.png")
            shares.append(share)
            strip.paste(im, (k * W, 0))
        strip.save(out)
        print(" ".join(f"{s:.2f}" for s in shares))
        if every:
            all_shares = [(render(exe, scene, f, f"{tmp}/all.png")[1], f)
                          for f in range(0, frames + 1, every)]
            over = [f for s, f in all_shares if s > 0.40]
            worst = max(all_shares)
            print(f"every {every} frames: {len(all_shares)} rendered, largest share "
                  f"{worst[0]:.2f} (frame {worst[1]}), {len(over)} over 0.40: {over}")


if __name__ == "__main__":
    main()
