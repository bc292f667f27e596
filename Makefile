# The README's two commands: `make demo` and `make test`. Both set up .venv themselves.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
# pytorch-kinematics imports matplotlib, which wants a writable config folder.
export MPLCONFIGDIR := $(CURDIR)/.mplconfig

.PHONY: install demo test fuzz

install: $(VENV)/.installed

$(VENV)/.installed: pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install -qq --upgrade pip
	$(BIN)/python -m pip install -qq -c constraints.txt torch==2.13.0
	$(BIN)/python -m pip install -qq -c constraints.txt -e '.[dev]'
	touch $@

# Four filters on a walk no prior was trained on, under occlusion: the table, plots and recordings in demo/.
demo: install
	$(BIN)/priortrack compare --filters pf-diffusion-local pf-gpdm pf-lie ukf-gpdm --motions cmu:07_10 \
		--scenarios occlusion:sigma_px=5 --out demo --rrd

test: install
	$(BIN)/python -m pytest -n 2 --dist loadgroup -q

# The long fuzzing profile (tests/test_fuzz.py: thousands of mutated files per reader).
fuzz: install
	PRIORTRACK_FUZZ=long $(BIN)/python -m pytest -q -p no:cacheprovider tests/test_fuzz.py
