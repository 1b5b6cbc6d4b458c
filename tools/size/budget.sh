#!/bin/bash
# The size budget CI holds: builds the core probe (tools/size/size.sh: avr-gcc,
# Marlin's AVR flags) for both features and for each one alone, prints the
# figures and fails when one exceeds its line in tools/size/budget. Lower a
# budget line when a change makes the core smaller, so size never creeps back.
#   bash tools/size/budget.sh
set -euo pipefail
cd "$(dirname "$0")/../.."
status=0
printf "%-6s %13s %13s\n" probe "flash/budget" "RAM/budget"
while read -r probe flash ram; do
  case "$probe" in ''|'#'*) continue ;; esac
  out=$(PROBE=$probe bash tools/size/size.sh 0)
  line=${out%%$'\n'*}
  f=$(sed -n 's/^core flash: \([0-9]*\) B.*/\1/p' <<<"$line")
  r=$(sed -n 's/.*core static RAM: \([0-9]*\) B.*/\1/p' <<<"$line")
  [ -n "$f" ] && [ -n "$r" ] || { echo "budget: no figures from size.sh for $probe: $line" >&2; exit 1; }
  verdict=ok
  if [ "$f" -gt "$flash" ] || [ "$r" -gt "$ram" ]; then verdict="OVER BUDGET"; status=1; fi
  printf "%-6s %6d/%-6d %6d/%-6d %s\n" "$probe" "$f" "$flash" "$r" "$ram" "$verdict"
done < tools/size/budget
exit $status
