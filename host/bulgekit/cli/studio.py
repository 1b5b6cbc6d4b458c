"""CLI command `studio`: the local web app (studio/). cli/__init__.py calls register(main)."""
from __future__ import annotations

import click

from ._util import POSITIVE, friendly


def register(main):
    @main.command(short_help="Place text and pictures on the wall in a browser; export, print, lithophanes.")
    @click.argument("gcode", required=False, type=click.Path(exists=True, dir_okay=False))
    @click.option("--port", type=click.IntRange(0, 65535), default=8420, show_default=True,
                  help="Port on 127.0.0.1 (0: any free one).")
    @click.option("--no-browser", is_flag=True, help="Only print the address; open no browser.")
    @click.option("--workdir", type=click.Path(file_okay=False),
                  help="Where uploads and exports go [a new folder under ~/.cache/bulgekit/studio].")
    @click.option("--max-upload", type=POSITIVE, default=256, show_default=True,
                  help="Largest G-code the page may open, MB.")
    @click.option("--arena", type=click.IntRange(min=1), default=1024, show_default=True,
                  help="Printer's map arena (BK_MAP_ARENA_BYTES), for the page's warnings.")
    @friendly(outputs=False)
    def studio(gcode, port, no_browser, workdir, max_upload, arena):
        """Start the studio: a page on http://127.0.0.1:PORT/ to open a sliced G-code (GCODE, or
        drop one on the page), place text, SVG drawings and pictures on its outer wall, see the
        bumps in 3D and unrolled, and export the map, the annotated and stock G-code, previews
        and the placement file (the same files `bulgekit build --placement` makes), or send them
        to a printer. A second tab makes lithophanes. Ctrl-C stops it.

        The server answers only this machine's browser page; it reads the files you choose and
        writes only in its working folder."""
        import os
        import signal
        import threading
        import time
        import webbrowser
        from pathlib import Path

        from ..outputs import Stopped
        from ..studio.server import Limits, Studio, serve

        if workdir is None:
            base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "bulgekit" / "studio"
            workdir = base / time.strftime("%Y%m%d-%H%M%S")
            k = 1
            while workdir.exists():
                k += 1
                workdir = base / f"{time.strftime('%Y%m%d-%H%M%S')}-{k}"
        st = Studio(Path(workdir), Limits(gcode_bytes=int(max_upload * 1_000_000), arena=arena))
        run = serve(st, port)
        if gcode:
            st.start("open", st.open_gcode, Path(gcode), Path(gcode).name)
        click.echo(f"bulgekit studio: {run.url}  (working folder {st.workdir}; Ctrl-C stops it)")
        if not no_browser:
            threading.Thread(target=webbrowser.open, args=(run.url,), daemon=True).start()
        try:
            threading.Event().wait()
        except Stopped as e:             # Ctrl-C is how it stops: exit status 0 (SIGTERM: 143)
            if e.signum != signal.SIGINT:
                raise
            click.echo("bulgekit studio: stopped")
        finally:
            run.stop()
