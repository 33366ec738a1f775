# Two set-up commands for a fresh machine (see README):
#   make demo   -> creates .venv, installs the package with its renderer (extra render), runs
#                  the main job (`forest demo`)
#   make test   -> creates .venv, installs the package with every extra and the test tools
#                  (extra dev), runs lint, type checks, the docs build (mkdocs --strict) and
#                  the whole test suite
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# one stamp per install, named by pyproject.toml's checksum: an edit there installs again
SUM := $(shell cksum < pyproject.toml | cut -d' ' -f1)
RENDER := $(VENV)/.installed-render-$(SUM)
DEV := $(VENV)/.installed-dev-$(SUM)

.PHONY: demo test lint docs bench schemas web clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip

$(RENDER): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[render]'
	rm -f $(VENV)/.installed-render-* && touch $@

# dev holds render: after render it only adds packages, and it stands for render too
$(DEV): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e '.[dev]'
	rm -f $(VENV)/.installed-* && touch $@ $(RENDER)

demo: $(RENDER)
	$(BIN)/forest demo -o demo
	@echo
	@echo "forest is installed in $(VENV): run 'source $(BIN)/activate', then try 'forest presets'"
	@echo "(or, without activating it: $(BIN)/forest presets)"

lint: $(DEV)
	$(BIN)/ruff check forest schemas farm worker service cli bench tests docs/hooks
	$(BIN)/ruff format --check forest schemas farm worker service cli bench tests docs/hooks
	$(BIN)/mypy

test: $(DEV) lint docs
	bash tests/setup_node.sh
	bash tests/setup_blender_venv.sh
	bash tests/setup_blender_venv.sh 5.2
	bash tests/setup_validator_venv.sh
	bash tests/setup_arkit_venv.sh
	$(BIN)/python -m pytest -n 2 --dist loadfile

# the documentation site (docs/, mkdocs.yml) into build/site: a broken link or anchor fails it;
# `$(BIN)/mkdocs serve` shows it while you edit
docs: $(DEV)
	$(BIN)/mkdocs build --strict -d build/site

bench: $(RENDER)
	$(BIN)/forest bench generate

schemas: $(RENDER)
	$(BIN)/python -m schemas.export

# the web page (web/ -> service/static, committed so pip install needs no node): gallery
# thumbnails, vite build, Swagger UI and ReDoc vendored, build.json digest of the sources
web: $(RENDER)
	$(BIN)/python web/scripts/thumbs.py
	cd web && npm ci --no-audit --no-fund && npm run build

clean:
	rm -rf $(VENV) .venv-blender .venv-blender52 .venv-validator .venv-arkit demo .pytest_cache .mypy_cache .ruff_cache .hypothesis
