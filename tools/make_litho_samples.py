#!/usr/bin/env python3
"""Writes the sample images for `bulgekit litho` into examples/litho/ (all drawn here, nothing
downloaded):

  wedge.png    a grey wedge: eight hard steps from white to black, then a smooth ramp (steps test
               how the mid-line follows a sudden change of thickness; the ramp tests the curve)
  text.png     black lettering on white with a thin frame (sharp edges, thin strokes)
  drawing.png  a line drawing with filled shapes and a radial shading (sun over hills)

Usage: python3 tools/make_litho_samples.py [OUTDIR]
"""
from __future__ import annotations

import math
import sys
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont


def wedge(w=400, h=380) -> Image.Image:
    im = Image.new("L", (w, h), 255)
    d = ImageDraw.Draw(im)
    top = h * 55 // 100
    steps = 8
    for i in range(steps):                      # hard steps, white (left) to black (right)
        x0, x1 = w * i // steps, w * (i + 1) // steps
        d.rectangle([x0, 0, x1 - 1, top - 1], fill=round(255 * (1 - i / (steps - 1))))
    for x in range(w):                          # smooth ramp below
        d.line([(x, top), (x, h - 1)], fill=round(255 * (1 - x / (w - 1))))
    return im


def text(w=400, h=380) -> Image.Image:
    im = Image.new("L", (w, h), 255)
    d = ImageDraw.Draw(im)
    d.rectangle([6, 6, w - 7, h - 7], outline=0, width=6)
    try:
        font = ImageFont.load_default(size=84)
    except TypeError:                           # Pillow < 10.1 has one fixed size
        font = ImageFont.load_default()
    for i, word in enumerate(("BULGE", "KIT")):
        box = d.textbbox((0, 0), word, font=font)
        x = (w - (box[2] - box[0])) // 2
        d.text((x, 60 + i * 140), word, fill=40, font=font)
    return im


def drawing(w=400, h=380) -> Image.Image:
    im = Image.new("L", (w, h), 235)
    px = im.load()
    cx, cy, r = w * 0.68, h * 0.32, h * 0.16
    for y in range(h):                          # sky: radial glow around the sun
        for x in range(w):
            dist = math.hypot(x - cx, y - cy)
            px[x, y] = max(0, min(255, round(250 - 0.55 * dist)))
    d = ImageDraw.Draw(im)
    d.ellipse([cx - r, cy - r, cx + r, cy + r], fill=255, outline=60, width=3)
    hills = [(0, h)] + [(x, h * 0.62 + 28 * math.sin(x / 37.0) + 18 * math.sin(x / 13.0))
                        for x in range(0, w + 1, 4)] + [(w, h)]
    d.polygon(hills, fill=70)
    front = [(0, h)] + [(x, h * 0.80 + 20 * math.sin(x / 23.0 + 1.0)) for x in range(0, w + 1, 4)] + [(w, h)]
    d.polygon(front, fill=20)
    for i in range(5):                          # birds: thin strokes
        bx, by = 60 + 45 * i, 70 + 17 * (i % 2)
        d.line([(bx, by), (bx + 10, by + 7), (bx + 20, by)], fill=30, width=3)
    return im


def main(argv: list[str]) -> int:
    out = Path(argv[1]) if len(argv) > 1 else Path(__file__).resolve().parents[1] / "examples" / "litho"
    out.mkdir(parents=True, exist_ok=True)
    for name, fn in (("wedge", wedge), ("text", text), ("drawing", drawing)):
        p = out / f"{name}.png"
        fn().save(p, optimize=True)
        print(f"wrote {p}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
