# The two commands a new user runs (see README): `make demo` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin

.PHONY: setup demo test
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

test: setup
	$(BIN)/pytest
