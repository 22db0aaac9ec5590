# Two commands do all the set-up on a fresh machine: `make demo` and `make test`.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.stamp-install

.PHONY: demo screenshot test lint bench venv viewer-deps browser-deps clean

# constraints.txt pins every distribution to the version the docs' figures were measured with
$(STAMP): pyproject.toml constraints.txt
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	# torch first, pinned, so pip takes the CPU build on disk instead of a multi-GB CUDA build
	$(BIN)/pip install -q --disable-pip-version-check -c constraints.txt torch==2.13.0
	$(BIN)/pip install -q --disable-pip-version-check -c constraints.txt -e '.[test,app,scale,dev]'
	# TrackEval: the reference the tracking metrics are tested against (seg2pose/eval/tracking_metrics.py);
	# --no-deps because its package requires opencv-python, which would shadow opencv-python-headless
	$(BIN)/pip install -q --disable-pip-version-check --no-deps -c constraints.txt trackeval==1.3.0
	touch $(STAMP)

venv: $(STAMP)

# The real Rerun viewer runs headless on Mesa's software Vulkan (tests against the viewer need it),
# and decodes the camera videos (H.264) with the ffmpeg executable it finds on the PATH.
viewer-deps:
	@if ! ldconfig -p | grep -q libvulkan_lvp || ! ldconfig -p | grep -q 'libvulkan\.so\.1' || ! ls /usr/share/vulkan/icd.d/lvp_icd*.json >/dev/null 2>&1 || ! command -v ffmpeg >/dev/null; then \
	  if [ "$$(id -u)" = 0 ]; then (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mesa-vulkan-drivers libvulkan1 ffmpeg >/dev/null) || echo "warning: could not install mesa-vulkan-drivers; viewer tests will be skipped"; \
	  else echo "warning: not root, cannot install mesa-vulkan-drivers; viewer tests will be skipped"; fi; \
	fi

# The annotation app's browser tests drive Debian's chromium (Playwright's own browser download
# needs the internet); without it they are skipped with the reason.
browser-deps:
	@if [ ! -x /usr/bin/chromium ]; then \
	  if [ "$$(id -u)" = 0 ]; then (apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq chromium >/dev/null) || echo "warning: could not install chromium; browser tests will be skipped"; \
	  else echo "warning: not root, cannot install chromium; browser tests will be skipped"; fi; \
	fi

demo: $(STAMP)
	$(BIN)/s2p demo

# the README picture, from the sample recording `make demo` wrote
screenshot: $(STAMP) viewer-deps
	$(BIN)/s2p screenshot sample_logs/demo.rrd -o docs/screenshot.png --frame 600 --force

# lint (pyflakes, pycodestyle, import order, pyupgrade, bugbear) and types, configured in pyproject.toml
lint: $(STAMP)
	$(BIN)/ruff check seg2pose s2p_review annotate tests benches
	$(BIN)/mypy

test: lint viewer-deps browser-deps
	$(BIN)/python -m pytest -q -p no:cacheprovider --durations=15

bench: $(STAMP)
	for b in benches/bench_*.py; do echo "== $$b"; $(BIN)/python $$b || exit 1; done

clean:
	rm -rf $(VENV) build *.egg-info
