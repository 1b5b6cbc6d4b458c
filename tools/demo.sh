#!/usr/bin/env bash
# The main job on data shipped in the repo (make demo):
#  1. the host toolkit: text + a wave on a sliced 40 mm cylinder (examples/) ->
#     bulge map, annotated G-code, stock-firmware fallback, previews, stats;
#  2. the firmware core, built natively (bkcore), runs the annotated G-code and
#     reports the stops, dwell and filament it would produce;
#  3. width by feedrate: the paper's sine-wave wall through the core;
#  4. a small lithophane from a sample picture (bulgekit litho): width-mode and stock G-code,
#     STL, predicted backlit look, figures.
# Steps 1 and 4 need only Python and the host's PyPI packages. Steps 2 and 3 run the firmware's
# C++ core, so they need a g++ (make test installs one); without it they are skipped, and say so.
set -euo pipefail
cd "$(dirname "${BASH_SOURCE[0]}")/.."
out=${1:-out/demo}
command -v bulgekit >/dev/null || { echo "demo: the bulgekit command is missing: run 'make demo', which installs it" >&2; exit 1; }
core=1
command -v g++ >/dev/null && [ -x .build/bin/bkcore ] || core=0
skipped() {
  echo "  skipped: the firmware core is C++ and there is no g++ here ('make test' installs it," \
       "or apt-get install g++); the host toolkit does not need it"
}

echo "== 1. host toolkit: bulgekit demo -o $out"
bulgekit demo -o "$out"

echo
echo "== 2. firmware core (native) on $out/demo.bulge.gcode"
if [ $core = 1 ]; then
  .build/bin/bkcore < "$out/demo.bulge.gcode" | tail -n 1 | fold -s -w 100 | sed 's/^/  /'
  echo "  (e_out = e_gcode + extra: the extra went through the internal E offset; host_e and pos are
   exactly where the G-code left them)"
else skipped; fi

echo
echo "== 3. width by feedrate: sine-wave wall (Jang & Hong, Fig. 4)"
if [ $core = 1 ]; then
  make -s -C tools/sinewall sinewall >/dev/null
  tools/sinewall/sinewall
else skipped; fi

echo
echo "== 4. lithophane: bulgekit litho examples/litho/drawing.png --width 40 -o $out/litho"
bulgekit litho examples/litho/drawing.png --width 40 -o "$out/litho"
echo
echo "outputs in $out/ (open demo.preview.png, demo.preview3d.png and litho/drawing.transmission.png)"
