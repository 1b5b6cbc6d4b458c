#!/bin/bash
# Flash and RAM of the portable core on an ATmega2560, with the flags Marlin's AVR
# build uses (avr-gcc -Os, LTO, gc-sections). Prints the totals beyond a baseline
# that already has what Marlin links anyway (float arithmetic, sqrt, UART, the
# strtod/strtoul its G-code parser converts numbers with), then
# the largest functions with the flash text (BK_F strings) each one owns.
#   bash tools/size/size.sh [N]          N: how many rows to list (default 40)
#   NOINLINE=1 bash tools/size/size.sh   every function on its own row (total grows)
#   PROBE=bulge|width bash tools/size/size.sh   one feature only (default: both)
#   ARCH=cm3|cm4f bash tools/size/size.sh        Thumb-2 for a Cortex-M3 / M4F
#                                        (arm-none-eabi-gcc, newlib-nano; default avr)
#   tools/size/budget.sh                 the CI check of these totals against tools/size/budget
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=.build/size/${ARCH:-avr}-${PROBE:-both}; mkdir -p $OUT
COMMON="-Os -std=gnu++1z -fno-exceptions -fno-threadsafe-statics -ffunction-sections -fdata-sections -flto -Wall -Isrc -Iconfig"
case "${ARCH:-avr}" in
  avr) CXX=avr-g++ NM=avr-nm SIZE=avr-size UART="UDR0 = UDR0"
       FLAGS="-mmcu=atmega2560 -DF_CPU=16000000L $COMMON" LIBS="" ;;
  cm3|cm4f)
       # gcc drives the C++ build: Debian ships no libstdc++ for arm-none-eabi (none needed)
       CXX=arm-none-eabi-gcc NM=arm-none-eabi-nm SIZE=arm-none-eabi-size
       UART="*(volatile unsigned char *)0x40004000u = *(volatile unsigned char *)0x40004000u"
       [ "$ARCH" = cm3 ] && CPU="-mcpu=cortex-m3 -mthumb -mfloat-abi=soft" \
                         || CPU="-mcpu=cortex-m4 -mthumb -mfloat-abi=hard -mfpu=fpv4-sp-d16"
       # newlib-nano and no system calls: what a 32-bit Marlin HAL links as well
       FLAGS="$CPU $COMMON -fno-rtti" LIBS="--specs=nano.specs --specs=nosys.specs -lm" ;;
  *) echo "size.sh: ARCH must be avr, cm3 or cm4f" >&2; exit 2 ;;
esac
CORE="-DBK_REPLY_SERIAL=1"  # replies printed as in the firmware (size_main.cpp)
case "${PROBE:-both}" in
  both) ;;
  bulge) CORE="$CORE -DBK_PROBE_WIDTH=0" ;;
  width) CORE="$CORE -DBK_PROBE_BULGE=0" ;;
  *) echo "size.sh: PROBE must be both, bulge or width" >&2; exit 2 ;;
esac
[ -n "${NOINLINE:-}" ] && FLAGS="$FLAGS -fno-inline -fno-inline-small-functions"
$CXX $FLAGS -x c++ - -o $OUT/base.elf -Wl,--gc-sections -Wl,--relax $LIBS <<C
#include <math.h>
#include <stdlib.h>
#ifdef __AVR__
#include <avr/io.h>
#endif
volatile float a, b; volatile long l; char *volatile s;
int main() { for (;;) { a = sqrtf(a * b + a / b - b); l = (long)a; a = (float)(unsigned long)l; b = (a < b); $UART;
  a = strtod(s, 0); l = strtoul(s, 0, 10); } }
C
$CXX $FLAGS $CORE tools/size/size_main.cpp src/*.cpp -o $OUT/core.elf -Wl,--gc-sections -Wl,--relax $LIBS \
  -Wl,-Map=$OUT/core.map
if [ "${ARCH:-avr}" = avr ]; then
  sz() { $SIZE -A "$1" | awk '$1==".text"||$1==".data"{f+=$2} $1==".data"||$1==".bss"{r+=$2} END{print f, r}'; }
  read bf br < <(sz $OUT/base.elf); read cf cr < <(sz $OUT/core.elf)
  echo "core flash: $((cf - bf)) B   core static RAM: $((cr - br)) B   (beyond a baseline with float math and UART)"
else
  # newlib's strtod alone outweighs the core, so a baseline difference says
  # nothing here: the link map gives what the probe's own objects (the LTO
  # partitions) put into flash and RAM; libgcc and newlib are not counted (a
  # 32-bit Marlin links its float routines and C library anyway).
  python3 - "$OUT/core.map" <<'P'
import re, sys
flash = ram = 0
out = None  # the output section the input sections below go to
in_map = False
for line in open(sys.argv[1]):
    if line.startswith("Linker script and memory map"):
        in_map = True
        continue
    if not in_map:
        continue
    m = re.match(r"^(\.[\w.]+)\s", line)
    if m:
        out = m.group(1)
        continue
    # An input section: " .text.name 0xADDR 0xSIZE file", or the name alone on
    # the line before when it is long.
    m = re.match(r"^ (\S+)?\s+0x[0-9a-f]+\s+0x([0-9a-f]+)\s+(\S+)", line)
    if not m:
        continue
    size, src = int(m.group(2), 16), m.group(3)
    if "ltrans" not in src:
        continue
    if out in (".text", ".rodata", ".data", ".ARM.exidx", ".init_array"):
        flash += size
    if out in (".data", ".bss"):
        ram += size
print(f"core flash: {flash} B   core static RAM: {ram} B   (the probe's own code and data; libgcc and newlib not counted)")
P
fi
$NM -C -S $OUT/core.elf > $OUT/core.nm
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
if text: print("strings in total: %d B" % sum(text.values()))  # AVR: flash strings are per function
print("RAM:", ", ".join("%s %d" % (re.sub(r'^_ZL\d+|\.lto_priv\.\d+', '', n), s) for s, n in sorted(ram, reverse=True) if s >= 8))
P
