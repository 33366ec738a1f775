# Two set-up commands for a fresh machine (see README):
#   make demo   -> creates .venv, installs the package, runs the main job (`forest demo`)
#   make test   -> creates .venv, installs the package with its test tools, runs lint,
#                  type checks and the whole test suite
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-$(shell cat pyproject.toml | cksum | cut -d' ' -f1)

.PHONY: demo test lint bench schemas web clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev]'
	rm -f $(VENV)/.installed-* && touch $@

demo: $(STAMP)
	$(BIN)/forest demo -o demo

lint: $(STAMP)
	$(BIN)/ruff check forest schemas farm worker service cli bench tests
	$(BIN)/mypy

test: $(STAMP) lint
	bash tests/setup_node.sh
	bash tests/setup_blender_venv.sh
	bash tests/setup_validator_venv.sh
	$(BIN)/python -m pytest -n 2 --dist loadfile

bench: $(STAMP)
	$(BIN)/forest bench generate

schemas: $(STAMP)
	$(BIN)/python -m schemas.export

# the web page (web/ -> service/static, committed so pip install needs no node): gallery
# thumbnails, vite build, Swagger UI and ReDoc vendored, build.json digest of the sources
web: $(STAMP)
	$(BIN)/python web/scripts/thumbs.py
	cd web && npm ci --no-audit --no-fund && npm run build

clean:
	rm -rf $(VENV) .venv-blender .venv-validator demo .pytest_cache .mypy_cache .ruff_cache .hypothesis
