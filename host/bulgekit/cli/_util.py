"""Pieces shared by the command modules (cli/__init__.py, cli/io.py)."""
from __future__ import annotations

import contextlib
import functools
import math
import sys
import warnings

import click

from ..errors import BulgekitError, MissingInputError


class MissingInput(click.ClickException):
    """An input file named inside another (a placement file's drawing) that is not there: exit
    status 2 as a usage error, but one `Error:` line, without click's Usage lines (the command
    line itself was right)."""
    exit_code = 2


def friendly(fn=None, *, outputs: bool = True):
    """Turn expected failures into one-line messages (exit status 1): our own
    errors (they name the file and line, stroke or layer), map-format errors,
    and I/O errors. An input file named inside another and not there is a usage
    error (exit status 2), as click's for one named on the command line.
    Every file the command writes goes in place when it ends, all or none (one
    bulgekit.outputs.Outputs for the command); outputs=False: none for a command
    that runs until stopped (studio)."""
    if fn is None:
        return functools.partial(friendly, outputs=outputs)
    from .. import outputs as out

    @functools.wraps(fn)
    def wrapper(*a, **kw):
        try:
            with out.Outputs(final=True) if outputs else contextlib.nullcontext():
                return fn(*a, **kw)
        except MissingInputError as e:
            raise MissingInput(str(e)) from None
        except BulgekitError as e:
            raise click.ClickException(str(e)) from None
        except ValueError as e:  # mapformat.MapFormatError and friends
            if type(e).__module__.startswith("bulgekit"):
                raise click.ClickException(str(e)) from None
            raise
        except BrokenPipeError:
            raise  # output piped into `head`: click ends quietly
        except OSError as e:
            raise click.ClickException(f"{e.filename or ''}: {e.strerror or e}") from None
    return wrapper


@contextlib.contextmanager
def warning_lines():
    """While a command runs, a warning of bulgekit's own (gcode.CutOffWarning) is one line on
    stderr, `WARNING: FILE: ...`, once per message; others are shown as Python shows them."""
    with warnings.catch_warnings():
        shown = warnings.showwarning

        def show(message, category, filename, lineno, file=None, line=None):
            if not category.__module__.startswith("bulgekit"):
                return shown(message, category, filename, lineno, file, line)
            click.echo(f"WARNING: {message}", err=True)
        warnings.showwarning = show
        yield


def progress_option(fn):
    """--quiet, and progress on stderr for the command's passes over its G-code while it runs
    (only on a terminal: a slicer, a pipe or a log gets none)."""
    @functools.wraps(fn)
    def wrapper(*a, quiet=False, **kw):
        from .. import progress
        if not quiet and sys.stderr.isatty():
            progress.enable()
        try:
            return fn(*a, **kw)
        finally:
            progress.disable()
    return click.option("-q", "--quiet", is_flag=True,
                        help="No progress on stderr (it is shown only on a terminal).")(wrapper)


class Num(click.ParamType):
    """A finite float, optionally within lo..hi (lo excluded with lo_open);
    click's FloatRange lets nan through."""
    name = "number"

    def __init__(self, lo: float | None = None, hi: float | None = None, lo_open: bool = False):
        self.lo, self.hi, self.lo_open = lo, hi, lo_open

    def convert(self, value, param, ctx):
        try:
            v = float(value)
        except (TypeError, ValueError):
            self.fail(f"{value!r} is not a number", param, ctx)
        if not math.isfinite(v):
            self.fail(f"{value!r} is not a finite number", param, ctx)
        lo_bad = self.lo is not None and (v <= self.lo if self.lo_open else v < self.lo)
        if lo_bad or (self.hi is not None and v > self.hi):
            lo = "" if self.lo is None else (f"> {self.lo:g}" if self.lo_open else f">= {self.lo:g}")
            hi = "" if self.hi is None else f"<= {self.hi:g}"
            self.fail(f"{value} must be {' and '.join(t for t in (lo, hi) if t)}", param, ctx)
        return v


FINITE = Num()
POSITIVE = Num(0.0, lo_open=True)
NONNEG = Num(0.0)


