"""header_layer_height starts each pattern's search at the line its words first occur on (the
four regexes scan a file's 4 MB of ends in some 20 ms each): it finds what a search of the whole
text finds, on texts with the words where no pattern matches (first_layer_height, inside a line,
after a blank line below the ";", Unicode blanks), the value unparsable or 0, several dialects."""
from __future__ import annotations

import random

from bulgekit.gcode import _HEADER_HEIGHT, header_height_of, header_layer_height


def whole_text_search(text: str) -> float | None:
    """header_layer_height as it was: every pattern searched from the start of the text."""
    for rx in _HEADER_HEIGHT:
        v = header_height_of(rx.search(text))
        if v is not None:
            return v
    return None


PIECES = ["; first_layer_height = 0.3", "; layer_height = 0.25", ";layer_height=0.2", "layer_height = 0.4",
          ";\n\n  layer_height = 0.15", "; \u00a0\u2003layer_height = 0.35", "x; layer_height = 0.45",
          "; layer_height = 0", "; layer_height = 0.1.2", ";Layer height: 0.3", "; Layer height: 0.5",
          ";LAYER HEIGHT: 0.6", ";Layer Height: 0.7", "G1 X10 ;Layer height: 0.8", ";   layerHeight,0.2",
          ";layerHeight,", "; printer_model = MK3S", "G1 X1 Y2 E0.5", ";TYPE:External perimeter", "",
          "\t", ";", ";\u00a0", "\u2028; layer_height = 0.55"]


def test_the_search_from_the_words_finds_what_the_whole_text_search_finds():
    rng = random.Random(26)
    found = set()
    for _ in range(3000):
        text = "\n".join(rng.choice(PIECES) for _ in range(rng.randint(0, 12)))
        want = whole_text_search(text)
        assert header_layer_height(text) == want, repr(text)
        found.add(want)
    # (the texts reach every dialect and the cases that find nothing)
    assert {None, 0.25, 0.2, 0.15, 0.35, 0.3, 0.6, 0.7} <= found
