# Two set-up commands for a fresh machine (see README.md):
#   make demo   - install into .venv and run the main job
#   make test   - install into .venv, lint, and run the test suite
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test lint bench clean browser

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -q --upgrade pip
	$(BIN)/python -m pip install -q -e '.[dev,bench]'
	touch $(STAMP)

demo: $(STAMP)
	$(BIN)/rota-companion demo --out out/demo

lint: $(STAMP)
	$(BIN)/ruff check .

# The web page's test drives Debian's chromium; install it where we can (root + apt).
browser:
	@if [ -x /usr/bin/chromium ] && [ -x /usr/bin/chromedriver ]; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
			chromium chromium-driver >/dev/null || echo "browser: install failed; its test skips"; \
	else echo "browser: no chromium (apt-get install chromium chromium-driver); its test skips"; fi

test: lint browser
	$(BIN)/python -m pytest -q

bench: $(STAMP)
	$(BIN)/rota bench --out docs/bench

clean:
	rm -rf $(VENV) out .pytest_cache .ruff_cache .hypothesis
