# vtexp — set up and run. `make demo` and `make test` are the README's Quick start.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test venv venv-test clean

# Core install: what `vtexp demo`, experiments on the simulator and analysis need.
$(VENV)/.core: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	$(BIN)/python -c "from vtexp._cv2 import cv2; cv2()"
	touch $@

# Tests also install the participant window (PsychoPy, the `gui` extra). PsychoPy
# pulls in opencv-python, which shares the cv2 module with the contrib build that
# vtexp needs: remove it and put the contrib build back, then check.
$(VENV)/.test: $(VENV)/.core
	$(BIN)/python -m pip install --quiet -e '.[gui,test]'
	$(BIN)/python -m pip uninstall --quiet -y opencv-python opencv-python-headless
	$(BIN)/python -m pip install --quiet --force-reinstall --no-deps opencv-contrib-python-headless
	$(BIN)/python -c "from vtexp._cv2 import cv2; cv2()"
	touch $@

venv: $(VENV)/.core
venv-test: $(VENV)/.test

demo: $(VENV)/.core
	$(BIN)/vtexp demo

test: $(VENV)/.test
	$(BIN)/python -m pytest

clean:
	rm -rf $(VENV) .pytest_cache test-output
