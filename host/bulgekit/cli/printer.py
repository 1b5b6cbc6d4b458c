"""CLI command group `printer`: the printer model every writer and the estimator read
(bulgekit.machine) — read one from a connected printer, show a preset or a file's.

cli/__init__.py calls register(main) to add it to the bulgekit command group.
"""
from __future__ import annotations

import os

import click


from ._util import POSITIVE, friendly, printer_model


def register(main):
    @main.group(short_help="The printer model: read it from a printer, show presets and files.")
    def printer():
        """The printer model that `build`, `post-process`, `fallback`, `litho` and `estimate`
        take with --printer: steps/mm, accelerations, feed-rate limits, junction deviation or
        classic jerk, the firmware kind (docs/host.md, "The printer model")."""

    @printer.command("read", short_help="Ask a connected printer (M115, M503) and save its profile.")
    @click.option("-p", "--port", required=True, envvar="BULGEKIT_PORT", show_envvar=True,
                  help="Serial device (/dev/ttyUSB0, COM3) or pyserial URL (socket://host:port).")
    @click.option("-b", "--baud", type=int, default=115200, show_default=True)
    @click.option("-o", "--output", type=click.Path(dir_okay=False), default="printer.toml",
                  show_default=True, help="Profile TOML to write (then --printer FILE).")
    @click.option("--timeout", type=POSITIVE, default=10.0, show_default=True,
                  help="Seconds to wait for each reply.")
    @click.option("--boot-wait", type=click.FloatRange(min=0), default=2.0, show_default=True,
                  help="Seconds to wait for the board to start after opening the port (0: none).")
    @friendly
    def read(port, baud, output, timeout, boot_wait):
        """Send M115 and M503 to the printer on PORT and save what they say as a profile TOML.
        Settings M503 does not print keep Marlin's defaults (the profile lists every one: check
        them). Klipper answers no M503: give --printer your printer.cfg instead."""
        from .. import machine, outputs
        from ..printer.sender import Sender
        with Sender(port, baud, timeout=timeout, boot_wait=boot_wait) as s:
            ident = s.command("M115", "M115")
            settings = s.command("M503", "M503")
        text = "\n".join(ident + settings)
        name = os.path.splitext(os.path.basename(output))[0]
        if not machine.has_settings("\n".join(settings)):
            raise machine.ProfileError(f"{port}: M503 printed no settings (is EEPROM_SETTINGS or "
                                       "its report off? Klipper: use --printer printer.cfg)")
        m = machine.from_m503(text, source=f"{port}", name=name)
        outputs.write(output, machine.to_toml(m))          # in place when the command ends
        click.echo(f"printer: {m.describe()}")
        click.echo(f"wrote {output} (use: --printer {output})")

    @printer.command("show", short_help="Show a preset's or a file's printer model.")
    @click.argument("spec", required=False, metavar="[PRESET|FILE]")
    @click.option("--firmware", type=click.Choice(("marlin", "klipper", "prusa", "reprap")))
    @click.option("--toml", "as_toml", is_flag=True, help="Print it as a profile TOML.")
    @friendly
    def show(spec, firmware, as_toml):
        """Print the model a command would use with --printer SPEC (none: the default), and
        where its numbers come from. Without SPEC, the presets are listed too."""
        from .. import machine
        m = printer_model(spec, firmware)
        if as_toml:
            click.echo(machine.to_toml(m), nl=False)
            return
        click.echo(m.describe())
        if m.source:
            click.echo(f"  from: {m.source}")
        if spec is None:
            click.echo("presets:")
            for k, p in machine.PRESETS.items():
                click.echo(f"  {k:<20} {p.source}")
