# One way to set up and run everything. `make train` and `make test` each create the virtual
# environment on first use. torch==2.13.0 is installed on its own first: resolved as a plain
# dependency it would pull a multi-GB CUDA build.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ARGS ?=

.PHONY: setup train test lint format bench scenes play clean

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install torch==2.13.0
	$(BIN)/pip install -e ".[dev]"
	touch $(STAMP)

setup: $(STAMP)

train: $(STAMP)
	$(BIN)/truckrl train $(ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test: lint
	SDL_VIDEODRIVER=dummy $(BIN)/python -m pytest $(ARGS)
	$(BIN)/python -m pytest -m wheel

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: $(STAMP)
	$(BIN)/truckrl bench $(ARGS)

play: $(STAMP)
	$(BIN)/truckrl play $(ARGS)

scenes: $(STAMP)
	$(BIN)/truckrl tools scenes $(ARGS)

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache
