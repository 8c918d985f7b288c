# The two commands a new user runs (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup demo test browser
setup: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet -c constraints.txt -e '.[test]'
	touch $@

demo: setup
	$(BIN)/stella validate scenarios/table3 scenarios/examples scenarios/profiles
	rm -rf runs/demo
	$(BIN)/stella run scenarios/examples/fig4.json --seed 1 --out runs/demo
	$(BIN)/stella inspect runs/demo/*.mcap --plot runs/demo/top_view.png

# Debian's chromium opens the campaign report in a test; installed if missing.
SUDO := $(shell [ "$$(id -u)" = 0 ] || echo sudo)
browser:
	command -v chromium >/dev/null || ($(SUDO) apt-get update -qq && DEBIAN_FRONTEND=noninteractive $(SUDO) apt-get install -y -qq chromium)

test: setup browser
	$(BIN)/pytest
