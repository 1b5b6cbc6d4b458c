# bulgekit — the two commands a user needs:
#   make demo    run the main job on the sample data shipped in the repo (needs only Python + PyPI)
#   make test    run every test: C++ core on the host, a simulated ATmega2560 and Cortex-M3/M4F in QEMU, checks, pytest
# Both install what is missing first (tools/install-deps.sh, by role; BK_NO_INSTALL=1 only lists it).
# Other targets: make deps (install everything make test needs, now), make bench, make fuzz, make help
SHELL := /bin/bash
ENV := source tools/env.sh &&

.PHONY: help deps bootstrap test test-native test-avr test-arm bench fuzz demo clean

help:
	@sed -n 's/^#   //p; s/^# Both/Both/p; s/^# Other/Other/p' Makefile

deps:
	bash tools/install-deps.sh

bootstrap:
	@bash tools/bootstrap.sh

test: bootstrap
	$(ENV) python3 tools/run_tests.py

test-native: bootstrap
	$(ENV) python3 tools/run_tests.py --only native

test-avr: bootstrap
	$(ENV) python3 tools/run_tests.py --only avr_sim

test-arm: bootstrap
	$(ENV) python3 tools/run_tests.py --only cm3_qemu --only cm4f_qemu

# Benchmark suites print their tables: cycles on the simulated ATmega2560,
# instructions on the Cortex-M3/M4F in QEMU; then the core's flash per target.
bench: bootstrap
	$(ENV) set -o pipefail; for e in avr_sim cm3_qemu cm4f_qemu; do \
	  echo "== $$e"; pio test -e $$e -f 'test_bench_*' -v | grep -v '^bksim: marker' || exit 1; done
	@$(ENV) for a in avr cm3 cm4f; do echo "== core flash, $$a (tools/size/size.sh)"; \
	  ARCH=$$a bash tools/size/size.sh 0 | head -1 || exit 1; done

fuzz: bootstrap
	bash tools/fuzz/run.sh $(FUZZ_SECONDS)

# only the host package and its PyPI packages: no compiler, simulator, slicer or browser
demo:
	@bash tools/bootstrap.sh --role demo
	$(ENV) bash tools/demo.sh

clean:
	rm -rf .build/pio
