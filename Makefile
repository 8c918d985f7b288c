# The two commands a new user runs (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup demo test test-fast browser docker
setup: $(VENV)/.installed

# setup.py compiles these: an edit to one rebuilds it (an import refuses a stale build: simlink.check_compiled).
COMPILED := $(wildcard autopilot/*.py autopilot/*.pxd simlink/*.py simlink/*.pxd sim_bridge/*.pxd) $(patsubst %.pxd,%.py,$(wildcard sim_bridge/*.pxd))

$(VENV)/.installed: pyproject.toml constraints.txt setup.py $(COMPILED)
	$(PYTHON) -m venv $(VENV)
	@# Cython regenerates a .c file only when its .py or .pxd is newer: not for setup.py's directives.
	rm -f autopilot/*.c simlink/*.c sim_bridge/*.c
	$(BIN)/pip install --quiet -c constraints.txt -e '.[test]'
	touch $@

# The tool's main job on the embedded defaults: a small search that finds a violation, its
# report, and the worst case kept as a regression test that pytest flies.
DEMO := runs/demo
demo: setup
	$(BIN)/stella validate scenarios/table3 scenarios/examples scenarios/profiles scenarios/faults
	rm -rf $(DEMO)
	$(BIN)/stella campaign scenarios/table3/scenario_09.json --algorithm NSGAII --evaluations 60 \
		--population 20 --store $(DEMO)/campaign.db
	$(BIN)/stella report $(DEMO)/campaign.db --out $(DEMO)/report.html
	$(BIN)/stella export-regressions $(DEMO)/campaign.db --out $(DEMO)/regressions \
		--threshold=-inf --worst 1 --expect violation
	$(BIN)/pytest -q -p no:cacheprovider -o addopts= --stella-out $(DEMO)/regression-logs $(DEMO)/regressions
	@echo
	@echo "campaign store (every evaluation): $(DEMO)/campaign.db, flight logs in $(DEMO)/campaign-logs/"
	@echo "report (open in a browser):        $(DEMO)/report.html"
	@echo "regression case of the worst:      $(DEMO)/regressions/"
	@echo "its flight log from pytest:        $(DEMO)/regression-logs/ (open the .mcap in Foxglove)"

# The tests not marked slow: seconds, nothing started.
test-fast: setup
	$(BIN)/pytest -n auto --dist loadfile -m "not slow and not alone"

# Debian's chromium opens the campaign report in a test; installed if missing.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
browser:
	command -v chromium >/dev/null || ($(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium)

# The docker executor's tests need a Docker Engine and the worker image: Debian's docker.io,
# dockerd started in the background when none answers (there is no systemd), and the image
# built on a debootstrapped base, as no image registry is reachable (made once; later builds
# reuse the cached dependency layer and only copy the project again).
docker: setup
	(command -v dockerd && command -v debootstrap && command -v docker-compose) >/dev/null || ($(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq docker.io debootstrap docker-compose)
	docker info >/dev/null 2>&1 || ($(SUDO) sh -c 'nohup dockerd >/tmp/stella-dockerd.log 2>&1 &'; \
		for i in $$(seq 60); do docker info >/dev/null 2>&1 && break; sleep 1; done; docker info >/dev/null)
	$(BIN)/stella docker build --make-base

# The tests run two at a time, a test module to a worker (most fly on one core); those marked
# `alone` count every process and port of the machine, so they run afterwards by themselves.
test: setup browser docker
	$(BIN)/pytest -n auto --dist loadfile -m "not alone"
	$(BIN)/pytest -m alone
