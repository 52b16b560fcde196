# Everything a fresh machine (Python 3.11, pip, Debian apt) needs to run the tests.
VENV    ?= .venv
PY      := $(VENV)/bin/python
STAMP   := $(VENV)/.installed
SYSDEPS := socat prometheus mosquitto chromium
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: test lint bench demo venv sysdeps clean stress-test soak screenshots test-fast

$(STAMP): pyproject.toml
	python3 -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

venv: $(STAMP)

# Debian packages the integration tests use: socat (serial ptys), prometheus/promtool,
# systemd-analyze (unit file verification), mosquitto (a real MQTT broker), chromium (the
# browser the page's tests drive headless through Playwright; nothing is downloaded at test time).
sysdeps:
	@missing=""; \
	command -v socat >/dev/null || missing="$$missing socat"; \
	command -v promtool >/dev/null || missing="$$missing prometheus"; \
	command -v systemd-analyze >/dev/null || missing="$$missing systemd"; \
	command -v mosquitto >/dev/null || [ -x /usr/sbin/mosquitto ] || missing="$$missing mosquitto"; \
	command -v chromium >/dev/null || missing="$$missing chromium"; \
	if [ -n "$$missing" ]; then \
		echo "installing Debian packages:$$missing"; \
		SUDO=""; [ "$$(id -u)" = 0 ] || SUDO=sudo; \
		$$SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $$SUDO apt-get install -y -qq --no-install-recommends $$missing; \
	fi

lint: $(STAMP)
	$(VENV)/bin/ruff check gateway sim_device tests bench
	$(VENV)/bin/ruff format --check gateway sim_device tests bench
	$(VENV)/bin/mypy

test: $(STAMP) sysdeps lint
	$(PY) -m pytest -q

# While working: only the tests not marked slow (no browser, broker, prometheus server or
# gateway/simulator process; markers in pyproject.toml). Installs no Debian packages and skips
# lint; the serial and promtool tests in it need socat and prometheus from one `make sysdeps`.
# Narrow it further with e.g. FAST='not slow and not serial'.
FAST ?= not slow
test-fast: $(STAMP)
	$(PY) -m pytest -q -m "$(FAST)"

bench: $(STAMP)
	$(PY) -m bench

# The gateway against the simulator with faults on a schedule (not part of `make test`).
SOAK_MINUTES ?= 20
soak: $(STAMP)
	$(PY) -m bench.soak --minutes $(SOAK_MINUTES)

# The integration tests, 5 rounds, with a CPU hog on every core (not part of `make test`).
stress-test: $(STAMP) sysdeps
	$(PY) -m bench.stress --rounds 5

demo: $(STAMP)
	$(VENV)/bin/tactile-gateway demo

# The docs' screenshots of the page, made by the tests that check what they show (headless
# chromium through Playwright): the live page at the demo's forces, the playback of a record,
# the hand profile drawn by regions, and the page as a measuring tool (issue 35: the array and
# its axes, a phone, one scale, a threshold, a region of interest, the history, a difference).
screenshots: $(STAMP) sysdeps
	TACTILE_SCREENSHOT_DEMO=$(CURDIR)/docs/screenshot-pressure-map.png \
	TACTILE_SCREENSHOT_PLAYBACK=$(CURDIR)/docs/screenshot-playback.png \
	TACTILE_SCREENSHOT_HAND=$(CURDIR)/docs/screenshot-hand.png \
	TACTILE_SCREENSHOT_ARRAY=$(CURDIR)/docs/screenshot-array.png \
	TACTILE_SCREENSHOT_PHONE=$(CURDIR)/docs/screenshot-phone.png \
	TACTILE_SCREENSHOT_OVERVIEW=$(CURDIR)/docs/screenshot-overview.png \
	TACTILE_SCREENSHOT_THRESHOLD=$(CURDIR)/docs/screenshot-threshold.png \
	TACTILE_SCREENSHOT_ROI=$(CURDIR)/docs/screenshot-roi.png \
	TACTILE_SCREENSHOT_HISTORY=$(CURDIR)/docs/screenshot-history.png \
	TACTILE_SCREENSHOT_DIFFERENCE=$(CURDIR)/docs/screenshot-difference.png \
	$(PY) -m pytest -q \
		tests/integration/test_web_page.py::test_auto_range_makes_the_peak_bright_at_demo_forces \
		tests/integration/test_web_playback.py::test_playback_moves_through_the_record \
		tests/integration/test_web_hand.py::test_the_page_draws_the_hand_by_regions_with_sums \
		tests/integration/test_web_page_tool.py \
		tests/integration/test_web_page_time.py \
		tests/integration/test_web_page_roi.py

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache *.egg-info
