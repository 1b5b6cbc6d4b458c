"""The bulge-map job: strokes from drawings, their placement on the wall, the map and
its format, the walls found in G-code, the annotated and stock-fallback G-code, the
statistics and the previews.  `api` is its Python API (re-exported by `bulgekit`).
"""
