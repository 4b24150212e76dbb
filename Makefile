# Two set-up commands for a fresh machine (see README.md):
#   make demo   - install into .venv and run the main job
#   make test   - install into .venv, lint, and run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
BASE   := $(VENV)/.installed-base
STAMP  := $(VENV)/.installed
# BROWSER=0: make test installs no browser (the web page's test then skips)
BROWSER ?= 1

.PHONY: demo test lint bench clean browser

# The package alone: all the demo needs.
$(BASE): pyproject.toml
	@echo "installing rota-companion into $(VENV) (first time: a few minutes) ..."
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e .
	touch $(BASE)

# With the test and benchmark tools (make test, lint, bench).
$(STAMP): $(BASE)
	@echo "installing the test and benchmark tools into $(VENV) ..."
	$(BIN)/python -m pip install -q -e '.[dev,bench]'
	touch $(STAMP)

demo: $(BASE)
	$(BIN)/rota-sitl demo --out out/demo

lint: $(STAMP)
	$(BIN)/ruff check .

# The web page's test drives Debian's chromium; install it where we can (root + apt).
browser:
	@if [ "$(BROWSER)" = 0 ]; then echo "browser: BROWSER=0, none installed; its test skips"; \
	elif [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		echo "browser: installing chromium and chromium-driver with apt-get (BROWSER=0: not)"; \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
			chromium chromium-driver >/dev/null || echo "browser: install failed; its test skips"; \
	else echo "browser: no chromium (apt-get install chromium chromium-driver); its test skips"; fi

test: lint browser
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/rota-sitl bench --out docs/bench

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .hypothesis
