# vtexp — set up and run. `make demo` and `make test` are the README's Quick start.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin

.PHONY: demo test venv venv-test system-packages clean

# Core install: what `vtexp demo`, experiments on the simulator and analysis need.
$(VENV)/.core: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e .
	$(BIN)/python -c "from vtexp._cv2 import cv2; cv2()"
	touch $@

# Tests also install the participant window (PsychoPy, the `gui` extra), the BIDS
# validator and scikit-image's photographs (in `test`), DuckDB (the `pool` extra), the
# LSL marker stream (`lsl`) and Dask (`cluster`). PsychoPy pulls in opencv-python, which
# shares the cv2 module with the contrib build that vtexp needs: remove it and put the
# contrib build back, then check.
$(VENV)/.test: $(VENV)/.core
	$(BIN)/python -m pip install --quiet -e '.[gui,test,pool,lsl,cluster]'
	$(BIN)/python -m pip uninstall --quiet -y opencv-python opencv-python-headless
	$(BIN)/python -m pip install --quiet --force-reinstall --no-deps opencv-contrib-python-headless
	$(BIN)/python -c "from vtexp._cv2 import cv2; cv2()"
	touch $@

# The window tests open a real PsychoPy window on a virtual X server (Xvfb) drawn by
# Mesa's software OpenGL; pyglet loads GLU, Xxf86vm, Xinerama, Xi, Xrandr, Xcursor and
# fontconfig at run time, and the window's text is DejaVu Sans. On Debian/Ubuntu as
# root (CI), what is missing is installed; elsewhere the command to run is printed.
GUI_DEBS := xvfb libgl1-mesa-dri libglu1-mesa libxxf86vm1 libxinerama1 libxi6 libxrandr2 \
            libxcursor1 fontconfig fonts-dejavu-core
# The audio mode speaks with espeak-ng and plays through PsychoPy's sound (PortAudio).
AUDIO_DEBS := espeak-ng libportaudio2 pulseaudio pulseaudio-utils libasound2-plugins alsa-utils
# The reference firmware (firmware/): avr-gcc and avr-libc build what a lab flashes; the
# tests run that .elf on an emulated ATmega2560 (libsimavr, through vtexp-simavr).
FIRMWARE_DEBS := gcc-avr avr-libc binutils-avr libsimavr-dev libelf-dev pkg-config make gcc
# The report tests lay every report out in headless Chromium and check that no text
# overlaps another (tests/report_render.py).
REPORT_DEBS := chromium
SYSTEM_DEBS := $(GUI_DEBS) $(AUDIO_DEBS) $(FIRMWARE_DEBS) $(REPORT_DEBS)

system-packages:
	@command -v dpkg-query >/dev/null || { command -v Xvfb >/dev/null || \
	  echo "the window tests need Xvfb, Mesa OpenGL and espeak-ng, the firmware tests avr-gcc and simavr, the report tests Chromium; install them with your package manager" >&2; exit 0; }; \
	missing=$$(for p in $(SYSTEM_DEBS); do dpkg-query -W -f='$${Status}\n' $$p 2>/dev/null \
	  | grep -q 'install ok installed' || echo $$p; done | tr '\n' ' '); \
	if [ -z "$$missing" ]; then exit 0; fi; \
	if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	  echo "+ apt-get install $$missing"; \
	  apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq \
	    --no-install-recommends $$missing >/dev/null; \
	else \
	  echo "the window and firmware tests need: sudo apt-get install --no-install-recommends $$missing" >&2; \
	fi

venv: $(VENV)/.core
venv-test: system-packages $(VENV)/.test

demo: $(VENV)/.core
	$(BIN)/vtexp demo

# Five test processes (pytest-xdist) on the two cores, each test file whole in one of
# them. Most tests run on a virtual clock; those whose subject is real time (a real pty,
# the firmware in simavr, the window and the PsychoPy Builder example under Xvfb, sound
# through a sound server, signals to a process) wait on it, and the other processes keep
# both cores busy while they do (four left the cores idle a sixth of the run; six made
# it no shorter). The study on the AVR firmware in simavr is handed out first and runs
# beside the others (it ran alone at the end before trains knew their end, see
# docs/firmware.md, Known limits). Bytecode is cached even where the environment says not
# to (PYTHONDONTWRITEBYTECODE): the suite starts Python about a hundred times, and each
# would compile vtexp again. The processes share the two cores, so NumPy's BLAS computes
# on one thread in each: its own threads would only wait for each other (OpenBLAS spins
# while it waits: the GLMM tests take 9.9 s of CPU with two threads, 5.9 s with one, in
# the same wall time).
test: system-packages $(VENV)/.test
	env -u PYTHONDONTWRITEBYTECODE OPENBLAS_NUM_THREADS=1 \
	  $(BIN)/python -m pytest -n 5 --dist loadfile

clean:
	rm -rf $(VENV) .pytest_cache test-output
