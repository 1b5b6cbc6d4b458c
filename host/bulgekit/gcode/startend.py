"""The start and end G-code of the prints bulgekit makes itself, no slicer (`bulgekit litho`,
`bulgekit calibrate`): heat the bed and the nozzle, home, wait for both; at the end, heaters
and fan off, the head 5 mm up, motors off. `{temp}` and `{bed_temp}` are filled in (fill)."""
from __future__ import annotations

HEAT_AND_HOME = """\
G21 ; millimetres
M140 S{bed_temp}
M104 S{temp}
G28 ; home
M190 S{bed_temp}
M109 S{temp}
"""
END = """\
M104 S0
M140 S0
M107
G91
G1 Z5 F300
G90
M84
"""


def fill(text: str, temp: int, bed_temp: int) -> str:
    return text.replace("{temp}", str(temp)).replace("{bed_temp}", str(bed_temp))