def pair(ctx, param, value):
    """click callback for a "U,V" option in mm."""
    if value is None:
        return None
    try:
        a, b = (float(t) for t in value.split(","))
    except ValueError:
        raise click.BadParameter(f"expected two numbers U,V (mm), got {value!r}") from None
    if not (math.isfinite(a) and math.isfinite(b)):
        raise click.BadParameter(f"U,V must be finite numbers, got {value!r}")
    return (a, b)


# where --at puts a drawing by default: u 0, 1 mm above the bed (above the first layers); a JSON
# stroke list is already in wall mm (what `strokes -o` writes) and is not moved
AT_DEFAULT = (0.0, 1.0)
AT_HELP = "[0,1: 1 mm above the bed; a .json stroke list: 0,0, as it is]"


def at_for(at, path=None) -> tuple[float, float]:
    """--at as given, or its default for this input (a stroke file's path, or None: text)."""
    if at is not None:
        return at
    return (0.0, 0.0) if path is not None and str(path).lower().endswith(".json") else AT_DEFAULT


ALIGNS = ("left", "center", "right")     # strokes.ALIGNS (not imported: `annotate` loads no build module)


def face_options(fn):
    """--face N and --align (docs/host.md, "Faces and corners"): strokes.on_face."""
    fn = click.option("--align", type=click.Choice(ALIGNS),
                      help="With --face: the drawing's left end at the face's start, its middle at "
                           "the face's middle, or its right end at the face's end [center].")(fn)
    fn = click.option("--face", type=click.IntRange(min=1), metavar="N",
                      help="Put the drawing on face N of the wall (faces: the stretches between "
                           "corners, 1 holding u = 0, counted along u; see the preview), at the "
                           "height of its middle; --at U,V's U is then an offset from there.")(fn)
    return fn


OUTDIR_DEFAULT = "bulgekit-out"


class _OldSpellings(click.Option):
    """An option whose earlier spellings still parse (scripts keep working) but are left out of
    --help, so the help shows the one convention."""

    def __init__(self, *a, old_spellings=(), **kw):
        super().__init__(*a, **kw)
        self.old_spellings = set(old_spellings)

    def get_help_record(self, ctx):
        opts = self.opts
        self.opts = [o for o in opts if o not in self.old_spellings]
        try:
            return super().get_help_record(ctx)
        finally:
            self.opts = opts


def outdir_option(*old_spellings):
    """`-o/--outdir DIR`, the output folder of every command that writes several files
    (build, litho, demo); a command writing one file takes `-o/--output FILE`."""
    return click.option("-o", "--outdir", *old_spellings, "outdir", cls=_OldSpellings,
                        old_spellings=old_spellings, type=click.Path(file_okay=False),
                        default=OUTDIR_DEFAULT, show_default=True, help="Output folder.")


def printer_options(fn):
    """--printer and --firmware: the printer model every writer and the estimator read
    (bulgekit.machine; docs/host.md, "The printer model")."""
    from ..machine import FIRMWARES, PRESETS
    fn = click.option("--firmware", type=click.Choice(FIRMWARES),
                      help="The printer's firmware, which sets the form of a stock file's stops "
                           "[the printer model's].")(fn)
    fn = click.option("--printer", "printer", metavar="PRESET|FILE",
                      help="The printer: a preset (" + ", ".join(PRESETS) + ") or a file: a saved "
                           "M503 reply, a Klipper printer.cfg or a profile TOML (bulgekit printer "
                           "read). The G-code's own M92/M201/M203/M204/M205/M900 then apply. "
                           "[marlin: Marlin's defaults, E 93]")(fn)
    return fn


def printer_model(printer: str | None, firmware: str | None, gcode=None, e_steps: float | None = None):
    """The model a command works for: --printer (or the default), --firmware, then the file's own
    settings before its first extrusion (gcode: a path), then --e-steps when given."""
    from dataclasses import replace

    from ..machine import resolve, with_gcode
    m = resolve(printer, firmware)
    if gcode is not None:
        with open(gcode, "rb") as f:
            head = f.read(1 << 20).split(b"\n")[:-1]
        m = with_gcode(m, head, str(gcode))
    if e_steps is not None:
        m = replace(m, steps_per_mm=m.steps_per_mm.with_(E=e_steps))
    return m

