# bulgekit for Cura: a post-processing script (Extensions > Post Processing > Modify G-Code >
# Add a script > "bulgekit: bulges on the outer wall").
#
# Install: copy this file into Cura's scripts folder (Help > Show Configuration Folder, then the
# `scripts` folder inside it; create it if missing) and restart Cura. The bulgekit command must
# be installed on the machine: from a bulgekit checkout, `pipx install ./host` (or `pip install
# ./host` in a virtual environment; docs/host.md, "Install"); give its full path below if Cura
# does not find it on the PATH (pipx puts it in ~/.local/bin).
#
# Cura hands the script the G-code as a list of layer texts. The script writes them to a
# temporary file, runs `bulgekit post-process --placement FILE` on it (the same code as for
# PrusaSlicer), and hands the annotated G-code back. On any error Cura shows bulgekit's message
# and the G-code is not changed.
import os
import subprocess
import tempfile

from ..Script import Script


class Bulgekit(Script):
    def getSettingDataString(self):
        return """{
            "name": "bulgekit: bulges on the outer wall",
            "key": "Bulgekit",
            "metadata": {},
            "version": 2,
            "settings": {
                "placement": {
                    "label": "Placement file",
                    "description": "TOML file: what to draw and the bulge settings (see bulgekit's examples/placement.toml).",
                    "type": "str",
                    "default_value": ""
                },
                "command": {
                    "label": "bulgekit command",
                    "description": "The bulgekit program (a full path if it is not on the PATH).",
                    "type": "str",
                    "default_value": "bulgekit"
                }
            }
        }"""

    def execute(self, data):
        placement = self.getSettingValueByKey("placement").strip()
        command = self.getSettingValueByKey("command").strip() or "bulgekit"
        if not placement:
            raise ValueError("bulgekit: set the placement file in the script's settings")
        fd, path = tempfile.mkstemp(suffix=".gcode", prefix="bulgekit-cura-")
        try:
            with os.fdopen(fd, "w", encoding="utf-8", newline="") as f:
                f.write("".join(data))
            r = subprocess.run([command, "post-process", "--placement", placement, path],
                               capture_output=True, text=True)
            if r.returncode != 0:
                raise RuntimeError((r.stderr or r.stdout).strip() or f"bulgekit failed ({r.returncode})")
            with open(path, encoding="utf-8", newline="") as f:
                return [f.read()]
        finally:
            os.unlink(path)
