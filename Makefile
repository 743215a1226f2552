# shotcrete-planner: every target sets itself up (apt packages, venv, build) on a fresh Debian 12.
VENV ?= .venv
PY := $(VENV)/bin/python
OUT ?= out/demo
export CMAKE_CXX_COMPILER_LAUNCHER := ccache

.PHONY: setup demo report-check test test-cpp test-python test-ros test-asan screenshot bench regression clean

setup:
	bash scripts/setup.sh

demo: setup
	$(VENV)/bin/shotcrete demo --out $(OUT)

# The demo's report.html in headless Chromium (fails on a broken page); first screen in out/report_demo.png.
report-check: demo
	$(PY) scripts/check_report_page.py $(OUT)/report.html --screenshot out/report_demo.png \
	  --first-screen "#verdict" --first-screen ".cards" --first-screen "#summary-table" --click ".updatemenu-button"

# ctest (C++ core) + pytest (bindings, CLI) + rostest (ROS node); fails if any suite fails or runs nothing.
test: setup
	bash scripts/run_tests.sh

test-cpp: setup
	bash scripts/run_tests.sh cpp

test-python: setup
	bash scripts/run_tests.sh python

test-ros: setup
	bash scripts/run_tests.sh ros

# The C++ tests once more, built with AddressSanitizer + UndefinedBehaviorSanitizer in build/asan.
test-asan: setup
	bash scripts/test_asan.sh

screenshot: setup
	bash ros1_pkg/scripts/rviz_screenshot.sh out/rviz.png

bench: setup
	$(PY) bench/run_benchmarks.py --out bench/results

# The default demo in both planner modes against the recorded report.json numbers (1e-6 relative).
regression: setup
	$(PY) bench/check_regression.py

clean:
	rm -rf build out bench/results ros1_pkg/.ws
