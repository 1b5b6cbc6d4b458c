# bulgekit — the two commands a user needs:
#   make demo    run the main job on the sample data shipped in the repo
#   make test    run every test: C++ core on the host and on a simulated ATmega2560, checks, pytest
# Other targets: make deps (install system + Python packages), make bench, make fuzz, make help
SHELL := /bin/bash
ENV := source tools/env.sh &&

.PHONY: help deps bootstrap test test-native test-avr bench fuzz demo clean

help:
	@sed -n 's/^#   //p; s/^# Other/Other/p' Makefile

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

# Benchmark suites print their tables (cycles on the simulated ATmega2560).
bench: bootstrap
	$(ENV) pio test -e avr_sim -f 'test_bench_*' -v | grep -v '^bksim: marker'

fuzz: bootstrap
	bash tools/fuzz/run.sh $(FUZZ_SECONDS)

demo: bootstrap
	$(ENV) bash tools/demo.sh

clean:
	rm -rf .build/pio
