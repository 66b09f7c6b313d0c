# One way to set up and run everything. `make train` and `make test` each create the virtual
# environment on first use. torch==2.13.0 is installed on its own first: resolved as a plain
# dependency it would pull a multi-GB CUDA build.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
ARGS ?=

.PHONY: setup train test lint format bench scenes play docs pretrained clean

$(STAMP): pyproject.toml
	test -d $(VENV) || $(PY) -m venv $(VENV)
	$(BIN)/pip install --upgrade pip
	$(BIN)/pip install torch==2.13.0
	$(BIN)/pip install -e ".[dev,docs]"
	touch $(STAMP)

setup: $(STAMP)

train: $(STAMP)
	$(BIN)/truckrl train $(ARGS)

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

test: lint
	SDL_VIDEODRIVER=dummy $(BIN)/python -m pytest $(ARGS)
	$(BIN)/python -m pytest -m wheel -n 0

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: $(STAMP)
	$(BIN)/truckrl bench $(ARGS)

play: $(STAMP)
	$(BIN)/truckrl play $(ARGS)

scenes: $(STAMP)
	$(BIN)/truckrl tools scenes $(ARGS)

# A shipped policy rebuilt from a clean commit by its preset, stopped by frames, with its card:
# make pretrained TASK=intersection|dock|uturn|network (truckrl tools pretrained --help); the shipped
# dock, uturn and network files are their runs' best.pt: make pretrained TASK=dock ARGS=checkpoint=best.
pretrained: $(STAMP)
	$(BIN)/truckrl tools pretrained task=$(TASK) $(ARGS)

# The documentation site: the generated fragments (docs/render.py, where it exists), then HTML
# into docs/_build/html with every warning an error (-W; -n: unresolved references too). A broken
# internal link (a missing page, heading anchor or file) is one of those warnings; external
# links are never fetched, so the build works offline.
DOCS_OPTS ?= -W --keep-going -n -q
docs: $(STAMP)
	if test -f docs/render.py; then $(BIN)/python docs/render.py; fi
	$(BIN)/python -m sphinx -b html -d docs/_build/doctrees $(DOCS_OPTS) docs docs/_build/html

clean:
	rm -rf $(VENV) .pytest_cache .ruff_cache docs/_build docs/_generated
