#!/usr/bin/env python3
"""Picture strip of an interior walk: six frames spread over the path (0, N/5, ..., N),
rendered by `coherent render` at 192x108 and stitched side by side; prints each frame's
most-common-colour share (exact RGB). Needs Pillow.

usage: scripts/interior_strip.py SCENE NATURAL_FRAMES OUT.png [COHERENT]
(NATURAL_FRAMES: the interior path's length in frames, 30 per key.)
"""
import subprocess
import sys
import tempfile
from collections import Counter

from PIL import Image


def main():
    scene, frames, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    exe = sys.argv[4] if len(sys.argv) > 4 else "target/release/coherent"
    w, h = 192, 108
    strip = Image.new("RGB", (6 * w, h))
    shares = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(6):
            f = frames * k // 5
            png = f"{tmp}/{k}.png"
            subprocess.run(
                [exe, "render", "--scene", scene, "--path", "interior", "--frame", str(f),
                 "--size", f"{w}x{h}", "--no-validation", "--out", png],
                check=True, stdout=subprocess.DEVNULL)
            im = Image.open(png).convert("RGB")
            top = Counter(im.getdata()).most_common(1)[0][1]
            shares.append(top / (w * h))
            strip.paste(im, (k * w, 0))
    strip.save(out)
    print(" ".join(f"{s:.2f}" for s in shares))


if __name__ == "__main__":
    main()
