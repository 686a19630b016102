# Two entry points: `make demo` and `make test`. Both build .venv from nothing when it is
# missing or older than requirements.txt / setup.py.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint unit colcon-smoke venv clean

venv: $(STAMP)

$(STAMP): requirements.txt setup.py setup.cfg
	@test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --disable-pip-version-check -r requirements.txt
	$(BIN)/python -m pip install --quiet --disable-pip-version-check --no-deps -e .
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/policy-align demo --out demo_out

lint: $(STAMP)
	$(BIN)/ruff check policy_align_ros test tools

unit: $(STAMP)
	$(BIN)/python -m pytest -q test

# colcon build of the package into a scratch workspace, then start an installed executable.
colcon-smoke: $(STAMP)
	PATH=$(CURDIR)/$(BIN):$$PATH tools/colcon_smoke.sh

test: lint unit colcon-smoke

clean:
	rm -rf $(VENV) build install log
