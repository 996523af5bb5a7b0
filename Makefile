# feltool: `make run` runs the standard-arm experiment, `make test` runs the suite.
# Both create .venv and install the package into it first.
PYTHON ?= python3
VENV   ?= .venv
BIN     = $(VENV)/bin

.PHONY: run test bench docs clean

$(BIN)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $@

run: $(BIN)/.installed
	$(BIN)/feltool run configs/two_link_standard.yaml

# Test files spread over the machine's cores (-n auto), each file whole on one worker
# (--dist loadfile: a module's fixtures are built once).
test: $(BIN)/.installed
	$(BIN)/python -m pytest -q -n auto --dist loadfile

bench: $(BIN)/.installed
	$(BIN)/python benchmarks/backends.py

docs: $(BIN)/.installed
	$(BIN)/python -m feltool.config.docgen docs/configuration.md

clean:
	rm -rf $(VENV) runs .pytest_cache
