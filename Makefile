# groupforward: `make demo` runs the end-to-end demo, `make test` runs every check CI runs.
# Both do their own idempotent setup (a project-local Python venv with pinned test tools).

CARGO ?= cargo
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed-$(shell sha256sum tests/python/requirements.txt | cut -c1-16)

.PHONY: all setup demo test test-rust test-python lint bench golden clean

all: test

$(STAMP): tests/python/requirements.txt
	@test -x $(VENV)/bin/python || $(PYTHON) -m venv $(VENV)
	$(VENV)/bin/python -m pip install --quiet --disable-pip-version-check -r tests/python/requirements.txt
	@rm -f $(VENV)/.installed-* && touch $@

setup: $(STAMP)

demo:
	$(CARGO) run --quiet -p groupforward -- demo

lint:
	$(CARGO) fmt --all -- --check
	$(CARGO) clippy --workspace --all-targets --quiet -- -D warnings

test-rust:
	$(CARGO) test --workspace

test-python: setup
	$(CARGO) build --quiet -p groupforward
	PYTHONDONTWRITEBYTECODE=1 $(VENV)/bin/python -m pytest -q -p no:cacheprovider tests/python

test: lint test-rust test-python

# Regenerate the golden CDR vectors and type hashes with Python rosbags.
golden: setup
	$(VENV)/bin/python msgs/tests/golden/make_golden.py

bench:
	$(CARGO) bench -p groupforward

clean:
	$(CARGO) clean
	rm -rf $(VENV)
