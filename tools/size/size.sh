#!/bin/bash
# Flash and RAM of the portable core on an ATmega2560, with the flags Marlin's AVR
# build uses (avr-gcc -Os, LTO, gc-sections). Prints the totals beyond a baseline
# that already has what Marlin links anyway (float arithmetic, sqrt, UART, the
# strtod/strtoul its G-code parser converts numbers with), then
# the largest functions with the flash text (BK_F strings) each one owns.
#   bash tools/size/size.sh [N]          N: how many rows to list (default 40)
#   NOINLINE=1 bash tools/size/size.sh   every function on its own row (total grows)
#   PROBE=bulge|width bash tools/size/size.sh   one feature only (default: both)
#   tools/size/budget.sh                 the CI check of these totals against tools/size/budget
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=.build/size/${PROBE:-both}; mkdir -p $OUT
FLAGS="-mmcu=atmega2560 -DF_CPU=16000000L -Os -std=gnu++1z -fno-exceptions -fno-threadsafe-statics -ffunction-sections -fdata-sections -flto -Wall -Isrc -Iconfig"
CORE="-DBK_REPLY_SERIAL=1"  # replies printed as in the firmware (size_main.cpp)
case "${PROBE:-both}" in
  both) ;;
  bulge) CORE="$CORE -DBK_PROBE_WIDTH=0" ;;
  width) CORE="$CORE -DBK_PROBE_BULGE=0" ;;
  *) echo "size.sh: PROBE must be both, bulge or width" >&2; exit 2 ;;
esac
[ -n "${NOINLINE:-}" ] && FLAGS="$FLAGS -fno-inline -fno-inline-small-functions"
avr-g++ $FLAGS -x c++ - -o $OUT/base.elf -Wl,--gc-sections -Wl,--relax <<'C'
#include <avr/io.h>
#include <math.h>
#include <stdlib.h>
volatile float a, b; volatile long l; char *volatile s;
int main() { for (;;) { a = sqrtf(a * b + a / b - b); l = (long)a; a = (float)(unsigned long)l; b = (a < b); UDR0 = UDR0;
  a = strtod(s, 0); l = strtoul(s, 0, 10); } }
C
avr-g++ $FLAGS $CORE tools/size/size_main.cpp src/*.cpp -o $OUT/core.elf -Wl,--gc-sections -Wl,--relax
sz() { avr-size -A "$1" | awk '$1==".text"||$1==".data"{f+=$2} $1==".data"||$1==".bss"{r+=$2} END{print f, r}'; }
read bf br < <(sz $OUT/base.elf); read cf cr < <(sz $OUT/core.elf)
echo "core flash: $((cf - bf)) B   core static RAM: $((cr - br)) B   (beyond a baseline with float math and UART)"
avr-nm -C -S $OUT/core.elf > $OUT/core.nm
python3 - "$OUT/core.nm" "${1:-40}" <<'P'
import re, sys, signal
signal.signal(signal.SIGPIPE, signal.SIG_DFL)
code, text, ram = {}, {}, []
for l in open(sys.argv[1]):
    p = l.split(None, 3)
    if len(p) < 4: continue
    size, kind, name = int(p[1], 16), p[2], p[3].strip()
    if kind in 'bBdD': ram.append((size, name)); continue
    base = re.sub(r' \[clone [^\]]*\]', '', name)
    if base.endswith('::__c'): text[base[:-5]] = text.get(base[:-5], 0) + size
    else: code[base] = code.get(base, 0) + size
rows = sorted(((code.get(k, 0) + text.get(k, 0), code.get(k, 0), text.get(k, 0), k) for k in set(code) | set(text)), reverse=True)
print("%6s %6s %6s  %s" % ("total", "code", "text", "function (flash)"))
for t, c, s, k in rows[:int(sys.argv[2])]: print("%6d %6d %6d  %s" % (t, c, s, k[:100]))
print("strings in total: %d B" % sum(text.values()))
print("RAM:", ", ".join("%s %d" % (re.sub(r'^_ZL\d+|\.lto_priv\.\d+', '', n), s) for s, n in sorted(ram, reverse=True) if s >= 8))
P
